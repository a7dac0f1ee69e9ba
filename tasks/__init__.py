"""Backend-neutral task definitions, found by name.

Every task, built-in or third-party, is registered through the entry-point group
``diffsim_bench.tasks`` (``name = "pkg.module:TaskClass"`` in the package's pyproject.toml) and
loaded only when asked for. This package never imports ``backends``: tasks and adapters share
only :mod:`simcore`.
"""

from __future__ import annotations

from simcore import PhysicsSpec, PluginRegistry, UnknownNameError
from tasks.base import PhysicsPreset, Task, UnknownPresetError

ENTRY_POINT_GROUP = "diffsim_bench.tasks"
REGISTRY = PluginRegistry(ENTRY_POINT_GROUP, Task, "task")
UnknownTaskError = UnknownNameError

available = REGISTRY.available
task_class = REGISTRY.get


def make_task(name: str, physics: PhysicsSpec | None = None, preset: str | None = None) -> Task:
    """Task ``name`` with its ``preset`` (the task's default when ``None``), or explicit ``physics``."""
    cls = task_class(name)
    if preset and not cls.presets:  # a task without presets may not take the argument at all
        raise UnknownPresetError(f"task {name!r} has no physics presets; got {preset!r}")
    return cls(physics, preset) if preset else cls(physics)


__all__ = [
    "PhysicsPreset",
    "PhysicsSpec",
    "Task",
    "UnknownPresetError",
    "UnknownTaskError",
    "available",
    "make_task",
    "task_class",
]
