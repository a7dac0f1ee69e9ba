"""Articulated robots (the Ant, the Go2) on Newton: one family per solver, sharing everything else.

* :class:`Articulation`: ``num_envs`` copies of the task's MJCF or URDF asset, the task's joint
  constants on every articulated dof, and the joint control (:class:`JointTorques` or
  :class:`PositionTargets`).
* :class:`SemiImplicitArticulation`: ``SolverSemiImplicit``, maximal coordinates (engine row
  ``[body_q, body_qd]`` of every body, penalty joints). It has no rotor inertia, so a non-zero
  armature is refused; joint coordinates come from inverse kinematics (``eval_ik``) on the tape;
  ``state_from_generalized`` runs forward kinematics on a tape of its own (:class:`_ForwardKinematics`).
* :class:`FeatherstoneArticulation`: ``SolverFeatherstone``, generalized coordinates (engine row
  ``[joint_q, joint_qd]``, the neutral layout itself). Its system matrices live in solver-owned
  buffers that every step overwrites: each frame owns a copy the solver is pointed at
  (``frame.matrices``), rebuilt once per control step by default (``mass_matrix_every``). Its
  ``eval_rigid_tau`` rewrites the external wrenches in place; the frame's tape writes them back
  before replaying each substep (:meth:`FeatherstoneArticulation.after_taped_substep`).
* Joint controls (torques, or position targets through the PD kernel): :mod:`backends.newton.joint_control`;
  the one difference between the solvers there is where the PD kernel reads joint coordinates
  (:meth:`Articulation.pd_coordinates`).
"""

from __future__ import annotations

import warnings

import newton
import numpy as np
import torch
import warp as wp

from backends.contract import BackendError, BatchedSim, option_number
from backends.newton.family import EngineFamily, semi_implicit_solver
from backends.newton.joint_control import JointTorques, PositionTargets
from backends.newton.tape import Frame
from simcore import ControlKind, SimState

_POSE = 7  # wp.transform: position (3) + quaternion xyzw (4)


# -- what both solvers share ------------------------------------------------------------------------
class Articulation(EngineFamily):
    """``num_envs`` copies of the task's articulated asset; see the module docstring."""

    contact_mapping = "ShapeConfig.{name} of every shape and of the ground (the pair's mean is the value), as given"

    def __init__(self, sim):
        super().__init__(sim)
        self.joint_control: JointTorques | PositionTargets | None = None
        self.bodies_per_env = 0

    def builder(self, shape_cfg) -> newton.ModelBuilder:
        task, phys = self.task, self.physics
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

    def apply_physics(self, model: newton.Model) -> None:
        """Write the task's joint constants onto every articulated (non-root) dof."""
        phys = self.physics
        nv = self.layout.nv
        articulated = np.zeros(nv, dtype=bool)
        articulated[nv - self.layout.num_dofs :] = True
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

    def after_build(self) -> None:
        if self.task.control_kind == ControlKind.JOINT_POSITION_TARGET:
            BatchedSim.check_torque_limits(self)  # the contract's check, on this family's task and layout
            self.joint_control = PositionTargets(self)
        else:
            self.joint_control = JointTorques(self)

    # -- differences between the solvers (overridden below) --------------------------------
    def new_pd_coordinate_buffers(self) -> tuple[wp.array, wp.array] | None:
        """Per-substep buffers the PD kernel reads joint coordinates from (None: the state's own)."""
        return None

    def pd_coordinates(self, state: newton.State, buffers) -> tuple[wp.array, wp.array]:
        """The joint coordinates of ``state`` for the PD kernel."""
        return state.joint_q, state.joint_qd

    # -- the joint control ------------------------------------------------------------------
    def add_frame_buffers(self, frame: Frame) -> None:
        self.joint_control.add_frame_buffers(frame)

    def control_array(self, frame: Frame) -> wp.array:
        return self.joint_control.control_array(frame)

    def substep_control(self, state: newton.State, frame: Frame, s: int) -> newton.Control:
        return self.joint_control.substep_control(state, frame, s)

    def bare_controls(self, horizon: int, rng, grad: bool, current: SimState):
        return self.joint_control.bare_controls(horizon, rng, grad, current)

    def sim_state(self, engine: torch.Tensor, joint_q: torch.Tensor, joint_qd: torch.Tensor) -> SimState:
        return SimState(joint_q=joint_q, joint_qd=joint_qd, engine=engine)

    def bare_loss(self, state: newton.State, loss: wp.array) -> None:
        wp.launch(_sum_positions, dim=self.model.body_count, inputs=[state.body_q], outputs=[loss])


