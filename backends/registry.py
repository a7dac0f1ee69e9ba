"""Find backend adapters by name.

Built-in adapters and third-party ones are both discovered through the entry-point group
``diffsim_bench.backends``: a package that declares

    [project.entry-points."diffsim_bench.backends"]
    my_engine = "my_package.adapter:MyEngineSim"

becomes available as ``--backend my_engine`` without any edit to this repository. Entry points
are loaded lazily, so listing backends never imports an engine.
"""

from __future__ import annotations

from backends.contract import BatchedSim
from simcore import PluginRegistry, TaskSpec, UnknownNameError

ENTRY_POINT_GROUP = "diffsim_bench.backends"
REGISTRY = PluginRegistry(ENTRY_POINT_GROUP, BatchedSim, "backend")
UnknownBackendError = UnknownNameError

available = REGISTRY.available
get = REGISTRY.get
register = REGISTRY.register


def make(name: str, task: TaskSpec, num_envs: int, device: str = "cpu", seed: int = 0, **options) -> BatchedSim:
    """Instantiate the adapter ``name`` for ``task``."""
    return get(name)(task, num_envs=num_envs, device=device, seed=seed, **options)
