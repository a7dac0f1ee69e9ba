"""Tests for algorithms/returns.py (TD-lambda / h-step returns, eq. 7-14)."""

import pytest
import torch

from algorithms.returns import (
    actor_loss_from_returns,
    actor_loss_per_env,
    critic_targets,
    h_step_returns,
    segment_starts,
    td_lambda_closed_form,
    td_lambda_returns,
)

DT = torch.float64


def random_window(seed, T=9, N=6, p_term=0.12, p_trunc=0.12):
    """Random float64 window (T >= 6, N >= 3) with forced termination and truncation inside it."""
    g = torch.Generator().manual_seed(seed)
    rewards = torch.randn(T, N, generator=g, dtype=DT)
    next_values = 3.0 * torch.randn(T, N, generator=g, dtype=DT)
    terminated = torch.rand(T, N, generator=g) < p_term
    truncated = torch.rand(T, N, generator=g) < p_trunc
    # Make sure both kinds of boundary occur mid-window, plus one double-flagged step.
    terminated[2, 0] = True
    truncated[4, 1] = True
    terminated[5, 2] = truncated[5, 2] = True
    return rewards, next_values, terminated, truncated


def one_step_target(rewards, next_values, terminated, gamma):
    return rewards + gamma * torch.where(terminated, torch.zeros_like(next_values), next_values)


