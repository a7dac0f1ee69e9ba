"""Newton adapter: exact gradients from ``wp.Tape`` wrapped in ``torch.autograd.Function``.

:class:`NewtonSim` is the one registered class. At build time it picks one engine family
(:class:`~backends.newton.family.EngineFamily`) from the task's control kind and the ``solver``
option, and everything family-specific goes through it:

* :mod:`backends.newton.articulation`: articulated assets on ``SolverSemiImplicit`` (symplectic
  Euler in maximal coordinates with penalty joints and penalty contacts; no rotor inertia, so a
  non-zero armature is refused) or on ``SolverFeatherstone`` (generalized coordinates, what MuJoCo
  integrates; the Ant's and the Go2's physics presets select it through their ``backend_options``:
  the semi-implicit solver's joints stretch under the Ant's weight, and it goes non-finite on the
  Go2 in the first step); joint torques or joint position targets (the PD law on the tape).
* :mod:`backends.newton.soft`: soft FEM bodies (``TET_ACTIVATION`` tasks, the SoftJumper) on the
  semi-implicit solver.

What every family shares: the frames, tapes and graph capture of :mod:`backends.newton.tape` (how
gradients stay exact, and why a repeated backward pass returns the same gradient), and the bare
reference rollout of :mod:`backends.newton.bare`. The model is finalized without parameter
gradients (the contract has none): states, controls and contacts carry gradients, masses and gains
do not, so the adjoint kernels skip their parameter accumulators. Gradients with respect to states
and controls are bit-identical either way (tests/test_newton_ant.py).
"""

from __future__ import annotations

import torch

from backends._warp import option_flag, warp_device
from backends.contract import MIB, BackendError, BatchedSim, TaskCost, inert_by_definition, option_number
from backends.newton.articulation import FeatherstoneArticulation, SemiImplicitArticulation
from backends.newton.bare import bare_tape_rollout
from backends.newton.family import EngineFamily
from backends.newton.soft import SoftBody
from backends.newton.tape import FrameStepper, TorchViews
from simcore import ControlKind, SimState, StateLayout

#: the articulation family of each ``solver`` option
ARTICULATIONS = {"semi_implicit": SemiImplicitArticulation, "featherstone": FeatherstoneArticulation}


