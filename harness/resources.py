"""Memory a job will need, estimated before it starts, so that a size this machine cannot hold is refused
in one line (the estimate and the limit) instead of running until the allocator gives up.

A window with gradients keeps its forward pass for the backward one: Newton's tape holds every
substep's state, MuJoCo-Warp's finite differences hold each step's Jacobians beside its perturbed
worlds. So training memory grows with envs x horizon, and evaluation (no gradients) with envs alone.
Each adapter ships its slopes (``costs``, :class:`backends.contract.TaskCost`): the growth of peak
resident memory between two env counts of the same command (``train --epochs 2`` at the task's
horizon, ``eval`` at two ``--num-envs``), rounded down: the estimate is a lower bound, so what it
refuses cannot fit, and what it lets through may still be tight. An engine or task without slopes (a
plug-in that measured none) gets no estimate and is never refused.
The interpreter, torch and the model (about 1 GB here) are not counted. docs/performance.md has the
command that measures them.
"""

from __future__ import annotations

import os

MB = 1 << 20  # for the messages


def task_cost(backend: str, task: str, options: dict | None = None):
    """The adapter's planning figures for ``task`` (:meth:`backends.contract.BatchedSim.task_cost`), or
    None for an engine that is not installed, cannot load, or measured nothing for the task."""
    import backends

    if backend not in backends.available():
        return None
    try:
        return backends.get(backend).task_cost(task, options)
    except Exception:  # a plug-in that fails to import is named by the verb that builds it
        return None


def estimate_bytes(
    backend: str, task: str, num_envs: int, horizon: int = 0, grads: bool = True, options: dict | None = None
) -> float | None:
    """Bytes ``num_envs`` envs need beyond the process's fixed cost; windows of ``horizon`` steps when
    ``grads``. None where the adapter measured nothing."""
    cost = task_cost(backend, task, options)
    if cost is None or cost.bytes_per_env is None:
        return None
    per_env, grads_once, per_step = cost.bytes_per_env
    return num_envs * (per_env + (grads_once + per_step * horizon if grads else 0.0))


def available_bytes(device: str = "cpu") -> float | None:
    """Memory free for a new job on ``device``: MemAvailable plus free swap (Linux), a CUDA device's free
    memory; None where the system does not say."""
    if device.startswith("cuda"):
        import torch

        try:
            return float(torch.cuda.mem_get_info(torch.device(device))[0])
        except (RuntimeError, AssertionError, ValueError):
            return None
    try:
        with open("/proc/meminfo") as f:
            fields = {line.split(":")[0]: float(line.split()[1]) * 1024 for line in f if ":" in line}
        return fields["MemAvailable"] + fields.get("SwapFree", 0.0)
    except (OSError, KeyError, ValueError, IndexError):
        pass
    try:
        return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def gib(size: float) -> str:
    return f"{size / (1 << 30):.1f} GiB" if size >= 1 << 30 else f"{size / MB:.0f} MiB"


def memory_problem(
    backend: str,
    task: str,
    num_envs: int,
    horizon: int = 0,
    grads: bool = True,
    device: str = "cpu",
    copies: int = 1,
    available: float | None = None,
) -> str | None:
    """Why ``num_envs`` envs (``copies`` such jobs at once) cannot fit in this machine's memory, as a
    phrase with the estimate, the limit and the largest env count that fits; None when they may fit or
    nothing is known."""
    need = estimate_bytes(backend, task, num_envs, horizon, grads)
    have = available_bytes(device) if available is None else available
    if need is None or have is None or need * copies <= have:
        return None
    one_env = need / num_envs
    fits = int(have / copies // one_env)
    what = f"{num_envs} envs of {backend}/{task}" + (f" with gradients over {horizon} steps" if grads else "")
    at_once = f" x {copies} jobs at once" if copies > 1 else ""
    return (
        f"{what} need at least {gib(need)}{at_once}; {device} has {gib(have)} free, "
        f"enough for at most {fits} envs{' per job' if copies > 1 else ''}"
    )