@pytest.mark.parametrize("seed", range(6))
def test_recursion_matches_closed_form(seed):
    g = torch.Generator().manual_seed(100 + seed)
    gamma = 0.8 + 0.2 * torch.rand((), generator=g, dtype=DT).item()
    lam = torch.rand((), generator=g, dtype=DT).item()
    batch = random_window(seed)
    rec = td_lambda_returns(*batch, gamma, lam)
    ref = td_lambda_closed_form(*batch, gamma, lam)
    assert rec.shape == batch[0].shape
    torch.testing.assert_close(rec, ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("lam", [0.0, 1.0])
def test_recursion_matches_closed_form_at_lambda_edges(lam):
    batch = random_window(7)
    torch.testing.assert_close(
        td_lambda_returns(*batch, 0.97, lam), td_lambda_closed_form(*batch, 0.97, lam), rtol=1e-12, atol=1e-12
    )


def test_hand_computed_example():
    # T=3, N=3 columns: no boundary / termination after t=1 / truncation after t=1.
    r = torch.tensor([[1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [3.0, 3.0, 3.0]], dtype=DT)
    v = torch.tensor([[10.0, 10.0, 10.0], [20.0, 20.0, 20.0], [30.0, 30.0, 30.0]], dtype=DT)
    term = torch.tensor([[0, 0, 0], [0, 1, 0], [0, 0, 0]], dtype=torch.bool)
    trunc = torch.tensor([[0, 0, 0], [0, 0, 1], [0, 0, 0]], dtype=torch.bool)
    # gamma = lam = 0.5. Column 0: G2 = 3 + 15 = 18; G1 = 2 + .5(.5*20 + .5*18) = 11.5;
    # G0 = 1 + .5(.5*10 + .5*11.5) = 6.375. Column 1: G1 = 2 (terminated), G0 = 1 + .5(5 + 1) = 4.
    # Column 2: G1 = 2 + .5*20 = 12, G0 = 1 + .5(5 + 6) = 6.5. Rows 2 are new episodes: 18.
    expected = torch.tensor([[6.375, 4.0, 6.5], [11.5, 2.0, 12.0], [18.0, 18.0, 18.0]], dtype=DT)
    for fn in (td_lambda_returns, td_lambda_closed_form):
        torch.testing.assert_close(fn(r, v, term, trunc, 0.5, 0.5), expected)
    # h-step: column 0: G0 = 1 + .5*2 + .25*3 + .125*30 = 6.5; column 1: G0 = 1 + .5*2 = 2;
    # column 2: G0 = 1 + .5*2 + .25*20 = 7.
    h0 = h_step_returns(r, v, term, trunc, 0.5)[0]
    torch.testing.assert_close(h0, torch.tensor([6.5, 2.0, 7.0], dtype=DT))


@pytest.mark.parametrize("seed", range(4))
def test_lambda_one_is_h_step_return(seed):
    batch = random_window(seed, T=11, N=5)
    h = h_step_returns(*batch, 0.95)
    torch.testing.assert_close(td_lambda_returns(*batch, 0.95, 1.0), h, rtol=1e-12, atol=1e-12)


def test_h_step_return_matches_explicit_segment_sum():
    rewards, next_values, terminated, truncated = random_window(3, T=10, N=4)
    gamma = 0.9
    done = terminated | truncated
    h = h_step_returns(rewards, next_values, terminated, truncated, gamma)
    T, N = rewards.shape
    for n in range(N):
        for t in range(T):
            e = t
            while e < T - 1 and not done[e, n]:
                e += 1
            boot = 0.0 if terminated[e, n] else next_values[e, n].item()
            expected = sum(gamma**k * rewards[t + k, n].item() for k in range(e - t + 1))
            expected += gamma ** (e - t + 1) * boot
            assert h[t, n].item() == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_lambda_zero_is_one_step_target():
    batch = random_window(11)
    rewards, next_values, terminated, _ = batch
    torch.testing.assert_close(
        td_lambda_returns(*batch, 0.93, 0.0), one_step_target(rewards, next_values, terminated, 0.93)
    )


def test_last_step_bootstraps_with_next_value():
    rewards, next_values, terminated, truncated = random_window(5)
    terminated[-1] = False
    truncated[-1] = False
    g = td_lambda_returns(rewards, next_values, terminated, truncated, 0.9, 0.7)
    torch.testing.assert_close(g[-1], rewards[-1] + 0.9 * next_values[-1])


@pytest.mark.parametrize("kind", ["terminated", "truncated"])
def test_boundary_isolates_earlier_steps(kind):
    rewards, next_values, terminated, truncated = random_window(2, T=8, N=3)
    terminated.zero_()
    truncated.zero_()
    b = 3
    (terminated if kind == "terminated" else truncated)[b] = True
    before = td_lambda_returns(rewards, next_values, terminated, truncated, 0.99, 0.9)
    r2, v2 = rewards.clone(), next_values.clone()
    r2[b + 1 :] += 100.0
    v2[b + 1 :] -= 50.0
    after = td_lambda_returns(r2, v2, terminated, truncated, 0.99, 0.9)
    assert torch.equal(before[: b + 1], after[: b + 1])
    # Sanity: the perturbation is visible after the boundary, so the check above can fail.
    assert not torch.allclose(before[b + 1 :], after[b + 1 :])
    # And without the boundary the same perturbation does leak backwards.
    no_boundary = torch.zeros_like(terminated)
    leak0 = td_lambda_returns(rewards, next_values, no_boundary, no_boundary, 0.99, 0.9)
    leak1 = td_lambda_returns(r2, v2, no_boundary, no_boundary, 0.99, 0.9)
    assert not torch.allclose(leak0[: b + 1], leak1[: b + 1])


def test_termination_bootstraps_zero_whatever_next_values_holds():
    rewards, next_values, terminated, truncated = random_window(4)
    base = td_lambda_returns(rewards, next_values, terminated, truncated, 0.97, 0.8)
    junk = next_values.clone()
    junk[terminated] = 1e9
    torch.testing.assert_close(td_lambda_returns(rewards, junk, terminated, truncated, 0.97, 0.8), base)
    # Terminated step alone: G_t = r_t exactly.
    torch.testing.assert_close(base[terminated], rewards[terminated])
    # No gradient reaches next_values at terminated steps; some does elsewhere.
    v = next_values.clone().requires_grad_(True)
    td_lambda_returns(rewards, v, terminated, truncated, 0.97, 0.8).sum().backward()
    assert torch.all(v.grad[terminated] == 0)
    assert torch.all(v.grad[~terminated] != 0)


def test_truncation_bootstraps_with_next_values():
    rewards, next_values, terminated, truncated = random_window(6, T=7, N=3)
    terminated.zero_()
    truncated.zero_()
    truncated[2, 0] = True
    gamma, lam = 0.9, 0.6
    base = td_lambda_returns(rewards, next_values, terminated, truncated, gamma, lam)
    torch.testing.assert_close(base[2, 0], rewards[2, 0] + gamma * next_values[2, 0])
    v2 = next_values.clone()
    v2[2, 0] += 1.0
    bumped = td_lambda_returns(rewards, v2, terminated, truncated, gamma, lam)
    # d G_2 / d V = gamma; d G_1 / d V = gamma * lam * gamma (flows through G_2).
    torch.testing.assert_close(bumped[2, 0] - base[2, 0], torch.tensor(gamma, dtype=DT))
    torch.testing.assert_close(bumped[1, 0] - base[1, 0], torch.tensor(gamma * lam * gamma, dtype=DT))


def test_gradcheck_wrt_lambda_tensor():
    rewards, next_values, terminated, truncated = random_window(8, T=6, N=3)
    lam = torch.tensor(0.7, dtype=DT, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda x: td_lambda_returns(rewards, next_values, terminated, truncated, 0.95, x), (lam,)
    )


def test_gradcheck_wrt_rewards_and_next_values():
    rewards, next_values, terminated, truncated = random_window(9, T=6, N=3)
    r = rewards.clone().requires_grad_(True)
    v = next_values.clone().requires_grad_(True)
    lam = torch.tensor(0.8, dtype=DT)

    def td(a, b):
        return td_lambda_returns(a, b, terminated, truncated, 0.95, lam)

    def hs(a, b):
        return h_step_returns(a, b, terminated, truncated, 0.95)

    assert torch.autograd.gradcheck(td, (r, v))
    assert torch.autograd.gradcheck(hs, (r, v))


def test_lambda_gradient_matches_closed_form_gradient():
    batch = random_window(10)
    phi = torch.tensor(0.4, dtype=DT, requires_grad=True)  # lam = sigmoid(phi), as in adaptive lambda
    (g_rec,) = torch.autograd.grad(td_lambda_returns(*batch, 0.99, torch.sigmoid(phi)).pow(2).mean(), phi)
    (g_ref,) = torch.autograd.grad(td_lambda_closed_form(*batch, 0.99, torch.sigmoid(phi)).pow(2).mean(), phi)
    assert g_rec.abs() > 0
    torch.testing.assert_close(g_rec, g_ref, rtol=1e-10, atol=1e-12)


def test_float32_and_integer_masks_accepted():
    rewards, next_values, terminated, truncated = random_window(12)
    ref = td_lambda_returns(rewards, next_values, terminated, truncated, 0.9, 0.5)
    r32, v32 = rewards.float(), next_values.float()
    out = td_lambda_returns(r32, v32, terminated.int(), truncated.float(), 0.9, 0.5)
    assert out.dtype == torch.float32
    torch.testing.assert_close(out.double(), ref, rtol=1e-5, atol=1e-5)


def test_shape_mismatch_raises():
    rewards, next_values, terminated, truncated = random_window(0)
    with pytest.raises(ValueError):
        td_lambda_returns(rewards, next_values[:-1], terminated, truncated, 0.9, 0.5)
    with pytest.raises(ValueError):
        h_step_returns(rewards[:, 0], next_values[:, 0], terminated[:, 0], truncated[:, 0], 0.9)


def test_segment_starts():
    term = torch.tensor([[0, 0], [1, 0], [0, 0], [0, 0]], dtype=torch.bool)
    trunc = torch.tensor([[0, 1], [0, 0], [0, 1], [1, 0]], dtype=torch.bool)
    expected = torch.tensor([[1, 1], [0, 1], [1, 0], [0, 1]], dtype=torch.bool)
    assert torch.equal(segment_starts(term, trunc), expected)


def test_actor_loss_hand_example():
    returns = torch.tensor([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]], dtype=DT)
    starts = torch.tensor([[1, 1], [0, 1], [1, 0]], dtype=torch.bool)
    # Picked: env0 -> 1 + 5, env1 -> 2 + 4. Loss = -(6 + 6) / (N=2 * h=4).
    torch.testing.assert_close(actor_loss_from_returns(returns, starts, 4), torch.tensor(-1.5, dtype=DT))
    torch.testing.assert_close(actor_loss_per_env(returns, starts, 4), torch.tensor([-1.5, -1.5], dtype=DT))


def test_actor_loss_with_h_step_matches_shac_accumulation():
    """Eq. 9 via returns equals SHAC's running per-step accumulation, written independently."""
    rewards, next_values, terminated, truncated = random_window(13, T=8, N=5)
    gamma = 0.97
    T, N = rewards.shape
    total = 0.0
    for n in range(N):
        acc, disc = 0.0, 1.0
        for t in range(T):
            acc += disc * rewards[t, n].item()
            disc *= gamma
            if terminated[t, n] or truncated[t, n] or t == T - 1:
                boot = 0.0 if terminated[t, n] else next_values[t, n].item()
                total += acc + disc * boot
                acc, disc = 0.0, 1.0
    expected = -total / (N * T)
    h = h_step_returns(rewards, next_values, terminated, truncated, gamma)
    loss = actor_loss_from_returns(h, segment_starts(terminated, truncated), T)
    assert loss.item() == pytest.approx(expected, rel=1e-12)


def test_actor_loss_gradient_reaches_rewards():
    rewards, next_values, terminated, truncated = random_window(14)
    r = rewards.clone().requires_grad_(True)
    g = td_lambda_returns(r, next_values, terminated, truncated, 0.99, 0.95)
    actor_loss_from_returns(g, segment_starts(terminated, truncated), r.shape[0]).backward()
    # Every reward lies in some mini-trajectory, so every reward gets a negative gradient.
    assert torch.all(r.grad < 0)


def test_critic_targets_detached_and_equal():
    rewards, next_values, terminated, truncated = random_window(15)
    r = rewards.clone().requires_grad_(True)
    lam = torch.tensor(0.9, dtype=DT, requires_grad=True)
    targets = critic_targets(r, next_values, terminated, truncated, 0.99, lam)
    assert not targets.requires_grad
    plain = td_lambda_returns(rewards, next_values, terminated, truncated, 0.99, 0.9)
    torch.testing.assert_close(targets, plain)
