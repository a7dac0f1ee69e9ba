"""Soft bodies on MuJoCo-Warp: the task's tet mesh as a MuJoCo flex, activations as nodal forces.

Model (:func:`build_soft_spec`, one per env, because each env's body has its own size):

* one body per vertex at its rest position, carrying the vertex's mass (a quarter of every incident
  tet's, as Newton's FEM gives it), with three slide joints along the world axes: ``qpos`` are the
  vertices' displacements from rest, ``qvel`` their velocities, ``qfrc_applied`` forces on them;
* a ``dim = 3`` flex over the tets with MuJoCo's linear elasticity, Young's modulus and Poisson
  ratio converted from the Lame parameters: ``E = mu (3 lambda + 2 mu) / (lambda + mu)``,
  ``nu = lambda / (2 (lambda + mu))`` (k_mu = k_lambda = 1000 Pa: E = 2500 Pa, nu = 0.25), and
  damping ``k_damp / E`` (MuJoCo's flex damping is stiffness-proportional, in seconds; Newton's
  ``k_damp`` is a viscosity in Pa s: the ratio gives the same damping stress for the same strain
  rate in the linear regime);
* ground contact: vertex spheres of the particle radius against the plane, the task's penalty
  constants converted as for rigid bodies (:mod:`backends.mujoco_penalty`: direct-form solref,
  constant impedance, elliptic cone with ``impratio = kf / kd``), with the mean vertex mass standing
  in for each vertex's, since a flex has one solref.

Activations: MuJoCo has no per-element activation, so Newton's activation term (the ``a`` in its
volume force ``k_lambda V (J - alpha + a) dJ/dx``) is applied as the equivalent nodal forces
(:func:`simcore.activation_nodal_forces`), computed in torch from the current vertex positions and
written to ``qfrc_applied`` before **every substep**, as Newton's FEM re-evaluates it every substep.
"""

from __future__ import annotations

import mujoco
import mujoco_warp as mjw
import torch
import warp as wp

from backends.contract import BackendError
from backends.mujoco_penalty import constant_solimp, penalty_solref
from backends.mujoco_warp.stepping import SubstepReplay, run_substeps
from simcore import SoftBodySpec, activation_nodal_forces


def young_and_poisson(k_mu: float, k_lambda: float) -> tuple[float, float]:
    """Young's modulus (Pa) and Poisson ratio of the Lame parameters."""
    return k_mu * (3.0 * k_lambda + 2.0 * k_mu) / (k_lambda + k_mu), k_lambda / (2.0 * (k_lambda + k_mu))


def build_soft_spec(task, scale: float) -> mujoco.MjSpec:
    """One env's soft body (the rest mesh scaled by ``scale``) on a ground plane; module docstring."""
    body: SoftBodySpec = task.soft_body
    phys = task.physics
    spec = mujoco.MjSpec()
    spec.option.timestep = phys.sim_dt
    spec.option.gravity = [0.0, 0.0, phys.gravity]
    if phys.ground_plane:
        spec.worldbody.add_geom(
            name="ground",
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            size=[0.0, 0.0, 1.0],
            friction=[phys.contact_mu, 0.005, 0.0001],
        )
    masses = (body.particle_masses() * scale**3).tolist()
    names = []
    for i, (position, mass) in enumerate(zip((body.vertices * scale).tolist(), masses, strict=True)):
        vertex = spec.worldbody.add_body(name=f"vertex{i}", pos=position)
        vertex.mass = mass
        vertex.inertia = [1e-9, 1e-9, 1e-9]  # a point mass: slide joints carry no rotation
        vertex.explicitinertial = True
        for axis in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)):
            vertex.add_joint(type=mujoco.mjtJoint.mjJNT_SLIDE, axis=list(axis))
        names.append(vertex.name)
    young, poisson = young_and_poisson(body.k_mu, body.k_lambda)
    flex = spec.add_flex()
    flex.name = "soft_body"
    flex.dim = 3
    flex.vertbody = names
    flex.vert = [0.0] * (3 * len(names))  # each vertex at its body's origin
    flex.elem = body.tets.reshape(-1).tolist()
    flex.radius = body.particle_radius
    flex.young = young
    flex.poisson = poisson
    flex.damping = body.k_damp / young
    flex.friction = [phys.contact_mu, 0.005, 0.0001]
    flex.selfcollide = mujoco.mjtFlexSelf.mjFLEXSELF_NONE
    # the penalty conversion of backends/mujoco_penalty.py; a flex has one solref for all its
    # vertices, so A is the inverse of the mean vertex mass
    mean_mass = sum(masses) / len(masses)
    flex.solref = penalty_solref(phys.contact_ke, phys.contact_kd, 1.0 / mean_mass)
    flex.solimp = constant_solimp()
    flex.condim = 1 if phys.contact_kf <= 0 or phys.contact_mu <= 0 else 3
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    if flex.condim == 3:
        if phys.contact_kd <= 0:
            raise BackendError("PhysicsSpec.contact_kf > 0 needs contact_kd > 0 on mujoco_warp (impratio = kf / kd)")
        spec.option.impratio = phys.contact_kf / phys.contact_kd
    return spec


