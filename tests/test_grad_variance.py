"""Tests for algorithms/grad_variance.py."""

import pytest
import torch

from algorithms.grad_variance import (
    batch_gradient_variance,
    gradient_statistics,
    gradient_variance,
    per_env_gradient_variance,
)

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


def test_scale_free_statistics_hand_computed():
    g = torch.tensor([[1.0, 0.0], [3.0, 0.0], [2.0, 3.0]], dtype=DT)
    stats = gradient_statistics(g)
    # Var_K = 4 (above); ||g_bar||^2 = 5; bias-corrected signal 5 - 4/3 = 11/3
    assert stats["grad_var"] == pytest.approx(4.0)
    assert stats["grad_mean_norm"] == pytest.approx(5.0**0.5)
    assert stats["grad_nsr"] == pytest.approx(12.0 / 11.0)
    # pairwise cosines 1, 2/sqrt(13), 2/sqrt(13)
    assert stats["grad_cosine"] == pytest.approx((1.0 + 4.0 / 13.0**0.5) / 3.0)


def test_scale_free_statistics_ignore_scale_and_raw_variance_scales_with_its_square():
    g = torch.randn(4, 50, dtype=DT, generator=torch.Generator().manual_seed(2)) + 0.3
    base, scaled = gradient_statistics(g), gradient_statistics(-7.5 * g)
    assert scaled["grad_var"] == pytest.approx(7.5**2 * base["grad_var"], rel=1e-12)
    assert scaled["grad_mean_norm"] == pytest.approx(7.5 * base["grad_mean_norm"], rel=1e-12)
    assert scaled["grad_nsr"] == pytest.approx(base["grad_nsr"], rel=1e-12)
    assert scaled["grad_cosine"] == pytest.approx(base["grad_cosine"], rel=1e-12)


def test_noise_to_signal_is_infinite_when_the_groups_resolve_no_mean_direction():
    g = torch.tensor([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]], dtype=DT)  # mean exactly 0
    assert gradient_statistics(g)["grad_nsr"] == float("inf")
    assert gradient_statistics(g)["grad_cosine"] == pytest.approx(-1.0 / 3.0)


def test_bias_corrected_noise_to_signal_is_consistent_where_the_naive_one_saturates():
    # groups g_k = mu + noise with tr Cov = 16 ||mu||^2: true per-group NSR 16, which K = 4 groups cannot
    # reach naively (Var_K / ||g_bar||^2 tends to 16 / (1 + 16/4) = 3.2); the corrected ratio's median does
    gen = torch.Generator().manual_seed(4)
    p = 400
    mu = torch.ones(p, dtype=DT)
    sigma = 4.0  # tr Cov = p sigma^2 = 16 p = 16 ||mu||^2
    naive, corrected = [], []
    for _ in range(400):
        g = mu + sigma * torch.randn(4, p, dtype=DT, generator=gen)
        var = gradient_variance(g)
        naive.append(float(var / g.mean(0).pow(2).sum()))
        corrected.append(gradient_statistics(g)["grad_nsr"])
    assert sorted(naive)[200] == pytest.approx(3.2, rel=0.1)
    assert sorted(corrected)[200] == pytest.approx(16.0, rel=0.1)
