"""Memory a job will need, estimated before it starts, so that a size this machine cannot hold is refused
in one line (the estimate and the limit) instead of running until the allocator gives up.

A window with gradients keeps its forward pass for the backward one: Newton's tape holds every
substep's state, MuJoCo-Warp's finite differences hold each step's Jacobians beside its perturbed
worlds. So training memory grows with envs x horizon, and evaluation (no gradients) with envs alone.
The slopes below are the growth of peak resident memory between two env counts of the same command
(``train --epochs 2`` at the task's horizon, ``eval`` at two ``--num-envs``), rounded down: the
estimate is a lower bound, so what it refuses cannot fit, and what it lets through may still be tight.
The interpreter, torch and the model (about 1 GB here) are not counted. docs/performance.md has the
command that measures them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

MB = 1 << 20


@dataclass(frozen=True)
class Footprint:
    """Bytes one env adds: without gradients; with gradients, once (finite-difference worlds) and per
    step of the window."""

    per_env: float
    per_env_grads: float
    per_env_step: float


# (backend, task) -> measured slopes. A backend or task not listed (a plug-in) gets no estimate.
FOOTPRINTS = {
    ("newton", "ant"): Footprint(per_env=0.15 * MB, per_env_grads=0.0, per_env_step=0.30 * MB),
    ("newton", "go2"): Footprint(per_env=0.3 * MB, per_env_grads=0.0, per_env_step=0.45 * MB),
    ("newton", "soft_jumper"): Footprint(per_env=0.0, per_env_grads=0.0, per_env_step=1.6 * MB),
    ("mujoco_warp", "ant"): Footprint(per_env=0.04 * MB, per_env_grads=3.0 * MB, per_env_step=0.05 * MB),
    ("mujoco_warp", "go2"): Footprint(per_env=0.05 * MB, per_env_grads=5.0 * MB, per_env_step=0.05 * MB),
}


def estimate_bytes(backend: str, task: str, num_envs: int, horizon: int = 0, grads: bool = True) -> float | None:
    """Bytes ``num_envs`` envs need beyond the process's fixed cost; windows of ``horizon`` steps when
    ``grads``. None where nothing was measured."""
    footprint = FOOTPRINTS.get((backend, task.split(".")[0]))
    if footprint is None:
        return None
    grads_part = footprint.per_env_grads + footprint.per_env_step * horizon if grads else 0.0
    return num_envs * (footprint.per_env + grads_part)


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
