"""SoftJumper: a tetrahedral soft body that learns to jump forward by activating its tetrahedra.

After Rewarped's SoftJumper (which the paper's soft-body experiments use), in z-up coordinates.
The body is the project's own mesh (:func:`tasks.tetmesh.table_mesh`: a slab on four legs,
2.5 x 2.5 x 1.8 m, 179 particles, 480 tetrahedra), Neo-Hookean FEM with k_mu = k_lambda = 1000 Pa,
k_damp = 1, density 1, on a ground plane (contact ke 2e3, kd 0.1, kf 10, mu 0.7), 60 Hz control with
80 substeps.

Control (``TET_ACTIVATION``): 240 actions, each driving the two tetrahedra ``2k`` and ``2k + 1``
(halves of one voxel of the mesh), clipped to [-1, 1] and scaled by 0.3 into activations.

Reward, in SI units of the simulated body (no position or velocity rescaling):
``10 * v_x(COM) + 30 * (z_COM - z_COM,start) - 0.001 * |a|^2`` where ``z_COM,start`` is the height
of the env's undeformed body standing on the ground (its COM height at rest, before gravity sags
it), so the height term rewards being higher than standing. Episodes last 300 steps (5 s); they
never end early.

Initial states: the env's body (scaled by its fixed size factor, +-10% over the envs: see
``simcore.SoftBodySpec.rest_scales``) undeformed, at rest, moved by a random horizontal offset and
dropped from a random height above the ground.

Observation (N, 1320): COM position (3) and velocity (3); particle positions (537) and velocities
(537) relative to the COM's; the previous actions (240).
"""

from __future__ import annotations

from pathlib import Path

import torch

from simcore import ControlKind, PhysicsSpec, SimState, SoftBodySpec, StateLayout
from tasks import tetmesh
from tasks.base import PhysicsPreset, Task, symmetric_uniform

SOFT_JUMPER_PHYSICS = PhysicsSpec(
    frame_dt=1.0 / 60.0,
    substeps=80,
    contact_ke=2.0e3,
    contact_kd=0.1,
    contact_kf=10.0,
    contact_mu=0.7,
)


def _soft_body() -> SoftBodySpec:
    vertices, tets = tetmesh.table_mesh()
    return SoftBodySpec(
        vertices=torch.from_numpy(vertices),
        tets=torch.from_numpy(tets),
        k_mu=1.0e3,
        k_lambda=1.0e3,
        k_damp=1.0,
        density=1.0,
        particle_radius=0.02,
        scale_spread=0.1,
        scale_seed=7,
    )


class SoftJumper(Task):
    name = "soft_jumper"
    asset_path = Path(tetmesh.__file__)  # the mesh is generated in code (tasks/tetmesh.py)
    asset_format = "tetmesh"
    soft_body = _soft_body()
    layout = StateLayout(
        num_dofs=0, floating_base=False, num_particles=soft_body.num_particles, num_tets=soft_body.num_tets
    )
    control_kind = ControlKind.TET_ACTIVATION
    tets_per_action = 2
    action_dim = soft_body.num_tets // tets_per_action
    obs_dim = 6 + 6 * soft_body.num_particles + action_dim
    episode_length = 300
    airborne_height = 0.5  # lowest particle (m): 8 steps of free fall (9 cm) stay clear of the ground
    activation_scale = 0.3
    # reward weights
    forward_weight = 10.0
    height_weight = 30.0
    action_weight = 1.0e-3
    # initial states
    max_offset = 0.25  # horizontal offset U(-0.25, 0.25) m in x and y
    max_drop = 0.2  # lowest particle U(0, 0.2) m above touching the ground

    presets = {
        "rewarped": PhysicsPreset(
            SOFT_JUMPER_PHYSICS,
            about="Rewarped's Jumper material, contact constants and 80 substeps (module docstring)",
        )
    }
    default_preset = "rewarped"

    def __init__(self, physics: PhysicsSpec | None = None, preset: str | None = None):
        super().__init__(physics, preset)
        body = self.soft_body
        masses = body.particle_masses()
        self._com_weights = (masses / masses.sum()).float()  # the same at every scale
        self._rest_com_z = float((masses / masses.sum()) @ body.vertices[:, 2])  # lowest vertex at z = 0

    # -- state -----------------------------------------------------------------------------
    def sample_initial_state(self, num_envs: int, generator: torch.Generator) -> tuple[torch.Tensor, ...]:
        body = self.soft_body
        scales = body.rest_scales(num_envs).float().reshape(-1, 1, 1)
        shift = torch.zeros(num_envs, 1, 3)
        shift[:, 0, :2] = self.max_offset * symmetric_uniform(generator, num_envs, 2)
        shift[:, 0, 2] = body.particle_radius + self.max_drop * torch.rand(num_envs, generator=generator)
        particle_q = body.vertices.float().unsqueeze(0) * scales + shift
        particle_qd = torch.zeros_like(particle_q)
        empty = torch.zeros(num_envs, 0)
        return empty, empty.clone(), particle_q, particle_qd

    def standing_com_height(self, num_envs: int, like: torch.Tensor) -> torch.Tensor:
        """(N,) z_COM,start: COM height of each env's undeformed body with its feet on the ground."""
        scales = self.soft_body.rest_scales(num_envs).to(like)
        return scales * self._rest_com_z + self.soft_body.particle_radius

    def com(self, state: SimState) -> tuple[torch.Tensor, torch.Tensor]:
        """Mass-weighted centre of mass (N, 3) and its velocity (N, 3)."""
        w = self._com_weights.to(state.particle_q)
        return torch.einsum("p,npk->nk", w, state.particle_q), torch.einsum("p,npk->nk", w, state.particle_qd)

    # -- control, observation, reward -------------------------------------------------------
    def actions_to_control(self, actions: torch.Tensor) -> torch.Tensor:
        """Per-tet activations (N, T): each action, clipped to [-1, 1] and scaled, drives two tets."""
        activation = self.activation_scale * actions.clamp(-1.0, 1.0)
        return activation.repeat_interleave(self.tets_per_action, dim=1)

    def observe(self, state: SimState, prev_actions: torch.Tensor) -> torch.Tensor:
        com, com_vel = self.com(state)
        n = com.shape[0]
        return torch.cat(
            (
                com,  # 0-2
                com_vel,  # 3-5
                (state.particle_q - com.unsqueeze(1)).reshape(n, -1),  # particle positions about the COM
                (state.particle_qd - com_vel.unsqueeze(1)).reshape(n, -1),  # and velocities
                prev_actions,
            ),
            dim=-1,
        )

    def reward(
        self, state: SimState, obs: torch.Tensor, actions: torch.Tensor, prev_actions: torch.Tensor
    ) -> torch.Tensor:
        com, com_vel = self.com(state)
        rise = com[:, 2] - self.standing_com_height(com.shape[0], com)
        return (
            self.forward_weight * com_vel[:, 0]
            + self.height_weight * rise
            - self.action_weight * actions.pow(2).sum(-1)
        )

    def forward_velocity(self, state: SimState) -> torch.Tensor:
        """The centre of mass's velocity along +x (the reward's forward term)."""
        return self.com(state)[1][:, 0]

    def terminated(self, state: SimState, obs: torch.Tensor) -> torch.Tensor:
        return torch.zeros(state.particle_q.shape[0], dtype=torch.bool, device=state.particle_q.device)
