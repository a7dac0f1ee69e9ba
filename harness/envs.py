"""The one place the harness builds adapters and envs (so graph depth and seeding are set once)."""

from __future__ import annotations

import backends
from simcore import PhysicsSpec
from tasks import make_task
from tasks.env import TaskEnv


def make_sim(backend: str, task, num_envs: int, device: str = "cpu", seed: int = 0, horizon: int = 32, **options):
    """Adapter ``backend`` for ``task`` with adapter ``options``; backward passes reach at most
    ``horizon`` steps (one window)."""
    return backends.make(backend, task, num_envs=num_envs, device=device, seed=seed, max_graph_steps=horizon, **options)


def make_env(
    task_name: str,
    backend: str,
    num_envs: int,
    device: str = "cpu",
    seed: int = 0,
    horizon: int = 32,
    physics: PhysicsSpec | None = None,
) -> TaskEnv:
    task = make_task(task_name, physics)
    return TaskEnv(task, make_sim(backend, task, num_envs, device, seed, horizon))
