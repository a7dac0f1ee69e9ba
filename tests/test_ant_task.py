"""The Ant task's torch code, without any engine."""

from __future__ import annotations

import math

import pytest
import torch

from simcore import SimState, quat_from_angle_axis, quat_mul, quat_rotate
from tasks import make_task


@pytest.fixture
def ant():
    return make_task("ant")


def _state(q: torch.Tensor, qd: torch.Tensor) -> SimState:
    return SimState(joint_q=q, joint_qd=qd, engine=torch.zeros(q.shape[0], 1))


def test_observation_layout_and_reward(ant):
    q, qd = ant.default_state()
    q, qd = q.repeat(2, 1), qd.repeat(2, 1)
    qd[:, 0] = torch.tensor([1.5, -0.5])  # forward velocity
    qd[:, 6:] = 2.0
    prev = torch.full((2, 8), 0.3)
    obs = ant.observe(_state(q, qd), prev)
    assert obs.shape == (2, 37)
    assert torch.allclose(obs[:, 0], torch.tensor(0.75))  # height
    assert torch.allclose(obs[:, 1:5], torch.tensor([0.0, 0.0, 0.0, 1.0]))
    assert torch.allclose(obs[:, 11:19], q[:, 7:])
    assert torch.allclose(obs[:, 19:27], torch.full((2, 8), 0.2))  # 0.1 * joint velocity
    assert torch.allclose(obs[:, 27], torch.tensor(1.0))  # upright
    assert torch.allclose(obs[:, 28], torch.tensor(1.0))  # facing +x
    assert torch.allclose(obs[:, 29:], prev)
    # forward velocity + 0.1 * up + heading + (height - 0.27)
    expected = qd[:, 0] + 0.1 + 1.0 + (0.75 - 0.27)
    assert torch.allclose(ant.reward(_state(q, qd), obs, prev, torch.zeros_like(prev)), expected)


def test_heading_and_up_follow_the_torso_rotation(ant):
    q, qd = ant.default_state()
    q = q.repeat(2, 1)
    yaw = quat_from_angle_axis(torch.tensor(math.pi / 2), torch.tensor([0.0, 0.0, 1.0]))
    roll = quat_from_angle_axis(torch.tensor(math.pi / 2), torch.tensor([1.0, 0.0, 0.0]))
    q[0, 3:7], q[1, 3:7] = yaw, roll
    obs = ant.observe(_state(q, qd.repeat(2, 1)), torch.zeros(2, 8))
    assert obs[0, 28].abs() < 1e-6 and torch.isclose(obs[0, 27], torch.tensor(1.0))  # facing +y, upright
    assert obs[1, 27].abs() < 1e-6 and torch.isclose(obs[1, 28], torch.tensor(1.0))  # on its side, facing +x


def test_termination_below_height(ant):
    q, qd = ant.default_state()
    q = q.repeat(3, 1)
    q[:, 2] = torch.tensor([0.5, 0.27, 0.2])
    state = _state(q, qd.repeat(3, 1))
    done = ant.terminated(state, ant.observe(state, torch.zeros(3, 8)))
    assert done.tolist() == [False, False, True]


def test_actions_become_clipped_torques(ant):
    a = torch.tensor([[-3.0, -1.0, -0.5, 0.0, 0.25, 1.0, 2.0, 0.1]], requires_grad=True)
    tau = ant.actions_to_control(a)
    assert torch.allclose(tau, 200.0 * a.detach().clamp(-1, 1))
    tau.sum().backward()
    assert a.grad.tolist()[0] == [0.0, 200.0, 200.0, 200.0, 200.0, 200.0, 0.0, 200.0]


def test_initial_state_randomisation_ranges_and_seeding(ant):
    q, qd = ant.sample_initial_state(4096, torch.Generator().manual_seed(3))
    q_again, _ = ant.sample_initial_state(4096, torch.Generator().manual_seed(3))
    assert torch.equal(q, q_again)
    q0, _ = ant.default_state()
    assert (q[:, :3] - q0[:3]).abs().max() <= 0.1 + 1e-6
    assert (q[:, :3] - q0[:3]).abs().max() > 0.09  # actually randomised
    assert torch.allclose(q[:, 3:7].norm(dim=1), torch.ones(4096), atol=1e-5)
    tilt = 2 * torch.acos(q[:, 6].clamp(-1, 1))
    assert tilt.max() <= math.pi / 24 + 1e-4
    assert (q[:, 7:] - q0[7:]).abs().max() <= 0.2 + 1e-6
    assert qd.abs().max() <= 0.25 + 1e-6 and qd.abs().max() > 0.2


def test_rotation_helpers_agree():
    axis = torch.nn.functional.normalize(torch.randn(16, 3), dim=-1)
    a = quat_from_angle_axis(torch.rand(16), axis)
    b = quat_from_angle_axis(torch.rand(16), torch.nn.functional.normalize(torch.randn(16, 3), dim=-1))
    v = torch.randn(16, 3)
    # rotating by a*b equals rotating by b then by a; rotation about the axis leaves the axis fixed
    assert torch.allclose(quat_rotate(quat_mul(a, b), v), quat_rotate(a, quat_rotate(b, v)), atol=1e-5)
    assert torch.allclose(quat_rotate(a, axis), axis, atol=1e-6)
