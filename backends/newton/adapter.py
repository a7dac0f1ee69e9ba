"""Newton adapter: exact gradients from ``wp.Tape`` wrapped in ``torch.autograd.Function``.

Solver: :class:`newton.solvers.SolverSemiImplicit` (symplectic Euler in maximal coordinates with
penalty joints and penalty contacts). README ("Newton solver choice") records the probe that
chose it: on the Ant with ground contact its gradients are finite and match finite differences,
while ``SolverFeatherstone`` returned NaN gradients in the same probe.

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
* Without grad (``torch.no_grad()`` or inputs that need none) the step runs without a tape on
  two ping-pong buffers.
"""

from __future__ import annotations

import warnings

import newton
import numpy as np
import torch
import warp as wp

from backends._warp import warp_device
from backends.contract import BackendError, BatchedSim
from simcore import SimState, StateLayout

_POSE = 7  # wp.transform: position (3) + quaternion xyzw (4)
_TWIST = 6  # wp.spatial_vector: COM linear velocity (3) + angular velocity (3), world frame


class _Frame:
    """Every Warp buffer one control step touches, so its tape can be replayed later."""

    def __init__(self, sim: NewtonSim, num_states: int):
        model = sim.model
        self.states = [model.state(requires_grad=True) for _ in range(num_states)]
        self.control = model.control(requires_grad=True)
        self.contacts = sim.pipeline.contacts()
        self.joint_q = wp.zeros(model.joint_coord_count, dtype=float, device=model.device, requires_grad=True)
        self.joint_qd = wp.zeros(model.joint_dof_count, dtype=float, device=model.device, requires_grad=True)
        self.tape: wp.Tape | None = None
        self.generation = 0


