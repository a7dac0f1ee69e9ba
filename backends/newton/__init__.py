"""Newton adapter (``--backend newton``). Importing this package imports warp and newton."""

from backends import _warp  # noqa: F401  (quiet Warp before the engine initialises it)
from backends.newton.adapter import NewtonSim

__all__ = ["NewtonSim"]
