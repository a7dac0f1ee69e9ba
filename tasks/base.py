"""What a task is, independent of any engine.

A :class:`Task` owns everything that defines the learning problem: the asset the engines load,
the physical constants they must honour (:class:`PhysicsSpec`), how policy actions become engine
controls, the initial-state distribution, and observation, reward and termination, all written
in torch over the backend-neutral :class:`simcore.SimState`. Adapters read the asset
and the physics spec; they never see observations or rewards.
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import torch

from simcore import ControlKind, PhysicsSpec, SimState, SoftBodySpec, StateLayout, quat_from_angle_axis, quat_mul

ASSET_DIR = Path(__file__).resolve().parent / "assets"


class UnknownPresetError(ValueError):
    """A physics preset the task does not define; the message lists the ones it does."""


@dataclass(frozen=True)
class PhysicsPreset:
    """A named physical setup of a task: its constants, the engine settings it was validated with
    (``simcore.TaskSpec.backend_options``), and the asset when it is not the task's own."""

    physics: PhysicsSpec
    backend_options: Mapping[str, Mapping[str, object]] = field(default_factory=dict)
    asset_path: Path | None = None
    about: str = ""  # one line: where the constants come from


class Task(ABC):
    """A backend-neutral task definition. Subclasses set the class attributes below.

    A task with ``presets`` is built from one of them by name (``default_preset`` when none is
    given); explicit ``physics`` replaces the preset's constants and keeps its engine settings and
    asset, and the task then reports its preset as ``NAME+custom`` (:attr:`preset_label`).
    """

    name: str = ""
    asset_path: Path
    asset_format: str = "mjcf"  # "mjcf" | "urdf" | "tetmesh" (see simcore.TaskSpec)
    layout: StateLayout
    control_kind: ControlKind = ControlKind.JOINT_TORQUE
    action_dim: int
    obs_dim: int
    episode_length: int = 1000
    #: root height (m) at which a short rollout never touches the ground (contact-free gradient checks)
    airborne_height: float = 2.0
    backend_options: dict[str, dict[str, object]] = {}  # see simcore.TaskSpec.backend_options
    soft_body: SoftBodySpec | None = None  # TET_ACTIVATION tasks: the soft body (simcore.SoftBodySpec)
    #: named physical setups (:class:`PhysicsPreset`); none: ``physics`` or ``PhysicsSpec()`` as given
    presets: Mapping[str, PhysicsPreset] = {}
    default_preset: str = ""

    def __init__(self, physics: PhysicsSpec | None = None, preset: str | None = None):
        self.preset = preset or self.default_preset
        limits = physics.torque_limits if physics is not None else ()
        if limits and len(limits) != self.layout.num_dofs:
            count, joints = len(limits), self.layout.num_dofs
            raise ValueError(f"PhysicsSpec.torque_limits has {count} limits; task {self.name!r} has {joints} joints")
        if not self.presets:
            if preset:
                raise UnknownPresetError(f"task {self.name!r} has no physics presets; got {preset!r}")
            self.physics = physics or PhysicsSpec()
            self.preset_label = "custom"
            return
        if self.preset not in self.presets:
            raise UnknownPresetError(
                f"task {self.name!r} has no physics preset {self.preset!r}; choose from: {', '.join(self.presets)}"
            )
        chosen = self.presets[self.preset]
        self.physics = physics or chosen.physics
        self.backend_options = {name: dict(values) for name, values in chosen.backend_options.items()}
        if chosen.asset_path is not None:
            self.asset_path = chosen.asset_path
        self.preset_label = self.preset if self.physics == chosen.physics else f"{self.preset}+custom"

    def physics_record(self) -> dict:
        """What a result file says about the physics it rests on: preset, constants, engine settings."""
        return {
            "preset": self.preset_label,
            "physics": dataclasses.asdict(self.physics),
            "backend_options": {name: dict(values) for name, values in self.backend_options.items()},
            "asset": self.asset_path.name if hasattr(self, "asset_path") else None,
        }

    @abstractmethod
    def sample_initial_state(self, num_envs: int, generator: torch.Generator) -> tuple[torch.Tensor, ...]:
        """Randomised initial coordinates: ``joint_q`` (N, nq), ``joint_qd`` (N, nv), then for tasks with
        particles ``particle_q``, ``particle_qd`` (N, P, 3) (see ``simcore.TaskSpec``)."""

    @abstractmethod
    def actions_to_control(self, actions: torch.Tensor) -> torch.Tensor:
        """Map policy actions (N, action_dim) to the engine control tensor (differentiable)."""

    @abstractmethod
    def observe(self, state: SimState, prev_actions: torch.Tensor) -> torch.Tensor:
        """Observation (N, obs_dim)."""

    @abstractmethod
    def reward(
        self, state: SimState, obs: torch.Tensor, actions: torch.Tensor, prev_actions: torch.Tensor
    ) -> torch.Tensor:
        """Reward (N,) for the transition that produced ``state`` under ``actions``; ``prev_actions``
        are those of the step before (zeros after a reset), for action-rate terms."""

    @abstractmethod
    def terminated(self, state: SimState, obs: torch.Tensor) -> torch.Tensor:
        """(N,) bool: the episode ends here (no bootstrap)."""

    def forward_velocity(self, state: SimState) -> torch.Tensor | None:
        """(N,) velocity along world +x in m/s, the direction every task here rewards moving in: the
        root's centre of mass for a floating base (None for a task without one, unless it says
        otherwise). Evaluations report its mean over each first episode, which says whether a policy
        moves forward at all in units that do not depend on the reward's terms."""
        return state.root_lin_vel[:, 0] if self.layout.floating_base else None


def floating_base_pose(height: float, dof_q: tuple[float, ...]) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalized coordinates of a floating-base robot at rest: root at ``(0, 0, height)``, upright,
    joints at ``dof_q``; and zero velocities."""
    q = torch.tensor((0.0, 0.0, height, 0.0, 0.0, 0.0, 1.0) + tuple(dof_q))
    return q, torch.zeros(6 + len(dof_q))


def symmetric_uniform(generator: torch.Generator, *shape: int) -> torch.Tensor:
    """Samples of U(-1, 1) from ``generator``."""
    return 2.0 * torch.rand(*shape, generator=generator) - 1.0


def random_tilt(quat: torch.Tensor, max_angle: float, generator: torch.Generator) -> torch.Tensor:
    """``quat`` (N, 4) turned in its own frame by U(-max_angle, max_angle) about a random axis
    (the angle is drawn first, then the axis)."""
    n = quat.shape[0]
    angle = max_angle * symmetric_uniform(generator, n)
    axis = torch.nn.functional.normalize(symmetric_uniform(generator, n, 3), dim=-1)
    return quat_mul(quat, quat_from_angle_axis(angle, axis))


__all__ = [
    "ASSET_DIR",
    "PhysicsPreset",
    "PhysicsSpec",
    "Task",
    "UnknownPresetError",
    "floating_base_pose",
    "random_tilt",
    "symmetric_uniform",
]