class NewtonSim(BatchedSim):
    """A task on Newton; see the module docstring.

    ``max_graph_steps`` (a contract argument) frames stay replayable. Options: ``solver``
    (``"semi_implicit"``, the default, or ``"featherstone"``); ``contact_gap`` (default 0.05 m)
    contact-candidate distance; ``mass_matrix_every`` (Featherstone: substeps between mass-matrix
    rebuilds, default all of a control step's); for the semi-implicit solver ``angular_damping``
    (default 0.05), ``joint_attach_ke`` (1e4) and ``joint_attach_kd`` (1e2): the solver's own
    defaults, exposed for experiments; ``parameter_gradients`` (0, the default, or 1): build the
    model with gradient buffers for its parameters, which no output of the contract uses (for A/B
    timing against the default); ``graph_capture`` (0 or 1, default 1 on CPU).
    Control kinds: joint torques, joint position targets through the PD law of the task's physics
    spec (evaluated at every substep inside the tape), and tet activations.

    Engine state per env: ``[body_q, body_qd]`` of every body (maximal coordinates) for the
    semi-implicit solver; ``[joint_q, joint_qd]`` (generalized coordinates, the neutral layout
    itself) for Featherstone, whose state they are; ``[particle_q, particle_qd]`` for a soft body.

    After build: ``family`` (the engine family), ``model``, ``solver``, ``pipeline`` (its Newton
    objects) and ``stepper`` (its frames: ``stepper.frames``, ``stepper.scratch``).
    """

    name = "newton"
    contract_tasks = ("ant", "go2", "soft_jumper")
    known_options = (
        "solver",
        "contact_gap",
        "mass_matrix_every",
        "angular_damping",
        "joint_attach_ke",
        "joint_attach_kd",
        "parameter_gradients",
        "graph_capture",
    )
    SOLVERS = tuple(ARTICULATIONS)
    table_rank = 0  # the reference engine: first in every table
    # Planning figures on a 2-core CPU: training from the runs in results/ (docs/cluster.md; the Go2's at
    # 64 envs from its throughput against the Ant's), evaluation from the protocol's evaluations, memory
    # from the growth of peak resident memory between two env counts (docs/performance.md).
    costs = {
        "ant": TaskCost(train_s=1.2e-3, eval_s=1.25e-4, bytes_per_env=(0.15 * MIB, 0.0, 0.30 * MIB)),
        "go2": TaskCost(train_s=2.5e-3, eval_s=2.3e-4, bytes_per_env=(0.3 * MIB, 0.0, 0.45 * MIB)),
        "soft_jumper": TaskCost(train_s=2e-2, eval_s=4e-3, bytes_per_env=(0.0, 0.0, 1.6 * MIB)),
    }

    # -- construction ---------------------------------------------------------------------
    def _build(self) -> None:
        # a candidate window of at most a metre: past it every pair of the scene is a candidate
        contact_gap = option_number(self.options, "contact_gap", 0.05, self.name, low=0.0, high=1.0)
        solver = self.options.get("solver", "semi_implicit")
        if solver not in self.SOLVERS:
            raise BackendError(f"newton solver must be one of {', '.join(self.SOLVERS)}, got {solver!r}")
        self.wp_device = warp_device(self.device)
        self.graph_capture = option_flag(self.options, "graph_capture", self.device.type == "cpu", self.name)
        self.views = TorchViews(self.num_envs)
        self.family = self._family(solver)
        parameter_gradients = option_flag(self.options, "parameter_gradients", False, self.name)
        self.family.build(self.wp_device, contact_gap, parameter_gradients)
        self.model, self.solver, self.pipeline = self.family.model, self.family.solver, self.family.pipeline
        self.stepper = FrameStepper(self.family, self.max_graph_steps, self.graph_capture, self.wp_device)

    def _family(self, solver: str) -> EngineFamily:
        """The engine family for this task: a soft body (tet activations) or an articulation on ``solver``."""
        if self.task.control_kind == ControlKind.TET_ACTIVATION:
            return SoftBody(self, solver)
        return ARTICULATIONS[solver](self)

    @property
    def integrator(self) -> str:
        return f"newton {type(self.solver).__name__}"

    def physics_mapping(self) -> dict[str, str]:
        """How each :class:`PhysicsSpec` field reaches Newton (see :meth:`BatchedSim.physics_mapping`)."""
        mapping = {
            "frame_dt": "one control step = substeps solver steps of frame_dt / substeps",
            "substeps": "solver.step calls per control step",
            "gravity": "ModelBuilder(gravity=(0, 0, gravity))",
            "ground_plane": "ModelBuilder.add_ground_plane (z-up, through the origin)",
        }
        for name in ("ke", "kd", "kf", "mu"):
            mapping[f"contact_{name}"] = self.family.contact_mapping.format(name=name)
        mapping["joint_limit_ke"] = "model.joint_limit_ke on every articulated dof, as given (N m / rad)"
        mapping["joint_limit_kd"] = "model.joint_limit_kd on every articulated dof, as given (N m s / rad)"
        mapping["joint_damping"] = "model.joint_damping on every articulated dof, as given (N m s / rad)"
        mapping["armature"] = self.family.armature_mapping
        for name in ("pd_kp", "pd_kd", "torque_limits"):
            mapping[name] = "the PD kernel on the tape, every substep (PhysicsSpec.pd_torque)"
        mapping.update(inert_by_definition(self.task))
        return mapping

    @property
    def layout(self) -> StateLayout:
        return self.task.layout

    # -- the contract ---------------------------------------------------------------------
    def state_from_generalized(self, joint_q, joint_qd, particle_q=None, particle_qd=None) -> SimState:
        return self.family.state_from_generalized(joint_q, joint_qd, particle_q, particle_qd)

    def simulate(self, state: SimState, control: torch.Tensor) -> SimState:
        engine, joint_q, joint_qd = self.stepper.step(state.engine, self.engine_control(control))
        return self.family.sim_state(engine, joint_q, joint_qd)

    def _control_joint_torque(self, control: torch.Tensor) -> torch.Tensor:
        """JOINT_TORQUE: generalized forces for every dof, zero on the free root, the control on the rest."""
        root = self.layout.nv - self.layout.num_dofs
        return torch.nn.functional.pad(control, (root, 0))

    def _control_joint_position_target(self, control: torch.Tensor) -> torch.Tensor:
        """JOINT_POSITION_TARGET: the (N, J) targets; the PD law runs per substep on the tape."""
        expected = (self.num_envs, self.layout.num_dofs)
        if tuple(control.shape) != expected:
            raise BackendError(f"position targets must have shape {expected}, got {tuple(control.shape)}")
        return control

    def _control_tet_activation(self, control: torch.Tensor) -> torch.Tensor:
        """TET_ACTIVATION: (N, T) activations, one per tet of each env's body."""
        expected = (self.num_envs, self.layout.num_tets)
        if tuple(control.shape) != expected:
            raise BackendError(f"tet activations must have shape {expected}, got {tuple(control.shape)}")
        return control

    def bare_engine_rollout(self, horizon: int, grad: bool = True) -> float:
        """Seconds per window on raw Newton/Warp, forward+backward or forward only (:func:`bare_tape_rollout`)."""
        return bare_tape_rollout(self, horizon, grad=grad)
