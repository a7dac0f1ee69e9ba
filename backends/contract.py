"""The contract every engine adapter implements.

An adapter is a *batched, differentiable simulator*: ``num_envs`` independent worlds of one
task, advanced together by :meth:`BatchedSim.step`. Everything that crosses this boundary is a
torch tensor in the backend-neutral layout of :class:`SimState`, so algorithms and tasks never
see an engine type.

What an adapter writes (the abstract part, engine-specific):

* :meth:`BatchedSim._build` - build the engine model for ``self.task`` and ``self.num_envs``.
* :meth:`BatchedSim.state_from_generalized` - a :class:`SimState` from generalized coordinates
  (root pose and velocity, joint positions and velocities, optional particles), differentiable.
* :meth:`BatchedSim.simulate` - ``(state, control) -> next state`` for one control step,
  differentiable through torch autograd w.r.t. the incoming state and the control.

What the base class provides once for every adapter (the stateful part):

* :meth:`BatchedSim.reset` - fresh randomised initial states for some or all envs; the reset
  rows are detached, so the graph is cut for those envs only.
* :meth:`BatchedSim.step` - validates actions, maps them to engine controls through the task,
  simulates, and reports non-finite simulation results per env.
* :meth:`BatchedSim.cut_graph` - detach all envs (window boundary) or only some.

State layout (z up, quaternions ``(x, y, z, w)``, everything in the world frame):

* ``joint_q``  (N, nq): ``[root_pos(3), root_quat(4), dof_q(J)]`` for a floating base, else ``dof_q``.
* ``joint_qd`` (N, nv): ``[root_lin_vel(3), root_ang_vel(3), dof_qd(J)]``; the linear velocity is
  that of the root body's centre of mass, the angular velocity is in the world frame.
* ``particle_q``, ``particle_qd`` (N, P, 3): particles of soft bodies (``None`` without any).
* ``engine`` (N, D): the adapter's own full state (maximal coordinates, solver extras), the only
  thing :meth:`simulate` reads. The other fields are views of it, kept consistent by the adapter.
"""

from __future__ import annotations

import dataclasses
import enum
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch

if TYPE_CHECKING:
    from tasks.base import Task


class BackendError(RuntimeError):
    """Base class for errors raised by the backend layer."""


class InvalidActionError(BackendError, ValueError):
    """Actions of the wrong shape or dtype, or with NaN/inf entries."""


class NonFiniteStateError(BackendError, FloatingPointError):
    """The simulation produced NaN or inf for some envs.

    ``env_ids`` lists them, so a caller can reset exactly those worlds.
    """

    def __init__(self, env_ids: list[int], step: int):
        self.env_ids = env_ids
        self.step_index = step
        shown = ", ".join(str(i) for i in env_ids[:16]) + (" ..." if len(env_ids) > 16 else "")
        super().__init__(f"non-finite simulation state in {len(env_ids)} env(s) [{shown}] at step {step}")


class ControlKind(enum.Enum):
    """How a task's control tensor drives the engine."""

    JOINT_TORQUE = "joint_torque"  # (N, J) generalized forces on the actuated dofs
    JOINT_POSITION_TARGET = "joint_position_target"  # (N, J) PD targets, gains in the task's physics spec
    TET_ACTIVATION = "tet_activation"  # (N, T) per-tetrahedron muscle activation of a soft body


@dataclass(frozen=True)
class StateLayout:
    """Static sizes of the backend-neutral state for one env."""

    num_dofs: int  # actuated/articulated degrees of freedom after the root (J)
    floating_base: bool = True
    num_particles: int = 0
    num_tets: int = 0

    @property
    def nq(self) -> int:
        return (7 if self.floating_base else 0) + self.num_dofs

    @property
    def nv(self) -> int:
        return (6 if self.floating_base else 0) + self.num_dofs


@dataclass
class SimState:
    """Batched backend-neutral state; see the module docstring for the layout."""

    joint_q: torch.Tensor
    joint_qd: torch.Tensor
    engine: torch.Tensor
    particle_q: torch.Tensor | None = None
    particle_qd: torch.Tensor | None = None

    # -- views of a floating base ---------------------------------------------------------
    @property
    def root_pos(self) -> torch.Tensor:
        return self.joint_q[:, 0:3]

    @property
    def root_quat(self) -> torch.Tensor:
        return self.joint_q[:, 3:7]

    @property
    def root_lin_vel(self) -> torch.Tensor:
        return self.joint_qd[:, 0:3]

    @property
    def root_ang_vel(self) -> torch.Tensor:
        return self.joint_qd[:, 3:6]

    def dof_q(self, layout: StateLayout) -> torch.Tensor:
        return self.joint_q[:, layout.nq - layout.num_dofs :]

    def dof_qd(self, layout: StateLayout) -> torch.Tensor:
        return self.joint_qd[:, layout.nv - layout.num_dofs :]

    # -- whole-state helpers --------------------------------------------------------------
    def tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if getattr(self, f.name) is not None}

    def map(self, fn) -> SimState:
        """Apply ``fn`` to every tensor field."""
        return SimState(**{k: fn(v) for k, v in self.tensors().items()})

    def detach(self) -> SimState:
        return self.map(torch.Tensor.detach)

    def select(self, env_mask: torch.Tensor, other: SimState) -> SimState:
        """Rows of ``other`` where ``env_mask`` is true, rows of ``self`` elsewhere."""
        mine = self.tensors()
        theirs = other.tensors()
        out = {}
        for name, value in mine.items():
            mask = env_mask.reshape((-1,) + (1,) * (value.dim() - 1))
            out[name] = torch.where(mask, theirs[name], value)
        return SimState(**out)

    def finite_envs(self) -> torch.Tensor:
        """(N,) bool: true where every entry of the env's state is finite."""
        ok = None
        for value in self.tensors().values():
            env_ok = torch.isfinite(value.detach()).reshape(value.shape[0], -1).all(dim=1)
            ok = env_ok if ok is None else ok & env_ok
        return ok


