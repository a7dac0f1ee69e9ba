"""Tests for algorithms/grad_variance.py."""

import pytest
import torch

from algorithms.grad_variance import (
    batch_gradient_variance,
    gradient_variance,
    group_gradients,
    group_losses,
    per_env_gradient_variance,
)
from algorithms.networks import GaussianActor

DT = torch.float64


def test_hand_computed_example():
    g = torch.tensor([[1.0, 0.0], [3.0, 0.0], [2.0, 3.0]], dtype=DT)
    # mean (2, 1); deviations (-1,-1), (1,-1), (0,2); squared norms 2 + 2 + 4 = 8; / (K-1) = 4.
    torch.testing.assert_close(gradient_variance(g), torch.tensor(4.0, dtype=DT))
    torch.testing.assert_close(per_env_gradient_variance(g, group_size=5), torch.tensor(20.0, dtype=DT))
    torch.testing.assert_close(batch_gradient_variance(g), torch.tensor(4.0 / 3.0, dtype=DT))


def test_equals_trace_of_torch_cov():
    g = torch.randn(6, 11, dtype=DT, generator=torch.Generator().manual_seed(1))
    torch.testing.assert_close(gradient_variance(g), torch.cov(g.T).trace())


def test_zero_for_identical_groups_and_positive_otherwise():
    row = torch.randn(1, 9, dtype=DT)
    assert gradient_variance(row.expand(4, 9)).item() == 0.0
    perturbed = row.expand(4, 9).clone()
    perturbed[2, 3] += 1e-3
    assert gradient_variance(perturbed).item() > 0.0


def test_group_gradients_linear_model():
    # loss_n = w . x_n  =>  per-env gradient x_n, group gradient = mean of x_n in the group.
    gen = torch.Generator().manual_seed(2)
    x = torch.randn(8, 3, dtype=DT, generator=gen)
    w = torch.randn(3, dtype=DT, generator=gen, requires_grad=True)
    unused = torch.zeros(2, dtype=DT, requires_grad=True)
    grads = group_gradients(x @ w, [w, unused], num_groups=4)
    assert grads.shape == (4, 5)
    torch.testing.assert_close(grads[:, :3], x.reshape(4, 2, 3).mean(1))
    assert torch.all(grads[:, 3:] == 0)
    assert not grads.requires_grad


def test_identical_envs_give_zero_variance_through_a_network():
    torch.manual_seed(3)
    actor = GaussianActor(4, 2).double()
    obs = torch.randn(1, 4, dtype=DT).expand(8, 4)
    loss_per_env = actor(obs, deterministic=True).pow(2).sum(-1)
    grads = group_gradients(loss_per_env, actor.parameters(), num_groups=4)
    assert grads.abs().sum() > 0
    assert gradient_variance(grads).item() == pytest.approx(0.0, abs=1e-20)
    distinct = actor(torch.randn(8, 4, dtype=DT), deterministic=True).pow(2).sum(-1)
    assert gradient_variance(group_gradients(distinct, actor.parameters(), 4)).item() > 0


def test_graph_survives_for_the_real_backward():
    w = torch.ones(3, dtype=DT, requires_grad=True)
    loss_per_env = (torch.arange(6, dtype=DT).reshape(6, 1) * w).pow(2).sum(-1)
    group_gradients(loss_per_env, [w], num_groups=2)
    loss_per_env.mean().backward()  # would raise if the graph had been freed
    assert w.grad is not None


def test_group_losses_mean_is_the_full_loss():
    losses = torch.randn(12, dtype=DT)
    groups = group_losses(losses, 3)
    torch.testing.assert_close(torch.stack(groups), losses.reshape(3, 4).mean(1))
    torch.testing.assert_close(torch.stack(groups).mean(), losses.mean())


def test_invalid_groupings_raise():
    with pytest.raises(ValueError):
        group_losses(torch.zeros(10), 3)
    with pytest.raises(ValueError):
        group_losses(torch.zeros(10), 1)
    with pytest.raises(ValueError):
        gradient_variance(torch.zeros(1, 4))


def test_rescalings_are_unbiased_for_iid_envs():
    # Per-env gradients iid N(0, sigma^2 I_P): tr Sigma = P sigma^2. Average over many repeats.
    gen = torch.Generator().manual_seed(4)
    reps, K, m, P, sigma = 4000, 8, 16, 4, 2.0
    per_env = sigma * torch.randn(reps, K, m, P, dtype=DT, generator=gen)
    group_means = per_env.mean(2)
    per_env_est = torch.stack([per_env_gradient_variance(g, m) for g in group_means]).mean()
    batch_est = torch.stack([batch_gradient_variance(g) for g in group_means]).mean()
    assert per_env_est.item() == pytest.approx(P * sigma**2, rel=0.03)
    assert batch_est.item() == pytest.approx(P * sigma**2 / (K * m), rel=0.03)
