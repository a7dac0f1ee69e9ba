"""Find backend adapters by name.

Built-in adapters and third-party ones are both discovered through the entry-point group
``diffsim_bench.backends``: a package that declares

    [project.entry-points."diffsim_bench.backends"]
    my_engine = "my_package.adapter:MyEngineSim"

becomes available as ``--backend my_engine`` without any edit to this repository. Entry points
are loaded lazily, so listing backends never imports an engine.
"""

from __future__ import annotations

from importlib.metadata import entry_points

from backends.contract import BatchedSim

ENTRY_POINT_GROUP = "diffsim_bench.backends"

# Adapters registered at run time (tests, notebooks); they shadow entry points of the same name.
_runtime: dict[str, type[BatchedSim]] = {}


class UnknownBackendError(KeyError):
    def __init__(self, name: str, choices: list[str]):
        self.name = name
        self.choices = choices
        super().__init__(name)

    def __str__(self) -> str:
        return f"unknown backend {self.name!r}; choose from: {', '.join(self.choices) or '(none registered)'}"


def register(name: str, cls: type[BatchedSim]) -> None:
    """Register an adapter class in-process (entry points are the persistent way)."""
    if not (isinstance(cls, type) and issubclass(cls, BatchedSim)):
        raise TypeError(f"{cls!r} is not a BatchedSim subclass")
    _runtime[name] = cls


def _entry_points() -> dict:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def available() -> list[str]:
    """Names of every registered adapter, sorted."""
    return sorted(set(_entry_points()) | set(_runtime))


def get(name: str) -> type[BatchedSim]:
    """The adapter class registered under ``name``."""
    if name in _runtime:
        return _runtime[name]
    eps = _entry_points()
    if name not in eps:
        raise UnknownBackendError(name, available())
    cls = eps[name].load()
    if not (isinstance(cls, type) and issubclass(cls, BatchedSim)):
        raise TypeError(f"entry point {name!r} -> {cls!r} is not a BatchedSim subclass")
    return cls


def make(name: str, task, num_envs: int, device: str = "cpu", seed: int = 0, **options) -> BatchedSim:
    """Instantiate the adapter ``name`` for ``task`` (a :class:`tasks.base.Task`)."""
    return get(name)(task, num_envs=num_envs, device=device, seed=seed, **options)