class BatchedSim(ABC):
    """A task simulated in ``num_envs`` worlds; see the module docstring."""

    #: registry name of the adapter, set by subclasses
    name: str = ""
    #: the task the contract test suite (tests/test_contract.py) runs this adapter on
    contract_task: str = "ant"

    def __init__(self, task: Task, num_envs: int, device: str = "cpu", seed: int = 0, **options):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.task = task
        self.num_envs = int(num_envs)
        self.device = torch.device(device)
        self.seed = int(seed)
        self.options = options
        self.generator = torch.Generator(device="cpu").manual_seed(self.seed)
        self.step_count = 0
        self._build()
        self._state: SimState = self._initial_state()

    # -- adapter hooks --------------------------------------------------------------------
    @property
    @abstractmethod
    def layout(self) -> StateLayout:
        """Static layout of one env's state."""

    @abstractmethod
    def _build(self) -> None:
        """Create the engine model for ``self.task`` x ``self.num_envs``."""

    @abstractmethod
    def state_from_generalized(
        self,
        joint_q: torch.Tensor,
        joint_qd: torch.Tensor,
        particle_q: torch.Tensor | None = None,
        particle_qd: torch.Tensor | None = None,
    ) -> SimState:
        """A full state for all envs from generalized coordinates (differentiable)."""

    @abstractmethod
    def simulate(self, state: SimState, control: torch.Tensor) -> SimState:
        """Advance every env by one control step (``task.physics.frame_dt``), differentiably."""

    # -- the shared stateful API ----------------------------------------------------------
    @property
    def state(self) -> SimState:
        return self._state

    @state.setter
    def state(self, value: SimState) -> None:
        self._state = value

    def _initial_state(self) -> SimState:
        """Freshly randomised, detached initial states for all envs (callers pick rows)."""
        with torch.no_grad():
            q, qd = self.task.sample_initial_state(self.num_envs, self.generator)
            return self.state_from_generalized(q.to(self.device), qd.to(self.device)).detach()

    def _env_mask(self, env_ids: torch.Tensor | list[int]) -> torch.Tensor:
        env_ids = torch.as_tensor(env_ids, dtype=torch.long, device=self.device)
        if env_ids.numel() and (env_ids.min() < 0 or env_ids.max() >= self.num_envs):
            raise IndexError(f"env ids must lie in [0, {self.num_envs}), got {env_ids.tolist()}")
        mask = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        mask[env_ids] = True
        return mask

    def reset(self, env_ids: torch.Tensor | list[int] | None = None) -> SimState:
        """Re-initialise some envs (all if ``None``); their graph history is dropped."""
        if env_ids is None:
            self._state = self._initial_state()
        else:
            mask = self._env_mask(env_ids)
            if mask.any():
                self._state = self._state.select(mask, self._initial_state())
        return self._state

    def cut_graph(self, env_ids: torch.Tensor | list[int] | None = None) -> SimState:
        """Drop the autograd history of all envs (``None``: a window boundary) or of some."""
        if env_ids is None:
            self._state = self._state.detach()
        else:
            self._state = self._state.select(self._env_mask(env_ids), self._state.detach())
        return self._state

    def validate_actions(self, actions: torch.Tensor) -> torch.Tensor:
        """Check shape, dtype and finiteness before anything reaches the engine."""
        expected = (self.num_envs, self.task.action_dim)
        if not isinstance(actions, torch.Tensor):
            raise InvalidActionError(f"actions must be a torch.Tensor, got {type(actions).__name__}")
        if tuple(actions.shape) != expected:
            raise InvalidActionError(f"actions must have shape {expected}, got {tuple(actions.shape)}")
        if not actions.is_floating_point():
            raise InvalidActionError(f"actions must be a floating-point tensor, got {actions.dtype}")
        bad = ~torch.isfinite(actions.detach()).all(dim=1)
        if bad.any():
            ids = bad.nonzero().flatten().tolist()
            raise InvalidActionError(f"actions contain NaN or inf for env(s) {ids[:16]}")
        return actions.to(device=self.device, dtype=torch.float32)

    def step(self, actions: torch.Tensor) -> SimState:
        """Apply ``actions`` (N, action_dim) for one control step and return the next state.

        Raises :class:`NonFiniteStateError` naming the envs whose state became NaN/inf; the
        internal state is left at the last finite state so the caller can reset those envs.
        """
        actions = self.validate_actions(actions)
        control = self.task.actions_to_control(actions)
        next_state = self.simulate(self._state, control)
        self.step_count += 1
        finite = next_state.finite_envs()
        if not bool(finite.all()):
            raise NonFiniteStateError((~finite).nonzero().flatten().tolist(), self.step_count)
        self._state = next_state
        return next_state
