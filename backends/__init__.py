"""Engine adapters behind one contract (:mod:`backends.contract`), found by name (:mod:`backends.registry`).

Engine packages (warp, newton, mujoco, ...) are imported only inside the adapter sub-packages,
and only when an adapter is loaded.
"""

from backends.contract import BackendError, BatchedSim, InvalidActionError, InvalidStateError, NonFiniteStateError
from backends.registry import UnknownBackendError, available, get, make, register
from simcore import ControlKind, SimState, StateLayout

__all__ = [
    "BackendError",
    "BatchedSim",
    "ControlKind",
    "InvalidActionError",
    "InvalidStateError",
    "NonFiniteStateError",
    "SimState",
    "StateLayout",
    "UnknownBackendError",
    "available",
    "get",
    "make",
    "register",
]
