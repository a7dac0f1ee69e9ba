"""Newton adapter: exact gradients from ``wp.Tape`` wrapped in ``torch.autograd.Function``.

Solvers (option ``solver``): :class:`newton.solvers.SolverSemiImplicit` by default (symplectic Euler
in maximal coordinates with penalty joints and penalty contacts; it has no rotor inertia, so a
non-zero armature is refused), or :class:`newton.solvers.SolverFeatherstone` (generalized
coordinates, what MuJoCo integrates; the Ant's and the Go2's physics presets select it through their
``backend_options``: the semi-implicit solver's joints stretch under the Ant's weight, and it goes
non-finite on the Go2 in the first step). Soft bodies
(``TET_ACTIVATION`` tasks, the SoftJumper) are particles and Neo-Hookean tets on the semi-implicit
solver, one body per env scaled to the env's size (``SoftBodySpec``), activations written to
``control.tet_activations``; particle-particle contact is off.

How gradients stay exact:

* One control step is one :class:`_Frame`: ``substeps + 1`` fresh ``State`` buffers, its own
  control and contact buffers, and its own tape. Nothing in a frame is overwritten while the
  torch graph that references it may still call ``backward``, so the tape replays the data it
  recorded.
* Frames live in a ring of ``max_graph_steps`` (grown lazily). A backward that reaches a frame
  already reused by a later step raises instead of returning a wrong gradient; cut the graph at
  window boundaries (``cut_graph()``) or raise ``max_graph_steps``.
* Contact candidates are found once per control step outside the tape (not differentiated:
  which pairs touch is discrete); contact forces are re-evaluated from the current body poses at
  every substep inside the tape. A contact gap of ``contact_gap`` metres keeps candidates valid
  for the motion within one control step.
* Featherstone keeps its system matrices in solver-owned buffers that every step overwrites; each
  frame owns a copy the solver is pointed at (``_Frame.matrices``), rebuilt once per control step
  by default (``mass_matrix_every``).
* ``JOINT_POSITION_TARGET``: the PD law runs as a kernel on the tape before every substep, reading
  that substep's joint coordinates and writing that substep's own ``joint_f``.
* A tape's backward pass is not read-only: replaying Featherstone's kernels rewrites some of their
  forward outputs in place (the joint forces and accelerations, the external wrenches), so a second
  backward through the same frame would replay from changed values and return a different, wrong
  gradient. Before every backward after a frame's first, the frame's forward runs again from its
  own (unchanged) inputs, so ``retain_graph`` backward passes all return the first one's gradient.
* Without grad (``torch.no_grad()`` or inputs that need none) the step runs without a tape on
  two ping-pong buffers.
* Graph capture (option ``graph_capture``, on by default on CPU): a frame's Warp work (collision,
  substeps, IK; then its tape's backward pass and the zeroing of its gradients) is captured once,
  the second time the frame is used, and replayed with ``wp.capture_launch`` ever after. Warp's
  Python-side launch path (argument packing, tape bookkeeping) costs ~80 us per kernel launch on
  this CPU, about as much as the kernels themselves at 64 Ant envs; the replay runs the same
  kernels on the same buffers from C++. A frame's buffers never change identity, so its graphs
  stay valid; what changes per step (the state and control tensors, the incoming gradients) is
  copied into those buffers outside the graphs. Outputs and gradients are bit-identical to the
  uncaptured path (tests/test_newton_ant.py).
* The model is finalized without parameter gradients (the contract has no parameter gradients):
  states, controls and contacts carry gradients, masses and gains do not, so the adjoint kernels
  skip their parameter accumulators. Gradients with respect to states and controls are bit-identical
  either way (tests/test_newton_ant.py).
"""

from __future__ import annotations

import contextlib
import warnings

import newton
import numpy as np
import torch
import warp as wp

from backends._warp import option_flag, warp_device
from backends.contract import BackendError, BatchedSim, inert_by_definition
from simcore import ControlKind, SimState, StateLayout

_POSE = 7  # wp.transform: position (3) + quaternion xyzw (4)


class _Frame:
    """Every Warp buffer one control step touches, so its tape can be replayed later."""

    def __init__(self, sim: NewtonSim, num_states: int):
        model = sim.model
        self.states = [model.state(requires_grad=True) for _ in range(num_states)]
        self.control = model.control(requires_grad=True)  # JOINT_TORQUE: one joint_f for the whole step
        self.contacts = sim.pipeline.contacts()
        self.joint_q = wp.zeros(model.joint_coord_count, dtype=float, device=model.device, requires_grad=True)
        self.joint_qd = wp.zeros(model.joint_dof_count, dtype=float, device=model.device, requires_grad=True)
        self.pd = None
        if sim.position_control:
            # JOINT_POSITION_TARGET: the targets, and one joint_f per substep (the PD torque depends on the
            # substep's state; a shared buffer would be overwritten before the tape replays it)
            n, j = sim.num_envs, sim.layout.num_dofs
            self.target = wp.zeros(n * j, dtype=float, device=model.device, requires_grad=True)
            self.pd = [model.control(requires_grad=True) for _ in range(sim.task.physics.substeps)]
            if not sim.featherstone:  # maximal coordinates: joint coordinates come from eval_ik per substep
                self.pd_q = [wp.zeros_like(self.joint_q) for _ in range(sim.task.physics.substeps)]
                self.pd_qd = [wp.zeros_like(self.joint_qd) for _ in range(sim.task.physics.substeps)]
        # Featherstone keeps its mass matrix, Jacobian and Cholesky factor in solver-owned buffers that
        # every step overwrites; a frame owns one set per mass-matrix update so its tape replays them
        self.matrices = [sim.new_matrix_buffers() for _ in range(sim.matrix_updates)] if sim.featherstone else []
        self.tape: wp.Tape | None = None
        self.forward_work = None  # the forward's Warp work, to run again before a repeated backward
        self.backward_passes = 0  # backward passes since the last forward
        self.generation = 0
        # captured once per frame when the adapter captures (see the module docstring)
        self.forward_graph = None
        self.forward_uses = 0
        self.backward_graph = None
        self.zero_graph = None
        self.last: newton.State | None = None  # the state the forward ends in (ping-pong: either buffer)

    def substep_control(self, s: int) -> newton.Control:
        return self.control if self.pd is None else self.pd[s]


