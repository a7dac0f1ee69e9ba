"""MuJoCo-Warp adapter (``--backend mujoco_warp``). Importing this package imports mujoco, mujoco_warp and warp."""

from backends import _warp  # noqa: F401  (quiet Warp before the engine initialises it)
from backends.mujoco_warp.adapter import MujocoWarpSim, build_spec, engine_to_generalized, generalized_to_engine

__all__ = ["MujocoWarpSim", "build_spec", "engine_to_generalized", "generalized_to_engine"]
