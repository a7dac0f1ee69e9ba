"""Tests for algorithms/grad_variance.py."""

import pytest
import torch

from algorithms.grad_variance import batch_gradient_variance, gradient_variance, per_env_gradient_variance

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


def test_invalid_groupings_raise():
    with pytest.raises(ValueError):
        gradient_variance(torch.zeros(1, 4))
    with pytest.raises(ValueError):
        gradient_variance(torch.zeros(4))


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