class NewtonSim(BatchedSim):
    """A task on Newton's semi-implicit solver; see the module docstring.

    ``max_graph_steps`` (a contract argument) frames stay replayable. Options: ``contact_gap``
    (default 0.05 m) contact-candidate distance; ``angular_damping`` (default 0.05),
    ``joint_attach_ke`` (1e4) and ``joint_attach_kd`` (1e2): the solver's own defaults, exposed for
    experiments. Control kinds: joint torques (``JOINT_POSITION_TARGET`` comes with the Go2 task).
    """

    name = "newton"

    # -- construction ---------------------------------------------------------------------
    def _build(self) -> None:
        task = self.task
        phys = task.physics
        contact_gap = float(self.options.get("contact_gap", 0.05))
        self.wp_device = warp_device(self.device)

        shape_cfg = newton.ModelBuilder.ShapeConfig(
            ke=phys.contact_ke, kd=phys.contact_kd, kf=phys.contact_kf, mu=phys.contact_mu, gap=contact_gap
        )
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
        if phys.ground_plane:
            builder.add_ground_plane(cfg=shape_cfg)
        model = builder.finalize(device=self.wp_device, requires_grad=True)
        self._apply_physics(model)
        self.model = model
        self.solver = newton.solvers.SolverSemiImplicit(
            model,
            angular_damping=float(self.options.get("angular_damping", 0.05)),
            joint_attach_ke=float(self.options.get("joint_attach_ke", 1.0e4)),
            joint_attach_kd=float(self.options.get("joint_attach_kd", 1.0e2)),
        )
        self.pipeline = newton.CollisionPipeline(model, requires_grad=True)
        self._frames: list[_Frame] = []
        self._cursor = 0
        self._scratch = _Frame(self, 2)

    def _load_asset(self, builder: newton.ModelBuilder) -> None:
        path = str(self.task.asset_path)
        fmt = self.task.asset_format
        try:
            if fmt == "mjcf":
                builder.add_mjcf(path, enable_self_collisions=False, parse_visuals=False)
            elif fmt == "urdf":
                builder.add_urdf(
                    path,
                    floating=self.task.layout.floating_base,
                    enable_self_collisions=False,
                    collapse_fixed_joints=True,  # rotor and foot links: fixed, tiny, stiff as penalty joints
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
        # torque control: no PD drive (the importer may have set gains from the MJCF's actuators)
        model.joint_target_ke.assign(per_dof(0.0))
        model.joint_target_kd.assign(per_dof(0.0))

    @property
    def layout(self) -> StateLayout:
        return self.task.layout

    # -- torch <-> warp -------------------------------------------------------------------
    def _split_engine(self, engine: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        n_pose = self.bodies_per_env * _POSE
        body_q = engine[:, :n_pose].reshape(-1, _POSE).contiguous()
        body_qd = engine[:, n_pose:].reshape(-1, _TWIST).contiguous()
        return body_q, body_qd

    def _join_engine(self, body_q: wp.array, body_qd: wp.array) -> torch.Tensor:
        n = self.num_envs
        return torch.cat((wp.to_torch(body_q).reshape(n, -1), wp.to_torch(body_qd).reshape(n, -1)), dim=1)

    def _load_frame_inputs(self, frame: _Frame, engine: torch.Tensor, joint_f: torch.Tensor) -> None:
        body_q, body_qd = self._split_engine(engine.detach().float())
        first = frame.states[0]
        wp.copy(first.body_q, wp.from_torch(body_q, dtype=wp.transform))
        wp.copy(first.body_qd, wp.from_torch(body_qd, dtype=wp.spatial_vector))
        wp.copy(frame.control.joint_f, wp.from_torch(joint_f.detach().float().reshape(-1).contiguous()))

    def _outputs(self, frame: _Frame, last: newton.State) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        n = self.num_envs
        engine = self._join_engine(last.body_q, last.body_qd).clone()
        joint_q = wp.to_torch(frame.joint_q).reshape(n, -1).clone()
        joint_qd = wp.to_torch(frame.joint_qd).reshape(n, -1).clone()
        return engine, joint_q, joint_qd

    # -- simulation -----------------------------------------------------------------------
    def _substep(self, state_in: newton.State, state_out: newton.State, frame: _Frame) -> None:
        state_in.clear_forces()
        self.solver.step(state_in, state_out, frame.control, frame.contacts, self.task.physics.sim_dt)

    def _forward_no_grad(self, engine: torch.Tensor, joint_f: torch.Tensor):
        frame = self._scratch
        self._load_frame_inputs(frame, engine, joint_f)
        a, b = frame.states
        self.pipeline.collide(a, frame.contacts)
        for _ in range(self.task.physics.substeps):
            self._substep(a, b, frame)
            a, b = b, a
        newton.eval_ik(self.model, a, frame.joint_q, frame.joint_qd)
        return self._outputs(frame, a)

    def _next_frame(self) -> _Frame:
        if len(self._frames) < self.max_graph_steps:
            self._frames.append(_Frame(self, self.task.physics.substeps + 1))
            frame = self._frames[-1]
        else:
            frame = self._frames[self._cursor % self.max_graph_steps]
        self._cursor += 1
        frame.generation += 1
        return frame

    def _forward_taped(self, engine: torch.Tensor, joint_f: torch.Tensor) -> _Frame:
        frame = self._next_frame()
        self._load_frame_inputs(frame, engine, joint_f)
        states = frame.states
        self.pipeline.collide(states[0], frame.contacts)  # discrete: outside the tape
        tape = wp.Tape()
        with tape:
            for s in range(self.task.physics.substeps):
                self._substep(states[s], states[s + 1], frame)
            newton.eval_ik(self.model, states[-1], frame.joint_q, frame.joint_qd)
        frame.tape = tape
        return frame

    def _backward_taped(self, frame: _Frame, generation: int, grad_engine, grad_q, grad_qd):
        if frame.generation != generation:
            raise BackendError(
                f"backward reached a step more than max_graph_steps={self.max_graph_steps} steps old whose "
                "buffers were reused; call cut_graph() at window boundaries or raise max_graph_steps"
            )
        last = frame.states[-1]
        grads = {}
        if grad_engine is not None:
            g_q, g_qd = self._split_engine(grad_engine.float())
            grads[last.body_q] = wp.from_torch(g_q, dtype=wp.transform)
            grads[last.body_qd] = wp.from_torch(g_qd, dtype=wp.spatial_vector)
        if grad_q is not None:
            grads[frame.joint_q] = wp.from_torch(grad_q.float().reshape(-1).contiguous())
        if grad_qd is not None:
            grads[frame.joint_qd] = wp.from_torch(grad_qd.float().reshape(-1).contiguous())
        frame.tape.backward(grads=grads)
        first = frame.states[0]
        grad_engine_in = self._join_engine(first.body_q.grad, first.body_qd.grad).clone()
        grad_joint_f = wp.to_torch(frame.control.joint_f.grad).reshape(self.num_envs, -1).clone()
        frame.tape.zero()
        return grad_engine_in, grad_joint_f

    def simulate(self, state: SimState, control: torch.Tensor) -> SimState:
        joint_f = self.engine_control(control)
        if torch.is_grad_enabled() and (state.engine.requires_grad or joint_f.requires_grad):
            engine, joint_q, joint_qd = _NewtonStep.apply(self, state.engine, joint_f)
        else:
            engine, joint_q, joint_qd = self._forward_no_grad(state.engine, joint_f)
        return SimState(joint_q=joint_q, joint_qd=joint_qd, engine=engine)

    def _control_joint_torque(self, control: torch.Tensor) -> torch.Tensor:
        """JOINT_TORQUE: generalized forces for every dof, zero on the free root, the control on the rest."""
        root = self.layout.nv - self.layout.num_dofs
        return torch.nn.functional.pad(control, (root, 0))

    def bare_engine_rollout(self, horizon: int) -> float:
        """Seconds per forward+backward window on raw Newton/Warp (see :func:`bare_tape_rollout`)."""
        return bare_tape_rollout(self, horizon)

    # -- generalized -> maximal coordinates -----------------------------------------------
    def state_from_generalized(self, joint_q, joint_qd, particle_q=None, particle_qd=None) -> SimState:
        if particle_q is not None or particle_qd is not None:
            raise BackendError("particles are not supported by the newton adapter yet")
        joint_q = joint_q.to(self.device, torch.float32)
        joint_qd = joint_qd.to(self.device, torch.float32)
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
        return self._join_engine(out.body_q, out.body_qd).clone(), (tape, q, qd, out)


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
        q, qd, out = ctx.arrays
        g_q, g_qd = ctx.sim._split_engine(grad_engine.float())
        ctx.tape.backward(
            grads={
                out.body_q: wp.from_torch(g_q, dtype=wp.transform),
                out.body_qd: wp.from_torch(g_qd, dtype=wp.spatial_vector),
            }
        )
        n = ctx.sim.num_envs
        grad_q = wp.to_torch(q.grad).reshape(n, -1).clone()
        grad_qd = wp.to_torch(qd.grad).reshape(n, -1).clone()
        ctx.tape.zero()
        return None, grad_q, grad_qd


def bare_tape_rollout(sim: NewtonSim, horizon: int, repeats: int = 1, seed: int = 0) -> float:
    """Seconds per forward+backward of ``horizon`` frames on raw Newton/Warp, no torch involved.

    The reference for the adapter's overhead: the same model, solver, contact pipeline, substeps
    and fresh state buffers per substep, one tape over the whole window, a loss on the final
    body positions, ``tape.backward`` and ``tape.zero``. Returns the best of ``repeats``.
    """
    import time

    model, phys = sim.model, sim.task.physics
    subs = phys.substeps
    states = [model.state(requires_grad=True) for _ in range(horizon * subs + 1)]
    controls = [model.control(requires_grad=True) for _ in range(horizon)]
    contacts = [sim.pipeline.contacts() for _ in range(horizon)]
    loss = wp.zeros(1, dtype=float, device=model.device, requires_grad=True)
    body_q, body_qd = sim._split_engine(sim.state.engine.detach())
    wp.copy(states[0].body_q, wp.from_torch(body_q, dtype=wp.transform))
    wp.copy(states[0].body_qd, wp.from_torch(body_qd, dtype=wp.spatial_vector))
    rng = np.random.default_rng(seed)
    for c in controls:
        f = np.zeros((sim.num_envs, sim.layout.nv), dtype=np.float32)
        f[:, sim.layout.nv - sim.layout.num_dofs :] = rng.uniform(-100.0, 100.0, (sim.num_envs, sim.layout.num_dofs))
        c.joint_f.assign(f.ravel())

    best = float("inf")
    for _ in range(repeats + 1):  # the first pass warms caches and is not counted
        start = time.perf_counter()
        tape = wp.Tape()
        for t in range(horizon):
            sim.pipeline.collide(states[t * subs], contacts[t])
            with tape:
                for s in range(t * subs, (t + 1) * subs):
                    states[s].clear_forces()
                    sim.solver.step(states[s], states[s + 1], controls[t], contacts[t], phys.sim_dt)
        with tape:
            wp.launch(_sum_positions, dim=model.body_count, inputs=[states[-1].body_q], outputs=[loss])
        tape.backward(loss)
        tape.zero()
        loss.zero_()
        wp.synchronize_device(model.device)
        best = min(best, time.perf_counter() - start)
    return best


@wp.kernel
def _sum_positions(body_q: wp.array[wp.transform], loss: wp.array[float]):
    i = wp.tid()
    p = wp.transform_get_translation(body_q[i])
    wp.atomic_add(loss, 0, p[0] + p[1] + p[2])