@wp.kernel
def _sum_positions(body_q: wp.array[wp.transform], loss: wp.array[float]):
    i = wp.tid()
    p = wp.transform_get_translation(body_q[i])
    wp.atomic_add(loss, 0, p[0] + p[1] + p[2])


# -- SolverSemiImplicit: maximal coordinates ---------------------------------------------------------
class SemiImplicitArticulation(Articulation):
    """Bodies in maximal coordinates held by penalty joints; see the module docstring."""

    armature_mapping = "zero only (the semi-implicit solver has none); anything else is refused"

    def apply_physics(self, model: newton.Model) -> None:
        super().apply_physics(model)
        self._refuse_armature(model)

    def _refuse_armature(self, model: newton.Model) -> None:
        """The semi-implicit solver integrates bodies in maximal coordinates and has no rotor inertia:
        a spec (or, with ``armature=None``, an asset) that asks for one is refused, not ignored."""
        nv = self.layout.nv
        armature = model.joint_armature.numpy().reshape(self.num_envs, nv)[:, nv - self.layout.num_dofs :]
        if armature.size and float(np.abs(armature).max()) > 0.0:
            source = "the asset's" if self.physics.armature is None else "the spec's"
            raise BackendError(
                f"PhysicsSpec.armature: newton's semi_implicit solver has no rotor inertia, and {source} is "
                f"{float(np.abs(armature).max()):g} kg m^2; use solver=featherstone or a spec with armature=0"
            )

    def make_solver(self, model: newton.Model):
        return semi_implicit_solver(model, self.options)

    def state_arrays(self, state: newton.State) -> tuple[wp.array, wp.array]:
        return state.body_q, state.body_qd

    def engine_split(self) -> int:
        return self.bodies_per_env * _POSE

    def _joint_buffers(self) -> tuple[wp.array, wp.array]:
        model = self.model
        return (
            wp.zeros(model.joint_coord_count, dtype=float, device=model.device, requires_grad=True),
            wp.zeros(model.joint_dof_count, dtype=float, device=model.device, requires_grad=True),
        )

    def add_frame_buffers(self, frame: Frame) -> None:
        frame.joint_q, frame.joint_qd = self._joint_buffers()  # the step's joint outputs, from IK
        super().add_frame_buffers(frame)

    def new_pd_coordinate_buffers(self) -> tuple[wp.array, wp.array]:
        return self._joint_buffers()

    def pd_coordinates(self, state: newton.State, buffers) -> tuple[wp.array, wp.array]:
        """Inverse kinematics into ``buffers`` (maximal coordinates hold no joint coordinates)."""
        q, qd = buffers
        newton.eval_ik(self.model, state, q, qd)
        return q, qd

    def finish_step(self, frame: Frame, last: newton.State) -> None:
        newton.eval_ik(self.model, last, frame.joint_q, frame.joint_qd)

    def joint_outputs(self, frame: Frame, engine: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.views(frame.joint_q).clone(), self.views(frame.joint_qd).clone()

    def output_seeds(self, frame: Frame, grad_engine, grad_q, grad_qd) -> list[tuple[wp.array, torch.Tensor]]:
        seeds = self.engine_seeds(frame.states[-1], grad_engine)
        if grad_q is not None:
            seeds.append((frame.joint_q, grad_q))
        if grad_qd is not None:
            seeds.append((frame.joint_qd, grad_qd))
        return seeds

    def state_from_generalized(self, joint_q, joint_qd, particle_q, particle_qd) -> SimState:
        joint_q = joint_q.to(self.device, torch.float32)
        joint_qd = joint_qd.to(self.device, torch.float32)
        engine = _ForwardKinematics.apply(self, joint_q, joint_qd)
        return SimState(joint_q=joint_q, joint_qd=joint_qd, engine=engine)

    def forward_kinematics(self, joint_q: torch.Tensor, joint_qd: torch.Tensor, record: bool):
        """Engine rows from generalized coordinates, on a tape of its own when ``record``."""
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
        engine = torch.cat((self.views(out.body_q, cache=False), self.views(out.body_qd, cache=False)), dim=1)
        return engine, (tape, q, qd, out)


class _ForwardKinematics(torch.autograd.Function):
    """Forward kinematics (joint_q, joint_qd) -> maximal-coordinate engine state."""

    @staticmethod
    def forward(ctx, family: SemiImplicitArticulation, joint_q: torch.Tensor, joint_qd: torch.Tensor):
        record = joint_q.requires_grad or joint_qd.requires_grad
        engine, (tape, q, qd, out) = family.forward_kinematics(joint_q, joint_qd, record)
        ctx.family, ctx.tape, ctx.arrays = family, tape, (q, qd, out)
        return engine

    @staticmethod
    def backward(ctx, grad_engine):
        family, (q, qd, out) = ctx.family, ctx.arrays
        views, k = family.views, family.engine_split()  # seeded as a frame's outputs are seeded
        with torch.no_grad():
            views(out.body_q.grad, cache=False).copy_(grad_engine[:, :k])
            views(out.body_qd.grad, cache=False).copy_(grad_engine[:, k:])
        ctx.tape.backward()
        grad_q = views(q.grad, cache=False).clone()
        grad_qd = views(qd.grad, cache=False).clone()
        ctx.tape.zero()
        return None, grad_q, grad_qd


# -- SolverFeatherstone: generalized coordinates ------------------------------------------------------
class FeatherstoneArticulation(Articulation):
    """Generalized coordinates, with per-frame system matrices; see the module docstring."""

    armature_mapping = "model.joint_armature on every articulated dof (the asset's when None)"
    MATRICES = ("M", "J", "P", "H", "L")

    def make_solver(self, model: newton.Model):
        substeps = self.physics.substeps
        self.mass_matrix_every = option_number(self.options, "mass_matrix_every", substeps, "newton", 1, integer=True)
        if substeps % self.mass_matrix_every:
            raise BackendError(
                f"mass_matrix_every={self.mass_matrix_every} must be a divisor of the {substeps} substeps"
            )
        self.matrix_updates = substeps // self.mass_matrix_every
        return newton.solvers.SolverFeatherstone(model, update_mass_matrix_interval=self.mass_matrix_every)

    def state_arrays(self, state: newton.State) -> tuple[wp.array, wp.array]:
        return state.joint_q, state.joint_qd

    def engine_split(self) -> int:
        return self.layout.nq

    def complete_loaded_state(self, state: newton.State) -> None:
        """Body poses for the collision pipeline (the solver recomputes them on the tape)."""
        newton.eval_fk(self.model, state.joint_q, state.joint_qd, state)

    def new_matrix_buffers(self) -> dict[str, wp.array]:
        """Fresh arrays shaped like the solver's system matrices."""
        return {name: wp.zeros_like(getattr(self.solver, name), requires_grad=True) for name in self.MATRICES}

    def add_frame_buffers(self, frame: Frame) -> None:
        super().add_frame_buffers(frame)
        # the solver keeps its mass matrix, Jacobian and Cholesky factor in buffers that every step
        # overwrites; a frame owns one set per mass-matrix update so its tape replays them
        frame.matrices = [self.new_matrix_buffers() for _ in range(self.matrix_updates)]

    def before_substep(self, frame: Frame, s: int) -> None:
        # the solver rebuilds its matrices when its step counter is a multiple of mass_matrix_every:
        # point it at this frame's buffers for that update and the substeps that use it
        self.solver._step = s
        for name, array in frame.matrices[s // self.mass_matrix_every].items():
            setattr(self.solver, name, array)

    def after_taped_substep(self, tape: wp.Tape, state: newton.State) -> None:
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

    def joint_outputs(self, frame: Frame, engine: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        nq = self.layout.nq
        return engine[:, :nq].clone(), engine[:, nq:].clone()

    def output_seeds(self, frame: Frame, grad_engine, grad_q, grad_qd) -> list[tuple[wp.array, torch.Tensor]]:
        """joint_q / joint_qd are copies of the engine rows' columns: their gradients add up to one."""
        nq = self.layout.nq
        total = torch.zeros(self.num_envs, self.layout.nq + self.layout.nv, device=self.device)
        for grad, cols in ((grad_engine, slice(None)), (grad_q, slice(0, nq)), (grad_qd, slice(nq, None))):
            if grad is not None:
                total[:, cols] += grad.float()
        return self.engine_seeds(frame.states[-1], total)

    def state_from_generalized(self, joint_q, joint_qd, particle_q, particle_qd) -> SimState:
        """Generalized coordinates are the engine state (quaternion normalised, as FK does)."""
        joint_q = joint_q.to(self.device, torch.float32)
        joint_qd = joint_qd.to(self.device, torch.float32)
        if self.layout.floating_base:
            quat = torch.nn.functional.normalize(joint_q[:, 3:7], dim=1)
            joint_q = torch.cat((joint_q[:, :3], quat, joint_q[:, 7:]), dim=1)
        return SimState(joint_q=joint_q, joint_qd=joint_qd, engine=torch.cat((joint_q, joint_qd), dim=1))


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
