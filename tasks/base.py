"""What a task is, independent of any engine.

A :class:`Task` owns everything that defines the learning problem: the asset the engines load,
the physical constants they must honour (:class:`PhysicsSpec`), how policy actions become engine
controls, the initial-state distribution, and observation, reward and termination, all written
in torch over the backend-neutral :class:`backends.contract.SimState`. Adapters read the asset
and the physics spec; they never see observations or rewards.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path

import torch

from backends.contract import ControlKind, SimState, StateLayout

ASSET_DIR = Path(__file__).resolve().parent / "assets"


@dataclass(frozen=True)
class PhysicsSpec:
    """Engine-neutral physical constants of a task; every adapter must apply them."""

    frame_dt: float = 1.0 / 60.0  # one control step
    substeps: int = 16  # integrator steps per control step
    gravity: float = -9.81  # along z
    ground_plane: bool = True  # a z-up plane through the origin
    contact_ke: float = 4.0e4  # penalty contact: normal stiffness
    contact_kd: float = 1.0e3  # normal damping (1e4 makes the adjoint blow up: README)
    contact_kf: float = 3.0e2  # tangential (friction) slope; 3e3 makes policy-driven adjoints explode (README)
    contact_mu: float = 0.75  # Coulomb friction coefficient
    joint_limit_ke: float = 1.0e3
    joint_limit_kd: float = 1.0e1
    joint_damping: float = 1.0  # passive viscous damping on articulated dofs
    pd_ke: float = 0.0  # gains for ControlKind.JOINT_POSITION_TARGET
    pd_kd: float = 0.0

    @property
    def sim_dt(self) -> float:
        return self.frame_dt / self.substeps


class Task(ABC):
    """A backend-neutral task definition. Subclasses set the class attributes below."""

    name: str = ""
    asset_path: Path
    asset_format: str = "mjcf"  # "mjcf" | "urdf" | "tetmesh"
    layout: StateLayout
    control_kind: ControlKind = ControlKind.JOINT_TORQUE
    action_dim: int
    obs_dim: int
    episode_length: int = 1000

    def __init__(self, physics: PhysicsSpec | None = None):
        self.physics = physics or PhysicsSpec()

    @abstractmethod
    def sample_initial_state(self, num_envs: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Randomised generalized initial coordinates: ``joint_q`` (N, nq), ``joint_qd`` (N, nv)."""

    @abstractmethod
    def actions_to_control(self, actions: torch.Tensor) -> torch.Tensor:
        """Map policy actions (N, action_dim) to the engine control tensor (differentiable)."""

    @abstractmethod
    def observe(self, state: SimState, prev_actions: torch.Tensor) -> torch.Tensor:
        """Observation (N, obs_dim)."""

    @abstractmethod
    def reward(self, state: SimState, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """Reward (N,) for the transition that produced ``state``."""

    @abstractmethod
    def terminated(self, state: SimState, obs: torch.Tensor) -> torch.Tensor:
        """(N,) bool: the episode ends here (no bootstrap)."""
