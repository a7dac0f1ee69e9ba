"""The public differentiable env (harness/diffenv.py): the field's step tuple over TaskEnv, graph cuts
that hold, and the example that trains a policy through it."""

from __future__ import annotations

import runpy
from pathlib import Path

import pytest
import torch

pytest.importorskip("newton")

from harness.diffenv import DiffEnv, make_diff_env  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "first_order_policy.py"


def test_step_returns_the_fields_tuple_and_its_gradient_is_the_task_envs():
    env = make_diff_env("ant", "newton", num_envs=3, horizon=4, seed=2)
    twin = make_diff_env("ant", "newton", num_envs=3, horizon=4, seed=2)
    assert isinstance(env, DiffEnv) and (env.num_obs, env.num_actions) == (env.task.obs_dim, env.task.action_dim)
    env.reset(), twin.reset()
    actions = torch.full((3, env.num_actions), 0.3, requires_grad=True)
    obs, reward, done, extras = env.step(actions)
    assert obs.shape == (3, env.num_obs) and reward.shape == (3,) and done.dtype == torch.long
    assert set(extras) == {"obs_before_reset", "episode_end", "truncated", "episode_return", "episode_length"}
    (grad,) = torch.autograd.grad(reward.sum(), actions)
    theirs = torch.full((3, env.num_actions), 0.3, requires_grad=True)
    result = twin.env.step(theirs)
    (expected,) = torch.autograd.grad(result.reward.sum(), theirs)
    assert torch.equal(grad, expected) and float(grad.abs().sum()) > 0.0


def test_a_window_boundary_cuts_the_graph():
    env = make_diff_env("ant", "newton", num_envs=2, horizon=4, seed=0)
    env.reset()
    early = torch.zeros(2, env.num_actions, requires_grad=True)
    env.step(early)
    obs = env.initialize_trajectory()
    assert not obs.requires_grad
    late = torch.zeros(2, env.num_actions, requires_grad=True)
    _, reward, _, _ = env.step(late + 0.1 * torch.tanh(obs[:, : env.num_actions]))
    early_grad, late_grad = torch.autograd.grad(reward.sum(), (early, late), allow_unused=True)
    assert early_grad is None and late_grad is not None


def test_checkpoints_continue_the_episodes_exactly():
    env = make_diff_env("ant", "newton", num_envs=2, horizon=4, seed=1)
    env.reset()
    actions = torch.full((2, env.num_actions), -0.2)
    with torch.no_grad():
        env.step(actions)
        saved = env.get_checkpoint()
        first = env.step(actions)[0]
        env.load_checkpoint(saved)
        again = env.step(actions)[0]
    assert torch.equal(first, again)


def test_the_example_trains_a_policy_through_the_simulator():
    """The example's loop runs as written, with a finite reward in every iteration."""
    train = runpy.run_path(str(EXAMPLE))["train"]
    history = train(num_envs=4, horizon=4, iterations=3, log=lambda _: None)
    assert len(history) == 3 and all(torch.isfinite(torch.tensor(history)))
