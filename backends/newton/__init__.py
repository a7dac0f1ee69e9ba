"""Newton adapter (``--backend newton``). Importing this package imports warp and newton."""

from backends.newton.adapter import NewtonSim

__all__ = ["NewtonSim"]
