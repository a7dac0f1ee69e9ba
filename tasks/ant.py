"""The SHAC/DiffRL Ant: forward running on flat ground.

Facts carried over from DiffRL's ``AntEnv`` (Xu et al., 2022): frame dt 1/60 with 16 substeps,
joint torques 200 * clip(action, -1, 1), termination below a torso height of 0.27 m, episodes of
1000 steps, the 37-dim observation and the reward below. The model is z-up here (DiffRL's was
y-up); the target direction is +x.
"""

from __future__ import annotations

import functools
import math

import torch

from simcore import ControlKind, SimState, StateLayout, quat_rotate
from tasks.base import ASSET_DIR, Task, floating_base_pose, random_tilt, symmetric_uniform

# hip_1, ankle_1, hip_2, ankle_2, hip_3, ankle_3, hip_4, ankle_4 (the asset's joint order)
DEFAULT_DOF_Q = (0.0, 1.0, 0.0, -1.0, 0.0, -1.0, 0.0, 1.0)
START_HEIGHT = 0.75


class Ant(Task):
    name = "ant"
    asset_path = ASSET_DIR / "ant.xml"
    asset_format = "mjcf"
    layout = StateLayout(num_dofs=8, floating_base=True)
    control_kind = ControlKind.JOINT_TORQUE
    action_dim = 8
    obs_dim = 37
    episode_length = 1000

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
