"""The one place the harness builds adapters and envs (so graph depth and seeding are set once)."""

from __future__ import annotations

import functools

import backends
from simcore import PhysicsSpec
from tasks import make_task
from tasks.env import TaskEnv


def make_sim(backend: str, task, num_envs: int, device: str = "cpu", seed: int = 0, horizon: int = 32, **options):
    """Adapter ``backend`` for ``task`` with adapter ``options``; backward passes reach at most
    ``horizon`` steps (one window)."""
    return backends.make(backend, task, num_envs=num_envs, device=device, seed=seed, max_graph_steps=horizon, **options)


def make_env(
    task,
    backend: str,
    num_envs: int,
    device: str = "cpu",
    seed: int = 0,
    horizon: int = 32,
    physics: PhysicsSpec | None = None,
    options: dict | None = None,
) -> TaskEnv:
    """An env of ``task`` (a :class:`tasks.Task`, or a task name with optional ``physics``); ``options``:
    the adapter's explicit options (``--backend-option``)."""
    if isinstance(task, str):
        task = make_task(task, physics)
    return TaskEnv(task, make_sim(backend, task, num_envs, device, seed, horizon, **(options or {})))


def device_problem(device: str) -> str | None:
    """Why this machine cannot run on ``device`` (a phrase), or None: cpu, or cuda[:N] where CUDA exists."""
    import torch

    try:
        parsed = torch.device(device)
    except (RuntimeError, ValueError):
        return f"unknown device {device!r}; use cpu or cuda[:N]"
    if parsed.type not in ("cpu", "cuda"):
        return f"device {device!r} is not supported; use cpu or cuda[:N]"
    if parsed.type == "cpu" and parsed.index not in (None, 0):
        return f"device {device!r}: the CPU is one device here (its cores are used by processes); use cpu"
    if parsed.type == "cuda" and not torch.cuda.is_available():
        return f"device {device!r}: this machine has no CUDA device; use cpu"
    if parsed.type == "cuda" and (parsed.index or 0) >= torch.cuda.device_count():
        return f"device {device!r}: this machine has {torch.cuda.device_count()} CUDA device(s)"
    return None


PHYSICS_RENAMED = {"pd_ke": "pd_kp"}  # physics constants of older config.json files, under today's names


def physics_fields(recorded: dict) -> dict:
    """A run's recorded physics constants, as PhysicsSpec fields (lists back to tuples; old names mapped)."""
    return {PHYSICS_RENAMED.get(k, k): tuple(v) if isinstance(v, list) else v for k, v in recorded.items()}


def run_task(config: dict, physics: PhysicsSpec | None = None):
    """The task a run was made with, from its config.json: the recorded preset (engine settings and
    asset) and constants, or ``physics`` instead of the constants. A run from before physics presets
    recorded no engine settings and is refused in one line rather than rebuilt on today's defaults."""
    from harness.results import RunError
    from tasks import task_class

    record = config.get("physics_record")
    if not record:
        raise RunError(
            f"the {config.get('task')!r} run predates physics presets: its engine settings are not recorded, "
            "and today's defaults may differ; train it again"
        )
    has_presets = bool(getattr(task_class(config["task"]), "presets", {}))
    preset = record["preset"].split("+")[0] if has_presets else None
    physics = physics or PhysicsSpec(**physics_fields(config["physics"]))
    return make_task(config["task"], physics, preset=preset)


@functools.cache
def engine_rank(name: str) -> int | None:
    """Where an installed engine's adapter asks to be listed (``table_rank``: the reference engine 0),
    or None for a name that is no engine here or cannot load."""
    if name not in backends.available():
        return None
    try:
        return int(backends.get(name).table_rank)
    except Exception:  # an adapter that cannot load here is named by the verb that builds it
        return None


def engines_for(task: str) -> list[str]:
    """The installed engines whose adapters drive ``task``'s control kind, in table order."""
    from tasks import task_class

    kind = task_class(task.split(".")[0]).control_kind
    ranked = sorted((r, name) for name in backends.available() if (r := engine_rank(name)) is not None)
    return [name for _, name in ranked if kind in backends.get(name).supported_control_kinds()]
