"""The SHAC/DiffRL Ant: forward running on flat ground.

Facts carried over from DiffRL's ``AntEnv`` (Xu et al., 2022): frame dt 1/60 with 16 substeps,
joint torques 200 * clip(action, -1, 1), termination below a torso height of 0.27 m, episodes of
1000 steps, the 37-dim observation and the reward below. The model is z-up here (DiffRL's was
y-up); the target direction is +x.

Physics presets (``--preset``; docs/physics.md compares them):

* ``bench`` (default): DiffRL's model (density 1000, armature 0.05, joint damping 1) and contact
  constants with the contact damping and friction slope softened (kd 1e3, kf 3e2; DiffRL's 1e4 and
  3e3 make the adjoints explode), integrated in generalized coordinates (Newton's Featherstone),
  which is what MuJoCo integrates: the two engines then simulate the same Ant.
* ``bench_semi_implicit``: the same constants on Newton's semi-implicit solver (maximal coordinates,
  joints held by penalty springs) with no armature, which that solver cannot represent. About 5x
  the throughput; its joints stretch under load, so its physics is not MuJoCo's.
* ``bench_kf3000``: the bench constants with DiffRL's own friction slope, kf 3e3, kept to compare
  training there; on Featherstone its gradients stay sound (docs/gradient-statistics.md).
* ``diffrl_contacts``: ``bench_semi_implicit`` with DiffRL's own contact damping and friction slope
  (kd 1e4, kf 3e3), integrated semi-implicitly as DiffRL's dflex does: the setting where the actor
  gradients explode in training, with the h-step and the TD-lambda return alike
  (docs/gradient-statistics.md).
* ``rewarped``: Rewarped 1.3.3's ``AntDflex``, the paper's simulator, constant by constant:
  Featherstone; the contact constants of an Ant shape (ke 4e3, kd 1e3, kf 3e2, mu 0.75) averaged with
  Rewarped's ground plane (ke 1e5, kd 1e3, kf 1e3, mu 0.5), as its contact kernel does; limits ke 1e3 /
  kd 10; armature 0.001 x armature_scale 5; no joint damping (its force-mode joints apply none); the
  torso sphere at the asset's density 5 while its capsules get the parser's 1000 (117 kg in all,
  against 182 kg). Not reproduced: its 44 self-contact pairs and per-substep collision detection
  (this harness collides robot against ground, once per control step), and the armature it also adds
  to each leg body's inertia.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import torch

from simcore import ControlKind, PhysicsSpec, SimState, StateLayout, quat_rotate
from tasks.base import ASSET_DIR, PhysicsPreset, Task, floating_base_pose, random_tilt, symmetric_uniform

# hip_1, ankle_1, hip_2, ankle_2, hip_3, ankle_3, hip_4, ankle_4 (the asset's joint order)
DEFAULT_DOF_Q = (0.0, 1.0, 0.0, -1.0, 0.0, -1.0, 0.0, 1.0)
START_HEIGHT = 0.75

#: the project's constants: DiffRL's Ant with softened contact damping and friction (module docstring)
BENCH_PHYSICS = PhysicsSpec(
    frame_dt=1.0 / 60.0,
    substeps=16,
    contact_ke=4.0e4,
    contact_kd=1.0e3,
    contact_kf=3.0e2,
    contact_mu=0.75,
    joint_limit_ke=1.0e3,
    joint_limit_kd=1.0e1,
    joint_damping=1.0,
    armature=None,  # the asset's 0.05
)


def _averaged(shape: float, ground: float) -> float:
    """A contact constant of an Ant shape against Rewarped's ground plane: the mean of the two."""
    return 0.5 * (shape + ground)


REWARPED_PHYSICS = PhysicsSpec(
    frame_dt=1.0 / 60.0,
    substeps=16,
    contact_ke=_averaged(4.0e3, 1.0e5),
    contact_kd=_averaged(1.0e3, 1.0e3),
    contact_kf=_averaged(3.0e2, 1.0e3),
    contact_mu=_averaged(0.75, 0.5),
    joint_limit_ke=1.0e3,
    joint_limit_kd=1.0e1,
    joint_damping=0.0,
    armature=0.001 * 5.0,  # the asset's armature times Rewarped's armature_scale
)

