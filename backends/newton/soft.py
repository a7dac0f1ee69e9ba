"""Soft bodies (``TET_ACTIVATION`` tasks, the SoftJumper) on Newton.

Particles and Neo-Hookean tets on the semi-implicit solver (Featherstone has no FEM), one body per
env scaled to the env's size (``SoftBodySpec``); the engine row is ``[particle_q, particle_qd]``,
activations are written to ``control.tet_activations``; particle-ground contact candidates are found
within ``contact_gap`` of the plane once per control step; particle-particle contact is off.
"""

from __future__ import annotations

import newton
import torch
import warp as wp

from backends.contract import BackendError
from backends.newton.family import EngineFamily, semi_implicit_solver
from backends.newton.tape import Frame
from simcore import SimState


class SoftBody(EngineFamily):
    """One FEM body per env on ``SolverSemiImplicit``; see the module docstring."""

    contact_mapping = "model.soft_contact_{name} (particle-ground penalty contact), as given"
    armature_mapping = "zero only (the semi-implicit solver has none); anything else is refused"

    def __init__(self, sim, solver: str):
        super().__init__(sim)
        self.body = sim.checked_soft_body()  # a task without one hears that first
        if solver != "semi_implicit":
            raise BackendError("soft bodies run on the semi_implicit solver (featherstone has no FEM)")

    # -- construction ---------------------------------------------------------------------
    def builder(self, shape_cfg) -> newton.ModelBuilder:
        """One soft body per env: the task's tet mesh scaled by the env's size factor, its particles
        carrying a quarter of each incident tet's mass (``SoftBodySpec``), one FEM element per tet."""
        body = self.body
        builder = newton.ModelBuilder(gravity=(0.0, 0.0, self.physics.gravity))
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

    def apply_physics(self, model: newton.Model) -> None:
        """Particle-ground contact constants (the kernel averages particle and shape values: both are
        the task's), no particle-particle contact (Newton warns that it may corrupt gradients, and envs
        overlap in space)."""
        phys = self.physics
        model.soft_contact_ke = phys.contact_ke
        model.soft_contact_kd = phys.contact_kd
        model.soft_contact_kf = phys.contact_kf
        model.soft_contact_mu = phys.contact_mu
        model.particle_grid = None

    def make_solver(self, model: newton.Model):
        return semi_implicit_solver(model, self.options)

    def collision_pipeline(self, model: newton.Model, contact_gap: float) -> newton.CollisionPipeline:
        """Particle-ground candidates within ``contact_gap`` of the plane, found once per control step."""
        return newton.CollisionPipeline(model, requires_grad=True, soft_contact_gap=contact_gap)

    # -- engine rows <-> Warp state -------------------------------------------------------
    def state_arrays(self, state: newton.State) -> tuple[wp.array, wp.array]:
        return state.particle_q, state.particle_qd

    def engine_split(self) -> int:
        return 3 * self.layout.num_particles

    def sim_state(self, engine: torch.Tensor, joint_q=None, joint_qd=None) -> SimState:
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

    def state_from_generalized(self, joint_q, joint_qd, particle_q, particle_qd) -> SimState:
        n = self.num_envs
        flat = (p.to(self.device, torch.float32).reshape(n, -1) for p in (particle_q, particle_qd))
        return self.sim_state(torch.cat(tuple(flat), dim=1))

    # -- one control step -----------------------------------------------------------------
    def control_array(self, frame: Frame) -> wp.array:
        return frame.control.tet_activations

    def substep_control(self, state: newton.State, frame: Frame, s: int) -> newton.Control:
        return frame.control

    def joint_outputs(self, frame: Frame, engine: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """No joints: (N, 0); particle_q / particle_qd are torch views of the engine (:meth:`sim_state`)."""
        empty = engine.new_zeros(self.num_envs, 0)
        return empty, empty.clone()

    def output_seeds(self, frame: Frame, grad_engine, grad_q, grad_qd) -> list[tuple[wp.array, torch.Tensor]]:
        return self.engine_seeds(frame.states[-1], grad_engine)  # the (N, 0) joint outputs carry no gradient

    # -- the bare reference rollout -------------------------------------------------------
    def bare_controls(self, horizon: int, rng, grad: bool, current: SimState):
        """Activations as the SoftJumper's actions give them."""
        controls = [self.model.control(requires_grad=grad) for _ in range(horizon)]
        for control in controls:
            control.tet_activations.assign(
                rng.uniform(-0.3, 0.3, self.num_envs * self.layout.num_tets).astype("float32")
            )
        return lambda t, s, state: controls[t]

    def bare_loss(self, state: newton.State, loss: wp.array) -> None:
        wp.launch(_sum_particles, dim=self.model.particle_count, inputs=[state.particle_q], outputs=[loss])


@wp.kernel
def _sum_particles(particle_q: wp.array[wp.vec3], loss: wp.array[float]):
    i = wp.tid()
    p = particle_q[i]
    wp.atomic_add(loss, 0, p[0] + p[1] + p[2])
