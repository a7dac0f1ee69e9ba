"""Backend-neutral task definitions, found by name."""

from __future__ import annotations

from tasks.ant import Ant
from tasks.base import PhysicsSpec, Task

TASKS: dict[str, type[Task]] = {"ant": Ant}


class UnknownTaskError(KeyError):
    def __init__(self, name: str):
        self.name = name
        super().__init__(name)

    def __str__(self) -> str:
        return f"unknown task {self.name!r}; choose from: {', '.join(sorted(TASKS))}"


def make_task(name: str, physics: PhysicsSpec | None = None) -> Task:
    if name not in TASKS:
        raise UnknownTaskError(name)
    return TASKS[name](physics)


__all__ = ["TASKS", "PhysicsSpec", "Task", "UnknownTaskError", "make_task"]