PRESETS = {
    "bench": PhysicsPreset(
        BENCH_PHYSICS,
        {"newton": {"solver": "featherstone"}},
        about="DiffRL's Ant, contact kd 1e3 and kf 3e2, generalized coordinates",
    ),
    "bench_semi_implicit": PhysicsPreset(
        dataclasses.replace(BENCH_PHYSICS, armature=0.0),
        {"newton": {"solver": "semi_implicit"}},
        about="the bench constants without armature on Newton's semi-implicit solver (maximal coordinates)",
    ),
    "bench_kf3000": PhysicsPreset(
        dataclasses.replace(BENCH_PHYSICS, contact_kf=3.0e3),
        {"newton": {"solver": "featherstone"}},
        about="the bench constants with DiffRL's friction slope kf 3e3 (ten times the bench's)",
    ),
    "diffrl_contacts": PhysicsPreset(
        dataclasses.replace(BENCH_PHYSICS, armature=0.0, contact_kd=1.0e4, contact_kf=3.0e3),
        {"newton": {"solver": "semi_implicit"}},
        about="bench_semi_implicit with DiffRL's own contact damping and friction slope (kd 1e4, kf 3e3)",
    ),
    "rewarped": PhysicsPreset(
        REWARPED_PHYSICS,
        {"newton": {"solver": "featherstone"}},
        asset_path=ASSET_DIR / "ant_rewarped.xml",
        about="Rewarped 1.3.3 AntDflex (the paper's simulator), without its self-collisions",
    ),
}


class Ant(Task):
    name = "ant"
    asset_path = ASSET_DIR / "ant.xml"
    asset_format = "mjcf"
    layout = StateLayout(num_dofs=8, floating_base=True)
    control_kind = ControlKind.JOINT_TORQUE
    action_dim = 8
    obs_dim = 37
    episode_length = 1000
    presets = PRESETS
    default_preset = "bench"

    action_strength = 200.0
    termination_height = 0.27
    target_distance = 1.0e4  # a far target along +x makes "heading" a projection onto +x

    def default_state(self) -> tuple[torch.Tensor, torch.Tensor]:
        return floating_base_pose(START_HEIGHT, DEFAULT_DOF_Q)

    def sample_initial_state(self, num_envs: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        uniform = functools.partial(symmetric_uniform, generator)  # U(-1, 1) of a shape
        q0, _ = self.default_state()
        q = q0.repeat(num_envs, 1)
        q[:, 0:3] += 0.1 * uniform(num_envs, 3)
        q[:, 3:7] = random_tilt(q[:, 3:7], math.pi / 24.0, generator)
        q[:, 7:] += 0.2 * uniform(num_envs, 8)
        qd = 0.25 * uniform(num_envs, self.layout.nv)
        return q, qd

    def actions_to_control(self, actions: torch.Tensor) -> torch.Tensor:
        return self.action_strength * torch.clamp(actions, -1.0, 1.0)

    def observe(self, state: SimState, prev_actions: torch.Tensor) -> torch.Tensor:
        quat = state.root_quat
        pos = state.root_pos
        up = quat_rotate(quat, _axis(quat, 2))
        forward = quat_rotate(quat, _axis(quat, 0))
        to_target = torch.zeros_like(pos)
        to_target[:, 0] = self.target_distance
        to_target = to_target - pos
        to_target[:, 2] = 0.0
        heading = (forward * torch.nn.functional.normalize(to_target, dim=-1)).sum(-1, keepdim=True)
        return torch.cat(
            (
                pos[:, 2:3],  # 0: torso height
                quat,  # 1-4
                state.root_lin_vel,  # 5-7
                state.root_ang_vel,  # 8-10
                state.dof_q(self.layout),  # 11-18
                0.1 * state.dof_qd(self.layout),  # 19-26
                up[:, 2:3],  # 27: up projection
                heading,  # 28: heading projection
                prev_actions,  # 29-36
            ),
            dim=-1,
        )

    def reward(
        self, state: SimState, obs: torch.Tensor, actions: torch.Tensor, prev_actions: torch.Tensor
    ) -> torch.Tensor:
        progress = obs[:, 5]
        up = 0.1 * obs[:, 27]
        heading = obs[:, 28]
        height = obs[:, 0] - self.termination_height
        return progress + up + heading + height

    def terminated(self, state: SimState, obs: torch.Tensor) -> torch.Tensor:
        return state.root_pos[:, 2] < self.termination_height


def _axis(like: torch.Tensor, index: int) -> torch.Tensor:
    e = torch.zeros(like.shape[0], 3, dtype=like.dtype, device=like.device)
    e[:, index] = 1.0
    return e
