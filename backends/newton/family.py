"""What the Newton adapter asks of an engine family: the part of one control step that differs
between articulations on the semi-implicit solver, articulations on Featherstone
(:mod:`backends.newton.articulation`) and soft FEM bodies (:mod:`backends.newton.soft`).

:class:`~backends.newton.adapter.NewtonSim` chooses one family at build time; the frame and tape
machinery (:mod:`backends.newton.tape`) and the bare reference rollout (:mod:`backends.newton.bare`)
call only the methods below, so each job has one path and the differences live in the families.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import TYPE_CHECKING

import newton
import torch
import warp as wp

from backends.contract import option_number
from simcore import SimState

if TYPE_CHECKING:
    from backends.newton.tape import Frame, TorchViews


def semi_implicit_solver(model: newton.Model, options: dict) -> newton.solvers.SolverSemiImplicit:
    """Newton's symplectic Euler solver with the solver's own defaults, exposed as adapter options."""
    return newton.solvers.SolverSemiImplicit(
        model,
        angular_damping=option_number(options, "angular_damping", 0.05, "newton"),
        joint_attach_ke=option_number(options, "joint_attach_ke", 1.0e4, "newton"),
        joint_attach_kd=option_number(options, "joint_attach_kd", 1.0e2, "newton"),
    )


class EngineFamily(ABC):
    """One engine family: how its model is built, which Warp arrays are its state, how its control
    reaches a substep, and how its outputs and their gradients map to torch.

    ``sim`` is the adapter being built (read once: task, envs, options, views). After :meth:`build`
    the family holds ``model``, ``solver`` and ``pipeline``. The abstract methods are what every
    family defines; the hooks whose body is ``return None`` do nothing unless a family needs them.
    """

    #: physics_mapping text of the contact constants (``{name}``: ke, kd, kf, mu) and of the armature
    contact_mapping: str = ""
    armature_mapping: str = ""

    def __init__(self, sim):
        self.task = sim.task
        self.physics = sim.task.physics
        self.layout = sim.task.layout
        self.num_envs = sim.num_envs
        self.device = sim.device
        self.options = sim.options
        self.views: TorchViews = sim.views
        self.model: newton.Model | None = None
        self.solver = None
        self.pipeline: newton.CollisionPipeline | None = None

    # -- construction ---------------------------------------------------------------------
    def build(self, wp_device: str, contact_gap: float, parameter_gradients: bool) -> None:
        """The model for ``num_envs`` worlds (with the ground plane when the spec has one), its
        solver and its collision pipeline."""
        phys = self.physics
        shape_cfg = newton.ModelBuilder.ShapeConfig(
            ke=phys.contact_ke, kd=phys.contact_kd, kf=phys.contact_kf, mu=phys.contact_mu, gap=contact_gap
        )
        builder = self.builder(shape_cfg)
        if phys.ground_plane:
            builder.add_ground_plane(cfg=shape_cfg)
        # The contract differentiates states and controls, never the model's parameters (masses,
        # inertias, gains, contact stiffnesses): a model finalized without gradients makes every adjoint
        # kernel skip its atomic adds into parameter gradients and the tapes skip zeroing them
        # (docs/performance.md, "Newton without parameter gradients"). States, controls, contacts and
        # Featherstone's per-frame matrices ask for gradients explicitly; the solver's remaining
        # model-sized buffers (body inertias and COM frames) depend on parameters only. Option
        # parameter_gradients=1 restores them (as Rewarped builds its models), for A/B measurements;
        # nothing reads them.
        model = builder.finalize(device=wp_device, requires_grad=parameter_gradients)
        self.apply_physics(model)
        self.model = model
        self.solver = self.make_solver(model)
        self.pipeline = self.collision_pipeline(model, contact_gap)
        self.after_build()

    @abstractmethod
    def builder(self, shape_cfg: newton.ModelBuilder.ShapeConfig) -> newton.ModelBuilder:
        """A builder holding every env's bodies (the ground plane is added after)."""

    @abstractmethod
    def apply_physics(self, model: newton.Model) -> None:
        """Write the task's physics constants that the builder does not carry onto the model."""

    @abstractmethod
    def make_solver(self, model: newton.Model):
        """The Newton solver this family integrates with."""

    def collision_pipeline(self, model: newton.Model, contact_gap: float) -> newton.CollisionPipeline:
        return newton.CollisionPipeline(model, requires_grad=True)

    def after_build(self) -> None:
        """Anything that needs the finished model and solver (control buffers, checks)."""
        return None

    # -- engine rows <-> Warp state -------------------------------------------------------
    @abstractmethod
    def state_arrays(self, state: newton.State) -> tuple[wp.array, wp.array]:
        """The solver state's own variables, the two halves of an engine row."""

    @abstractmethod
    def engine_split(self) -> int:
        """Columns of an engine row that belong to the first of the two state arrays."""

    def join_engine(self, a: wp.array, b: wp.array) -> torch.Tensor:
        """A new (N, D) tensor holding two of the adapter's own (frame) arrays side by side."""
        return torch.cat((self.views(a), self.views(b)), dim=1)

    def load_state(self, state: newton.State, engine: torch.Tensor, cache: bool = True, complete: bool = True) -> None:
        """Copy engine rows into ``state`` (``cache=False`` for arrays the adapter does not own).

        ``complete=False`` leaves :meth:`complete_loaded_state` to the caller: the frame stepper runs it
        inside the step's own Warp work, so that a captured step replays it from C++ instead of
        launching it from Python every step (``backends/newton/tape.py``)."""
        a, b = self.state_arrays(state)
        k = self.engine_split()
        with torch.no_grad():
            self.views(a, cache).copy_(engine[:, :k])
            self.views(b, cache).copy_(engine[:, k:])
        if complete:
            self.complete_loaded_state(state)

    def complete_loaded_state(self, state: newton.State) -> None:
        """Derive what the collision pipeline reads but the engine row does not hold (default: nothing)."""
        return None

    @abstractmethod
    def state_from_generalized(self, joint_q, joint_qd, particle_q, particle_qd) -> SimState:
        """The adapter's ``state_from_generalized`` (input already checked)."""

    @abstractmethod
    def sim_state(self, engine: torch.Tensor, joint_q: torch.Tensor, joint_qd: torch.Tensor) -> SimState:
        """The :class:`SimState` of one step's outputs."""

    # -- one control step -----------------------------------------------------------------
    def add_frame_buffers(self, frame: Frame) -> None:
        """Add the family's own per-frame buffers to ``frame`` (as attributes); default none."""
        return None

    @abstractmethod
    def control_array(self, frame: Frame) -> wp.array:
        """Where a frame's control tensor goes (joint forces, PD targets or tet activations)."""

    @abstractmethod
    def substep_control(self, state: newton.State, frame: Frame, s: int) -> newton.Control:
        """The control of substep ``s`` (on the tape: a kernel may compute it from ``state``)."""

    def substep(
        self, state_in: newton.State, state_out: newton.State, frame: Frame, s: int, tape: wp.Tape | None = None
    ) -> None:
        """One solver step of ``frame``'s control step; ``tape`` is the frame's, when it records."""
        state_in.clear_forces()
        self.before_substep(frame, s)
        control = self.substep_control(state_in, frame, s)
        self.solver.step(state_in, state_out, control, frame.contacts, self.physics.sim_dt)
        if tape is not None:
            self.after_taped_substep(tape, state_out)

    def before_substep(self, frame: Frame, s: int) -> None:
        """Point the solver at the frame's own buffers for substep ``s`` (default: nothing to point)."""
        return None

    def after_taped_substep(self, tape: wp.Tape, state: newton.State) -> None:
        """Record on ``tape`` whatever its replay of the substep needs (default: nothing)."""
        return None

    def finish_step(self, frame: Frame, last: newton.State) -> None:
        """After the last substep (on the tape when it records): derive the step's joint outputs."""
        return None

    def outputs(self, frame: Frame, last: newton.State) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(engine rows, joint_q, joint_qd) of a step that ended in ``last``; new tensors."""
        engine = self.join_engine(*self.state_arrays(last))
        return (engine, *self.joint_outputs(frame, engine))

    @abstractmethod
    def joint_outputs(self, frame: Frame, engine: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The step's joint_q, joint_qd."""

    @abstractmethod
    def output_seeds(self, frame: Frame, grad_engine, grad_q, grad_qd) -> list[tuple[wp.array, torch.Tensor]]:
        """The incoming gradients of :meth:`outputs`, paired with the frame arrays they seed."""

    def engine_seeds(self, last: newton.State, grad_engine) -> list[tuple[wp.array, torch.Tensor]]:
        if grad_engine is None:
            return []
        a, b = self.state_arrays(last)
        k = self.engine_split()
        return [(a, grad_engine[:, :k]), (b, grad_engine[:, k:])]

    # -- the bare reference rollout (backends.newton.bare) ----------------------------------
    @abstractmethod
    def bare_controls(self, horizon: int, rng, grad: bool, current: SimState):
        """Controls for a bare window of ``horizon`` steps: a function ``(t, s, state) -> Control`` for
        step ``t``, substep ``s`` (counted over the window) starting from ``state``."""

    @abstractmethod
    def bare_loss(self, state: newton.State, loss: wp.array) -> None:
        """Add the sum of the state's positions (bodies or particles) to ``loss``."""
