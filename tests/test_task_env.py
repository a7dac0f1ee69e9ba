"""The vector env: episodes, automatic resets, termination vs truncation, gradient flow."""

from __future__ import annotations

import pytest
import torch

pytest.importorskip("newton")

from backends import make  # noqa: E402
from tasks import make_task  # noqa: E402
from tasks.env import TaskEnv  # noqa: E402


@pytest.fixture(scope="module")
def env():
    task = make_task("ant")
    return TaskEnv(task, make("newton", task, num_envs=3, seed=0), episode_length=3)


def test_truncation_resets_with_fresh_detached_observations(env):
    env.reset()
    actions = torch.zeros(3, 8, requires_grad=True)
    results = [env.step(actions) for _ in range(3)]
    assert not any(r.done.any() for r in results[:2])
    last = results[-1]
    assert last.truncated.all() and not last.terminated.any()
    assert torch.equal(last.episode_length, torch.full((3,), 3))
    expected_return = sum(r.reward.detach() for r in results)
    assert torch.allclose(last.episode_return, expected_return)
    assert not torch.equal(last.obs, last.final_obs.detach())  # obs rows come from the reset states
    (through_final,) = torch.autograd.grad(last.final_obs.sum(), actions, retain_graph=True)
    assert through_final.abs().sum() > 0
    if last.obs.requires_grad:  # torch.where keeps a (zero) path; it must carry nothing
        (through_reset,) = torch.autograd.grad(last.obs.sum(), actions, allow_unused=True)
        assert through_reset is None or through_reset.abs().sum() == 0
    assert torch.equal(last.obs[:, 29:], torch.zeros(3, 8))  # no previous action after a reset
    assert torch.equal(env.steps, torch.zeros(3, dtype=torch.long))


def test_termination_below_the_height_limit_is_not_truncation(env):
    env.reset()
    q, qd = env.task.sample_initial_state(3, torch.Generator().manual_seed(0))
    q[1, 2] = 0.2  # env 1 starts below the termination height
    env.sim.state = env.sim.state_from_generalized(q, qd)
    result = env.step(torch.zeros(3, 8))
    assert result.terminated.tolist() == [False, True, False]
    assert not result.truncated.any()
    assert env.sim.state.root_pos[1, 2] > 0.5  # env 1 was reset


def test_rewards_are_differentiable_through_the_window_until_cut(env):
    env.reset()
    env.cut_graph()
    a0 = torch.zeros(3, 8, requires_grad=True)
    env.step(a0)
    r = env.step(torch.zeros(3, 8)).reward.sum()
    (g,) = torch.autograd.grad(r, a0)
    assert g.abs().sum() > 0
    env.cut_graph()
    r = env.step(torch.zeros(3, 8)).reward.sum()
    (g,) = torch.autograd.grad(r, a0, allow_unused=True)
    assert g is None


def test_the_rollout_objective_is_the_env_s_own_rewards():
    """tasks.rollout.rollout_reward (what gradcheck differentiates) sums exactly the env's rewards, for a
    task whose reward depends on the current action (the point-mass plug-in: -|x|^2 - 0.01 |u|^2)."""
    import backends
    from tasks.rollout import rollout_reward

    if "pointmass" not in backends.available():
        pytest.skip("the test plugin is not installed here (tox -e py installs it)")
    task = make_task("pointmass")
    env = TaskEnv(task, make("pointmass", task, num_envs=4, seed=3))
    start = env.sim.state
    actions = torch.rand(5, 4, task.action_dim, generator=torch.Generator().manual_seed(0)) * 2 - 1
    env_total = sum(env.step(a).reward.double() for a in actions)
    helper_total = rollout_reward(env.sim, start, actions)
    torch.testing.assert_close(helper_total, env_total)