class NewtonSim(BatchedSim):
    """A task on Newton; see the module docstring.

    ``max_graph_steps`` (a contract argument) frames stay replayable. Options: ``solver``
    (``"semi_implicit"``, the default, or ``"featherstone"``); ``contact_gap`` (default 0.05 m)
    contact-candidate distance; for the semi-implicit solver ``angular_damping`` (default 0.05),
    ``joint_attach_ke`` (1e4) and ``joint_attach_kd`` (1e2): the solver's own defaults, exposed for
    experiments; ``parameter_gradients`` (0, the default, or 1): build the model with gradient buffers
    for its parameters, which no output of the contract uses (for A/B timing against the default).
    Control kinds: joint torques, and joint position targets through the PD law of the task's physics
    spec, evaluated by :func:`_pd_torque` at every substep inside the tape.

    Engine state per env: ``[body_q, body_qd]`` of every body (maximal coordinates) for the
    semi-implicit solver; ``[joint_q, joint_qd]`` (generalized coordinates, the neutral layout
    itself) for Featherstone, whose state they are; ``[particle_q, particle_qd]`` for a soft body.
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
    SOLVERS = ("semi_implicit", "featherstone")

    # -- construction ---------------------------------------------------------------------
    def _build(self) -> None:
        task = self.task
        phys = task.physics
        contact_gap = float(self.options.get("contact_gap", 0.05))
        solver = self.options.get("solver", "semi_implicit")
        if solver not in self.SOLVERS:
            raise BackendError(f"newton solver must be one of {', '.join(self.SOLVERS)}, got {solver!r}")
        self.featherstone = solver == "featherstone"
        self.position_control = task.control_kind == ControlKind.JOINT_POSITION_TARGET
        self.soft = task.control_kind == ControlKind.TET_ACTIVATION
        self.wp_device = warp_device(self.device)
        self.graph_capture = option_flag(self.options, "graph_capture", self.device.type == "cpu", self.name)

        shape_cfg = newton.ModelBuilder.ShapeConfig(
            ke=phys.contact_ke, kd=phys.contact_kd, kf=phys.contact_kf, mu=phys.contact_mu, gap=contact_gap
        )
        if self.soft:
            builder = self._soft_builder()
            self.bodies_per_env = 0
        else:
            builder = self._articulation_builder(shape_cfg)
        if phys.ground_plane:
            builder.add_ground_plane(cfg=shape_cfg)
        # The contract differentiates states and controls, never the model's parameters (masses,
        # inertias, gains, contact stiffnesses): a model finalized without gradients makes every adjoint
        # kernel skip its atomic adds into parameter gradients and the tapes skip zeroing them
        # (docs/performance.md, "Newton without parameter gradients"). States, controls, contacts and
        # Featherstone's per-frame matrices ask for gradients explicitly below; the solver's remaining
        # model-sized buffers (body inertias and COM frames) depend on parameters only. Option
        # parameter_gradients=1 restores them (as Rewarped builds its models), for A/B measurements;
        # nothing reads them.
        model = builder.finalize(
            device=self.wp_device, requires_grad=option_flag(self.options, "parameter_gradients", False, self.name)
        )
        if self.soft:
            self._apply_soft_physics(model)
        else:
            self._apply_physics(model)
            self._refuse_unrepresentable_armature(model)
        self.model = model
        if self.featherstone:
            self.mass_matrix_every = int(self.options.get("mass_matrix_every", phys.substeps))
            if self.mass_matrix_every < 1 or phys.substeps % self.mass_matrix_every:
                raise BackendError(
                    f"mass_matrix_every={self.mass_matrix_every} must be a divisor of the {phys.substeps} substeps"
                )
            self.matrix_updates = phys.substeps // self.mass_matrix_every
            self.solver = newton.solvers.SolverFeatherstone(model, update_mass_matrix_interval=self.mass_matrix_every)
        else:
            self.solver = newton.solvers.SolverSemiImplicit(
                model,
                angular_damping=float(self.options.get("angular_damping", 0.05)),
                joint_attach_ke=float(self.options.get("joint_attach_ke", 1.0e4)),
                joint_attach_kd=float(self.options.get("joint_attach_kd", 1.0e2)),
            )
        if self.soft:  # particle-ground candidates within contact_gap of the plane, found once per control step
            self.pipeline = newton.CollisionPipeline(model, requires_grad=True, soft_contact_gap=contact_gap)
        else:
            self.pipeline = newton.CollisionPipeline(model, requires_grad=True)
        if self.position_control:
            self.check_torque_limits()
            limits = phys.torque_limits or (float("inf"),) * task.layout.num_dofs
            self._pd_limits = wp.array(np.asarray(limits, dtype=np.float32), dtype=float, device=self.wp_device)
        self._views: dict[int, tuple[wp.array, torch.Tensor]] = {}
        self._frames: list[_Frame] = []
        self._cursor = 0
        self._scratch = _Frame(self, 2)

    def _articulation_builder(self, shape_cfg) -> newton.ModelBuilder:
        """``num_envs`` copies of the task's articulated asset."""
        task, phys = self.task, self.task.physics
        template = newton.ModelBuilder(gravity=(0.0, 0.0, phys.gravity))
        template.default_shape_cfg = shape_cfg
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # missing visual meshes and similar import chatter
            self._load_asset(template)
        self.bodies_per_env = template.body_count
        if template.joint_dof_count != task.layout.nv or template.joint_coord_count != task.layout.nq:
            raise BackendError(
                f"asset {task.asset_path.name} has {template.joint_coord_count} coordinates and "
                f"{template.joint_dof_count} dofs, task {task.name!r} expects {task.layout.nq} and {task.layout.nv}"
            )
        builder = newton.ModelBuilder(gravity=(0.0, 0.0, phys.gravity))
        builder.replicate(template, self.num_envs)
        return builder

    def _soft_builder(self) -> newton.ModelBuilder:
        """One soft body per env: the task's tet mesh scaled by the env's size factor, its particles
        carrying a quarter of each incident tet's mass (``SoftBodySpec``), one FEM element per tet."""
        phys, body = self.task.physics, self.checked_soft_body()  # a task without one hears that first
        if self.featherstone:
            raise BackendError("soft bodies run on the semi_implicit solver (featherstone has no FEM)")
        builder = newton.ModelBuilder(gravity=(0.0, 0.0, phys.gravity))
        masses = body.particle_masses()
        tets = body.tets.tolist()
        for scale in body.rest_scales(self.num_envs).tolist():
            first = builder.particle_count
            builder.add_particles(
                pos=[tuple(p) for p in (body.vertices * scale).tolist()],
                vel=[(0.0, 0.0, 0.0)] * body.num_particles,
                mass=(masses * scale**3).tolist(),
                radius=[body.particle_radius] * body.num_particles,
            )
            for tet in tets:  # rest shapes (D_m) from the scaled positions just added
                builder.add_tetrahedron(*(first + v for v in tet), body.k_mu, body.k_lambda, body.k_damp)
        return builder

    def _apply_soft_physics(self, model: newton.Model) -> None:
        """Particle-ground contact constants (the kernel averages particle and shape values: both are
        the task's), no particle-particle contact (Newton warns that it may corrupt gradients, and envs
        overlap in space)."""
        phys = self.task.physics
        model.soft_contact_ke = phys.contact_ke
        model.soft_contact_kd = phys.contact_kd
        model.soft_contact_kf = phys.contact_kf
        model.soft_contact_mu = phys.contact_mu
        model.particle_grid = None

    _MATRICES = ("M", "J", "P", "H", "L")

    def new_matrix_buffers(self) -> dict[str, wp.array]:
        """Fresh arrays shaped like the Featherstone solver's system matrices."""
        return {name: wp.zeros_like(getattr(self.solver, name), requires_grad=True) for name in self._MATRICES}

    def _load_asset(self, builder: newton.ModelBuilder) -> None:
        path = str(self.task.asset_path)
        fmt = self.task.asset_format
        try:
            if fmt == "mjcf":
                builder.add_mjcf(path, enable_self_collisions=False, parse_visuals=False)
            elif fmt == "urdf":
                builder.add_urdf(
                    path,
                    floating=self.task.layout.floating_base,  # the trunk's free joint (MuJoCo's adapter adds the same)
                    enable_self_collisions=False,
                    collapse_fixed_joints=True,  # rotor and foot links: fixed, tiny, stiff as penalty joints
                    parse_visuals_as_colliders=False,
                )
            else:
                raise BackendError(f"the newton adapter cannot load {fmt!r} assets yet")
        except BackendError:
            raise
        except Exception as exc:  # the importers raise assorted types for malformed files
            raise BackendError(f"cannot load {fmt} asset {path}: {exc}") from exc

    def _apply_physics(self, model: newton.Model) -> None:
        """Write the task's joint constants onto every articulated (non-root) dof."""
        phys = self.task.physics
        nv = self.task.layout.nv
        articulated = np.zeros(nv, dtype=bool)
        articulated[nv - self.task.layout.num_dofs :] = True
        articulated = np.tile(articulated, self.num_envs)

        def per_dof(value: float) -> np.ndarray:
            return np.where(articulated, value, 0.0).astype(np.float32)

        model.joint_limit_ke.assign(per_dof(phys.joint_limit_ke))
        model.joint_limit_kd.assign(per_dof(phys.joint_limit_kd))
        model.joint_damping.assign(per_dof(phys.joint_damping))
        if phys.armature is not None:
            model.joint_armature.assign(per_dof(phys.armature))
        # no built-in drive: torques come from the control (position targets through our own PD kernel,
        # which clips to the torque limits as the task's law says; Newton's drive would not)
        model.joint_target_ke.assign(per_dof(0.0))
        model.joint_target_kd.assign(per_dof(0.0))

    def _refuse_unrepresentable_armature(self, model: newton.Model) -> None:
        """The semi-implicit solver integrates bodies in maximal coordinates and has no rotor inertia:
        a spec (or, with ``armature=None``, an asset) that asks for one is refused, not ignored."""
        if self.featherstone:
            return
        nv = self.task.layout.nv
        armature = model.joint_armature.numpy().reshape(self.num_envs, nv)[:, nv - self.task.layout.num_dofs :]
        if armature.size and float(np.abs(armature).max()) > 0.0:
            source = "the asset's" if self.task.physics.armature is None else "the spec's"
            raise BackendError(
                f"PhysicsSpec.armature: newton's semi_implicit solver has no rotor inertia, and {source} is "
                f"{float(np.abs(armature).max()):g} kg m^2; use solver=featherstone or a spec with armature=0"
            )

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
        if self.soft:
            contact = "model.soft_contact_{name} (particle-ground penalty contact), as given"
        else:
            contact = "ShapeConfig.{name} of every shape and of the ground (the pair's mean is the value), as given"
        for name in ("ke", "kd", "kf", "mu"):
            mapping[f"contact_{name}"] = contact.format(name=name)
        mapping["joint_limit_ke"] = "model.joint_limit_ke on every articulated dof, as given (N m / rad)"
        mapping["joint_limit_kd"] = "model.joint_limit_kd on every articulated dof, as given (N m s / rad)"
        mapping["joint_damping"] = "model.joint_damping on every articulated dof, as given (N m s / rad)"
        if self.featherstone:
            mapping["armature"] = "model.joint_armature on every articulated dof (the asset's when None)"
        else:
            mapping["armature"] = "zero only (the semi-implicit solver has none); anything else is refused"
        for name in ("pd_kp", "pd_kd", "torque_limits"):
            mapping[name] = "the PD kernel on the tape, every substep (PhysicsSpec.pd_torque)"
        mapping.update(inert_by_definition(self.task))
        return mapping

    @property
    def layout(self) -> StateLayout:
        return self.task.layout

    # -- torch <-> warp -------------------------------------------------------------------
    def _state_arrays(self, state: newton.State) -> tuple[wp.array, wp.array]:
        """The solver state's own variables: generalized for Featherstone, maximal otherwise."""
        if self.featherstone:
            return state.joint_q, state.joint_qd
        if self.soft:
            return state.particle_q, state.particle_qd
        return state.body_q, state.body_qd

    def _join_engine(self, a: wp.array, b: wp.array) -> torch.Tensor:
        """A new (N, D) tensor holding two of the adapter's own (frame) arrays side by side."""
        return torch.cat((self._view(a), self._view(b)), dim=1)

    def _view(self, array: wp.array, cache: bool = True) -> torch.Tensor:
        """An (N, -1) torch view of one of the adapter's own Warp arrays, made once and cached.

        Only for arrays that live as long as the adapter (frames, their gradients, the control
        buffers): frames never swap their buffers, so a view stays valid, and a cached view spares
        ``wp.to_torch`` / ``wp.from_torch`` + ``wp.copy`` on every step (tens of microseconds each).
        ``cache=False`` for anyone else's arrays (the bare rollout's): a plain view, nothing kept.
        """
        # made in grad mode whatever the caller's mode: torch refuses to use in grad mode a view made
        # under no_grad once its base (the tensor wp.to_torch keeps on the array) was written in place
        if not cache:
            with torch.enable_grad():
                return wp.to_torch(array).reshape(self.num_envs, -1)
        entry = self._views.get(id(array))
        if entry is None or entry[0] is not array:  # holding the array keeps its id from being reused
            with torch.enable_grad():
                entry = self._views[id(array)] = (array, wp.to_torch(array).reshape(self.num_envs, -1))
        return entry[1]

    def _engine_split(self) -> int:
        """Columns of an engine row that belong to the first of the two state arrays."""
        if self.featherstone:
            return self.layout.nq
        if self.soft:
            return 3 * self.layout.num_particles
        return self.bodies_per_env * _POSE

    def _load_state(self, state: newton.State, engine: torch.Tensor, cache: bool = True) -> None:
        a, b = self._state_arrays(state)
        k = self._engine_split()
        with torch.no_grad():
            self._view(a, cache).copy_(engine[:, :k])
            self._view(b, cache).copy_(engine[:, k:])
        if self.featherstone:  # body poses for the collision pipeline (the solver recomputes them on the tape)
            newton.eval_fk(self.model, state.joint_q, state.joint_qd, state)

    def _load_frame_inputs(self, frame: _Frame, engine: torch.Tensor, control: torch.Tensor) -> None:
        self._load_state(frame.states[0], engine)
        with torch.no_grad():
            self._view(self._control_array(frame)).copy_(control.reshape(self.num_envs, -1))

    def _control_array(self, frame: _Frame) -> wp.array:
        """Where a frame's control tensor goes: PD targets, tet activations or joint forces."""
        if self.position_control:
            return frame.target
        return frame.control.tet_activations if self.soft else frame.control.joint_f

    def _outputs(self, frame: _Frame, last: newton.State) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        engine = self._join_engine(*self._state_arrays(last))
        if self.soft:  # no joints: particle_q / particle_qd are torch views of the engine (simulate)
            empty = engine.new_zeros(self.num_envs, 0)
            return engine, empty, empty.clone()
        if self.featherstone:
            nq = self.layout.nq
            return engine, engine[:, :nq].clone(), engine[:, nq:].clone()
        return engine, self._view(frame.joint_q).clone(), self._view(frame.joint_qd).clone()

    # -- simulation -----------------------------------------------------------------------
    def _substep(
        self, state_in: newton.State, state_out: newton.State, frame: _Frame, s: int, tape: wp.Tape | None = None
    ) -> None:
        state_in.clear_forces()
        if self.featherstone:
            # the solver rebuilds its matrices when its step counter is a multiple of mass_matrix_every:
            # point it at this frame's buffers for that update and the substeps that use it
            self.solver._step = s
            for name, array in frame.matrices[s // self.mass_matrix_every].items():
                setattr(self.solver, name, array)
        control = frame.substep_control(s)
        if self.position_control:
            self._pd(state_in, frame, s, control)
        self.solver.step(state_in, state_out, control, frame.contacts, self.task.physics.sim_dt)
        if self.featherstone and tape is not None:
            self._record_public_wrench_restore(tape, state_out)

    def _record_public_wrench_restore(self, tape: wp.Tape, state: newton.State) -> None:
        """Undo, for the tape's replay, Featherstone's in-place rewrite of the external wrenches.

        ``eval_rigid_tau`` reads each body's public wrench (force, torque about the COM) from
        ``body_f_ext`` and overwrites it with the solve-frame wrench it uses. Warp's backward replays a
        kernel from its arrays as they are after the forward, so without this the replay would read
        the converted wrench as if it were the public one: wrong joint-force adjoints whenever contact
        forces act (in stance: ~10% error in d reward / d actions vs central differences; 0.1% with
        this). The recorded function runs in the backward pass just before the step's own kernels and
        writes the public wrench back (the conversion inverted; nothing after ``eval_rigid_tau`` in
        the step reads ``body_f_ext`` unless ``body_parent_f`` is requested, which we never do).
        """
        model = self.model
        arrays = (model.joint_child, state.body_q_com, state.body_solve_origin, state.body_f_ext)

        def restore() -> None:
            wp.launch(_public_wrench, model.joint_count, inputs=list(arrays), device=model.device, record_tape=False)

        tape.record_func(restore, [state.body_f_ext])

    def _pd(self, state: newton.State, frame: _Frame, s: int, control: newton.Control) -> None:
        """PhysicsSpec.pd_torque from the substep's joint coordinates into the substep's joint_f."""
        if self.featherstone:
            q, qd = state.joint_q, state.joint_qd
        else:
            q, qd = frame.pd_q[s], frame.pd_qd[s]
            newton.eval_ik(self.model, state, q, qd)
        self.launch_pd(frame.target, q, qd, control.joint_f)

    def launch_pd(self, target: wp.array, q: wp.array, qd: wp.array, joint_f: wp.array) -> None:
        """One launch of :func:`_pd_torque` with the task's gains and limits (the adapter's and the
        bare rollout's)."""
        layout, phys = self.layout, self.task.physics
        wp.launch(
            _pd_torque,
            dim=(self.num_envs, layout.num_dofs),
            inputs=[target, q, qd, self._pd_limits, phys.pd_kp, phys.pd_kd, layout.nq, layout.nv, layout.num_dofs],
            outputs=[joint_f],
            device=self.model.device,
        )

    def _replay(self, frame: _Frame, name: str, work) -> None:
        """Run ``work()`` directly, or from the graph ``frame.<name>`` (captured on the spot if missing).

        A frame's forward runs directly on its first use and is captured on its second: capturing costs
        two to three eager runs (Warp records every launch), so a frame used once (a short test, an
        unrolled graph longer than any window) is not made slower. Its backward and zeroing graphs are
        captured from the tape the forward graph recorded, so they follow the forward.
        """
        if name == "forward_graph":
            frame.forward_uses += 1
            use_graph = self.graph_capture and frame.forward_uses > 1
        else:
            use_graph = frame.forward_graph is not None
        if not use_graph:
            work()
            return
        graph = getattr(frame, name)
        if graph is None:
            with wp.ScopedCapture(device=self.wp_device) as capture:  # records; runs nothing yet
                work()
            graph = capture.graph
            setattr(frame, name, graph)
        wp.capture_launch(graph)

    def _forward_no_grad(self, engine: torch.Tensor, control: torch.Tensor):
        frame = self._scratch
        self._load_frame_inputs(frame, engine, control)

        def work() -> None:
            a, b = frame.states
            self.pipeline.collide(a, frame.contacts)
            for s in range(self.task.physics.substeps):
                self._substep(a, b, frame, s)
                a, b = b, a
            if not (self.featherstone or self.soft):
                newton.eval_ik(self.model, a, frame.joint_q, frame.joint_qd)
            frame.last = a

        self._replay(frame, "forward_graph", work)
        return self._outputs(frame, frame.last)

    def _next_frame(self) -> _Frame:
        if len(self._frames) < self.max_graph_steps:
            self._frames.append(_Frame(self, self.task.physics.substeps + 1))
            frame = self._frames[-1]
        else:
            frame = self._frames[self._cursor % self.max_graph_steps]
        self._cursor += 1
        frame.generation += 1
        return frame

    def _forward_taped(self, engine: torch.Tensor, control: torch.Tensor) -> _Frame:
        frame = self._next_frame()
        self._load_frame_inputs(frame, engine, control)

        def work() -> None:
            states = frame.states
            self.pipeline.collide(states[0], frame.contacts)  # discrete: outside the tape
            tape = wp.Tape()
            with tape:
                for s in range(self.task.physics.substeps):
                    self._substep(states[s], states[s + 1], frame, s, tape)
                if not (self.featherstone or self.soft):
                    newton.eval_ik(self.model, states[-1], frame.joint_q, frame.joint_qd)
            frame.tape = tape  # a captured frame keeps the tape its graphs were recorded from

        frame.forward_work, frame.backward_passes = work, 0
        self._replay(frame, "forward_graph", work)
        return frame

    def _backward_taped(self, frame: _Frame, generation: int, grad_engine, grad_q, grad_qd):
        if frame.generation != generation:
            raise BackendError(
                f"backward reached a step more than max_graph_steps={self.max_graph_steps} steps old whose "
                "buffers were reused; call cut_graph() at window boundaries or raise max_graph_steps"
            )
        if frame.backward_passes:  # the last backward rewrote forward values: restore them (module docstring)
            self._replay(frame, "forward_graph", frame.forward_work)
        frame.backward_passes += 1
        last = frame.states[-1]
        out_a, out_b = self._state_arrays(last)
        if self.featherstone:  # joint_q / joint_qd are views of the engine rows: one gradient
            nq = self.layout.nq
            total = torch.zeros(self.num_envs, self.layout.nq + self.layout.nv, device=self.device)
            for grad, cols in ((grad_engine, slice(None)), (grad_q, slice(0, nq)), (grad_qd, slice(nq, None))):
                if grad is not None:
                    total[:, cols] += grad.float()
            grad_engine, grad_q, grad_qd = total, None, None
        seeds = []
        if grad_engine is not None:
            k = self._engine_split()
            seeds += [(out_a, grad_engine[:, :k]), (out_b, grad_engine[:, k:])]
        if self.soft:  # the (N, 0) joint outputs carry no gradient
            grad_q = grad_qd = None
        if grad_q is not None:
            seeds.append((frame.joint_q, grad_q))
        if grad_qd is not None:
            seeds.append((frame.joint_qd, grad_qd))
        # the incoming gradients go into the outputs' own gradient buffers (zero until now: each
        # backward ends by zeroing the frame's gradients), which is what tape.backward(grads=...) does
        for array, g in seeds:
            self._view(array.grad).copy_(g)
        self._replay(frame, "backward_graph", frame.tape.backward)
        grad_engine_in = self._join_engine(*(a.grad for a in self._state_arrays(frame.states[0])))
        grad_control = self._view(self._control_array(frame).grad).clone()
        # the backward registered every gradient buffer it touched with the tape: zero them all
        self._replay(frame, "zero_graph", frame.tape.zero)
        return grad_engine_in, grad_control

    def simulate(self, state: SimState, control: torch.Tensor) -> SimState:
        control = self.engine_control(control)
        if torch.is_grad_enabled() and (state.engine.requires_grad or control.requires_grad):
            engine, joint_q, joint_qd = _NewtonStep.apply(self, state.engine, control)
        else:
            engine, joint_q, joint_qd = self._forward_no_grad(state.engine, control)
        if self.soft:
            return self._soft_state(engine)
        return SimState(joint_q=joint_q, joint_qd=joint_qd, engine=engine)

    def _soft_state(self, engine: torch.Tensor) -> SimState:
        """A particle state whose particle_q / particle_qd are views of ``engine`` (one gradient path)."""
        n, half = self.num_envs, 3 * self.layout.num_particles
        empty = engine.new_zeros(n, 0)
        return SimState(
            joint_q=empty,
            joint_qd=empty.clone(),
            engine=engine,
            particle_q=engine[:, :half].reshape(n, -1, 3),
            particle_qd=engine[:, half:].reshape(n, -1, 3),
        )

    def _control_tet_activation(self, control: torch.Tensor) -> torch.Tensor:
        """TET_ACTIVATION: (N, T) activations, one per tet of each env's body."""
        expected = (self.num_envs, self.layout.num_tets)
        if tuple(control.shape) != expected:
            raise BackendError(f"tet activations must have shape {expected}, got {tuple(control.shape)}")
        return control

    def _control_joint_torque(self, control: torch.Tensor) -> torch.Tensor:
        """JOINT_TORQUE: generalized forces for every dof, zero on the free root, the control on the rest."""
        root = self.layout.nv - self.layout.num_dofs
        return torch.nn.functional.pad(control, (root, 0))

    def _control_joint_position_target(self, control: torch.Tensor) -> torch.Tensor:
        """JOINT_POSITION_TARGET: the (N, J) targets; the PD law runs per substep in :meth:`_pd`."""
        expected = (self.num_envs, self.layout.num_dofs)
        if tuple(control.shape) != expected:
            raise BackendError(f"position targets must have shape {expected}, got {tuple(control.shape)}")
        return control

    def bare_engine_rollout(self, horizon: int, grad: bool = True) -> float:
        """Seconds per window on raw Newton/Warp, forward+backward or forward only (:func:`bare_tape_rollout`)."""
        return bare_tape_rollout(self, horizon, grad=grad)

    # -- generalized -> engine coordinates ------------------------------------------------
    def state_from_generalized(self, joint_q, joint_qd, particle_q=None, particle_qd=None) -> SimState:
        if self.soft:
            n = self.num_envs
            flat = (p.to(self.device, torch.float32).reshape(n, -1) for p in (particle_q, particle_qd))
            return self._soft_state(torch.cat(tuple(flat), dim=1))
        joint_q = joint_q.to(self.device, torch.float32)
        joint_qd = joint_qd.to(self.device, torch.float32)
        if self.featherstone:  # generalized coordinates are the engine state (quaternion normalised, as FK does)
            if self.layout.floating_base:
                quat = torch.nn.functional.normalize(joint_q[:, 3:7], dim=1)
                joint_q = torch.cat((joint_q[:, :3], quat, joint_q[:, 7:]), dim=1)
            return SimState(joint_q=joint_q, joint_qd=joint_qd, engine=torch.cat((joint_q, joint_qd), dim=1))
        engine = _NewtonFK.apply(self, joint_q, joint_qd)
        return SimState(joint_q=joint_q, joint_qd=joint_qd, engine=engine)

    def _fk(self, joint_q: torch.Tensor, joint_qd: torch.Tensor, record: bool):
        model = self.model
        q = wp.from_torch(joint_q.detach().reshape(-1).contiguous().clone(), requires_grad=record)
        qd = wp.from_torch(joint_qd.detach().reshape(-1).contiguous().clone(), requires_grad=record)
        out = model.state(requires_grad=record)
        tape = wp.Tape() if record else None
        if tape is not None:
            with tape:
                newton.eval_fk(model, q, qd, out)
        else:
            newton.eval_fk(model, q, qd, out)
        # fresh arrays per call: plain views, nothing cached
        engine = torch.cat((self._view(out.body_q, cache=False), self._view(out.body_qd, cache=False)), dim=1)
        return engine, (tape, q, qd, out)


@wp.kernel
def _pd_torque(
    target: wp.array[float],
    joint_q: wp.array[float],
    joint_qd: wp.array[float],
    limit: wp.array[float],
    kp: float,
    kd: float,
    nq: int,
    nv: int,
    num_dofs: int,
    joint_f: wp.array[float],
):
    """tau = clip(kp (q* - q) - kd qd, -limit, limit) on the articulated dofs (PhysicsSpec.pd_torque)."""
    env, j = wp.tid()
    q = joint_q[env * nq + nq - num_dofs + j]
    qd = joint_qd[env * nv + nv - num_dofs + j]
    tau = kp * (target[env * num_dofs + j] - q) - kd * qd
    joint_f[env * nv + nv - num_dofs + j] = wp.clamp(tau, -limit[j], limit[j])


@wp.kernel
def _public_wrench(
    joint_child: wp.array[int],
    body_q_com: wp.array[wp.transform],
    body_solve_origin: wp.array[wp.vec3],
    body_f_ext: wp.array[wp.spatial_vector],
):
    """Invert Featherstone's ``f_ext = -(F, tau + x x F)`` (x: the COM relative to the body's solve origin)
    on the child body of every joint: ``F = -top``, ``tau = -bottom + x x top``."""
    j = wp.tid()
    body = joint_child[j]
    if body < 0:
        return
    converted = body_f_ext[body]
    top = wp.spatial_top(converted)
    x = wp.transform_get_translation(body_q_com[body]) - body_solve_origin[body]
    body_f_ext[body] = wp.spatial_vector(-top, -wp.spatial_bottom(converted) + wp.cross(x, top))


class _NewtonStep(torch.autograd.Function):
    """(engine state, joint forces) -> (next engine state, joint_q, joint_qd) for one control step."""

    @staticmethod
    def forward(ctx, sim: NewtonSim, engine: torch.Tensor, joint_f: torch.Tensor):
        frame = sim._forward_taped(engine, joint_f)
        ctx.sim, ctx.frame, ctx.generation = sim, frame, frame.generation
        return sim._outputs(frame, frame.states[-1])

    @staticmethod
    def backward(ctx, grad_engine, grad_q, grad_qd):
        grad_engine_in, grad_joint_f = ctx.sim._backward_taped(ctx.frame, ctx.generation, grad_engine, grad_q, grad_qd)
        return None, grad_engine_in, grad_joint_f


class _NewtonFK(torch.autograd.Function):
    """Forward kinematics (joint_q, joint_qd) -> maximal-coordinate engine state."""

    @staticmethod
    def forward(ctx, sim: NewtonSim, joint_q: torch.Tensor, joint_qd: torch.Tensor):
        record = joint_q.requires_grad or joint_qd.requires_grad
        engine, (tape, q, qd, out) = sim._fk(joint_q, joint_qd, record)
        ctx.sim, ctx.tape, ctx.arrays = sim, tape, (q, qd, out)
        return engine

    @staticmethod
    def backward(ctx, grad_engine):
        sim, (q, qd, out) = ctx.sim, ctx.arrays
        k = sim._engine_split()  # seeded as NewtonSim._backward_taped seeds a frame's outputs
        with torch.no_grad():
            sim._view(out.body_q.grad, cache=False).copy_(grad_engine[:, :k])
            sim._view(out.body_qd.grad, cache=False).copy_(grad_engine[:, k:])
        ctx.tape.backward()
        grad_q = sim._view(q.grad, cache=False).clone()
        grad_qd = sim._view(qd.grad, cache=False).clone()
        ctx.tape.zero()
        return None, grad_q, grad_qd


def bare_tape_rollout(sim: NewtonSim, horizon: int, repeats: int = 1, seed: int = 0, grad: bool = True) -> float:
    """Seconds per forward+backward of ``horizon`` frames on raw Newton/Warp, no torch involved
    (``grad=False``: the same frames forward only, without a tape).

    The reference for the adapter's overhead: the same model, solver, contact pipeline, substeps
    and fresh state buffers per substep, one tape over the whole window, a loss on the final
    body positions (particle positions for a soft body), ``tape.backward`` and ``tape.zero``.
    Position-target tasks run the same PD kernel per substep as the adapter. Featherstone runs as
    raw Newton does, on the solver's own system-matrix buffers (the adapter points the solver at
    per-frame copies instead, so that its replay is exact; the arithmetic is the same). When the
    adapter captures graphs (option ``graph_capture``), so does this: the whole window is captured
    once and replayed, so that the ratio compares like with like. Returns the best of ``repeats``
    passes after a warm-up pass (the only pass when ``repeats`` is 0).
    """
    import time

    model, phys, layout = sim.model, sim.task.physics, sim.layout
    subs = phys.substeps
    states = [model.state(requires_grad=grad) for _ in range(horizon * subs + 1)]
    controls = [model.control(requires_grad=grad) for _ in range(horizon * subs if sim.position_control else horizon)]
    contacts = [sim.pipeline.contacts() for _ in range(horizon)]
    loss = wp.zeros(1, dtype=float, device=model.device, requires_grad=grad)
    sim._load_state(states[0], sim.state.engine, cache=False)
    rng = np.random.default_rng(seed)
    targets = []
    for t in range(horizon):
        if sim.position_control:  # targets within a quarter radian of the current pose
            q = sim.state.dof_q(layout).detach().cpu().numpy()
            values = (q + rng.uniform(-0.25, 0.25, q.shape)).astype(np.float32).ravel()
            targets.append(wp.array(values, dtype=float, device=model.device, requires_grad=grad))
        elif sim.soft:  # activations as the SoftJumper's actions give them
            activations = rng.uniform(-0.3, 0.3, sim.num_envs * layout.num_tets).astype(np.float32)
            controls[t].tet_activations.assign(activations)
        else:
            f = np.zeros((sim.num_envs, layout.nv), dtype=np.float32)
            f[:, layout.nv - layout.num_dofs :] = rng.uniform(-100.0, 100.0, (sim.num_envs, layout.num_dofs))
            controls[t].joint_f.assign(f.ravel())

    def window() -> None:
        tape = wp.Tape() if grad else contextlib.nullcontext()
        for t in range(horizon):
            sim.pipeline.collide(states[t * subs], contacts[t])
            with tape:
                for s in range(t * subs, (t + 1) * subs):
                    states[s].clear_forces()
                    control = controls[s] if sim.position_control else controls[t]
                    if sim.position_control:
                        pd_q, pd_qd = states[s].joint_q, states[s].joint_qd
                        if not sim.featherstone:
                            newton.eval_ik(model, states[s], pd_q, pd_qd)
                        sim.launch_pd(targets[t], pd_q, pd_qd, control.joint_f)
                    sim.solver.step(states[s], states[s + 1], control, contacts[t], phys.sim_dt)
        if not grad:
            return
        with tape:
            if sim.soft:
                wp.launch(_sum_particles, dim=model.particle_count, inputs=[states[-1].particle_q], outputs=[loss])
            else:
                wp.launch(_sum_positions, dim=model.body_count, inputs=[states[-1].body_q], outputs=[loss])
        tape.backward(loss)
        tape.zero()
        loss.zero_()

    best = float("inf")
    graph = None
    for attempt in range(repeats + 1):  # the first pass warms caches (and captures) and is not counted
        start = time.perf_counter()
        if sim.graph_capture:  # as the adapter runs its frames: the whole window captured once, then replayed
            if graph is None:
                with wp.ScopedCapture(device=model.device) as capture:
                    window()
                graph = capture.graph
            wp.capture_launch(graph)
        else:
            window()
        wp.synchronize_device(model.device)
        if attempt > 0 or repeats == 0:
            best = min(best, time.perf_counter() - start)
    return best


@wp.kernel
def _sum_particles(particle_q: wp.array[wp.vec3], loss: wp.array[float]):
    i = wp.tid()
    p = particle_q[i]
    wp.atomic_add(loss, 0, p[0] + p[1] + p[2])


@wp.kernel
def _sum_positions(body_q: wp.array[wp.transform], loss: wp.array[float]):
    i = wp.tid()
    p = wp.transform_get_translation(body_q[i])
    wp.atomic_add(loss, 0, p[0] + p[1] + p[2])