class SoftEnvModels:
    """Every env's compiled model, its rest positions, and Warp ``Data`` batches keyed by (env, worlds)."""

    def __init__(
        self, task, num_envs: int, stepper: SubstepReplay, torch_device: torch.device, nconmax: int, njmax: int
    ):
        self.task, self.stepper, self.device = task, stepper, torch_device
        wp_device = self.wp_device = stepper.wp_device
        self.nconmax, self.njmax = nconmax, njmax
        body = task.soft_body
        self.scales = body.rest_scales(num_envs)
        self.mjm = [build_soft_spec(task, float(s)).compile() for s in self.scales]
        with wp.ScopedDevice(wp_device):
            self.models = [mjw.put_model(m) for m in self.mjm]
        rest = body.vertices.unsqueeze(0) * self.scales.reshape(-1, 1, 1)
        self.rest = rest.to(torch_device, torch.float32)  # (N, P, 3)
        self.tets = body.tets.to(torch_device)
        self._data: dict[tuple[int, int], tuple[mjw.Data, dict[str, torch.Tensor]]] = {}

    def _data_for(self, env: int, nworld: int):
        key = (env, nworld)
        if key not in self._data:
            with wp.ScopedDevice(self.wp_device):
                data = mjw.make_data(self.mjm[env], nworld=nworld, nconmax=self.nconmax, njmax=self.njmax)
            names = ("qpos", "qvel", "qfrc_applied", "qacc_warmstart", "time", "overflow")
            self._data[key] = (data, {k: wp.to_torch(getattr(data, k)) for k in names})
        return self._data[key]

    def run(self, env: int, qpos: torch.Tensor, qvel: torch.Tensor, activation: torch.Tensor) -> torch.Tensor:
        """One control step of ``W`` worlds of env ``env``: displacements (W, 3P), velocities (W, 3P) and
        tet activations (W, T) -> next engine rows (W, 6P); nodal activation forces every substep."""
        data, view = self._data_for(env, qpos.shape[0])
        view["qpos"].copy_(qpos)
        view["qvel"].copy_(qvel)
        view["qacc_warmstart"].zero_()
        view["time"].zero_()
        view["overflow"].zero_()
        rest = self.rest[env].unsqueeze(0)
        k_lambda = self.task.soft_body.k_lambda

        def activation_forces() -> None:
            positions = rest + view["qpos"].reshape(qpos.shape[0], -1, 3)
            forces = activation_nodal_forces(positions, self.tets, activation, k_lambda)
            view["qfrc_applied"].copy_(forces.reshape(qpos.shape[0], -1))

        substeps = self.task.physics.substeps
        buffers = (self.nconmax, self.njmax)
        return run_substeps(self.models[env], data, view, substeps, self.stepper, activation_forces, buffers)
