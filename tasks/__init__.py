"""Backend-neutral task definitions, found by name.

Built-in tasks are listed in ``TASKS``; third-party packages add tasks through the entry-point
group ``diffsim_bench.tasks`` (``name = "pkg.module:TaskClass"``), loaded only when asked for.
"""

from __future__ import annotations

from importlib.metadata import entry_points

from tasks.ant import Ant
from tasks.base import PhysicsSpec, Task

TASKS: dict[str, type[Task]] = {"ant": Ant}
ENTRY_POINT_GROUP = "diffsim_bench.tasks"


class UnknownTaskError(KeyError):
    def __init__(self, name: str):
        self.name = name
        super().__init__(name)

    def __str__(self) -> str:
        return f"unknown task {self.name!r}; choose from: {', '.join(available())}"


def _entry_points() -> dict:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def available() -> list[str]:
    """Names of every task, built-in and plugged in, sorted."""
    return sorted(set(TASKS) | set(_entry_points()))


def task_class(name: str) -> type[Task]:
    if name in TASKS:
        return TASKS[name]
    eps = _entry_points()
    if name not in eps:
        raise UnknownTaskError(name)
    cls = eps[name].load()
    if not (isinstance(cls, type) and issubclass(cls, Task)):
        raise TypeError(f"entry point {name!r} -> {cls!r} is not a Task subclass")
    return cls


def make_task(name: str, physics: PhysicsSpec | None = None) -> Task:
    return task_class(name)(physics)


__all__ = ["TASKS", "PhysicsSpec", "Task", "UnknownTaskError", "available", "make_task", "task_class"]
