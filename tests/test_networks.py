"""Tests for algorithms/networks.py and algorithms/normalization.py."""

import math

import numpy as np
import pytest
import torch
from torch import nn
from torch.distributions import Normal, TanhTransform, TransformedDistribution

from algorithms.networks import MLP, STYLES, Critic, GaussianActor, SquashedGaussianActor
from algorithms.normalization import RunningMeanStd

DT = torch.float64
OBS, ACT = 7, 3


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)


def test_mlp_layer_order_and_shapes():
    net = MLP(5, [8, 4], 2)
    kinds = [type(m) for m in net]
    assert kinds == [nn.Linear, nn.ELU, nn.LayerNorm, nn.Linear, nn.ELU, nn.LayerNorm, nn.Linear]
    swapped = MLP(5, [8, 4], 2, norm_before_activation=True)
    assert [type(m) for m in swapped][:3] == [nn.Linear, nn.LayerNorm, nn.ELU]
    assert net(torch.randn(10, 5)).shape == (10, 2)
    assert [type(m) for m in MLP(5, [], 2)] == [nn.Linear]


def test_mlp_orthogonal_init():
    net = MLP(6, [6], 6, init_gain=math.sqrt(2.0))
    w = net[0].weight.detach()
    torch.testing.assert_close(w @ w.T, 2.0 * torch.eye(6), atol=1e-5, rtol=0)
    assert torch.all(net[0].bias == 0)


HIDDEN, CRITIC_HIDDEN = (128, 64, 32), (64, 64)


def _gaussian(style="diffrl"):
    return GaussianActor(OBS, ACT, HIDDEN, **STYLES[style][0])


def _squashed(style="mineral"):
    return SquashedGaussianActor(OBS, ACT, HIDDEN, **STYLES[style][0])


def _critic(style="diffrl"):
    return Critic(OBS, CRITIC_HIDDEN, **STYLES[style][1])


def test_sizes_and_initial_log_std():
    actor = _gaussian()
    hidden = [m.out_features for m in actor.mu_net if isinstance(m, nn.Linear)]
    assert hidden == [128, 64, 32, ACT]
    assert [m.out_features for m in _critic().v_net if isinstance(m, nn.Linear)] == [64, 64, 1]
    torch.testing.assert_close(actor.logstd.detach(), torch.full((ACT,), -1.0))


def test_mineral_style_is_layernorm_then_silu_with_orthogonal_gain_one_everywhere():
    for net in (list(_squashed().net)[:-1], list(_critic("mineral").v_net)):  # actor heads: below
        kinds = [type(m) for m in net][:3]
        assert kinds == [nn.Linear, nn.LayerNorm, nn.SiLU]
        for m in net:
            if isinstance(m, nn.Linear):
                w = m.weight.detach()
                small = w @ w.T if w.shape[0] <= w.shape[1] else w.T @ w
                torch.testing.assert_close(small, torch.eye(small.shape[0]), atol=1e-5, rtol=0)
                assert torch.all(m.bias == 0)
    # the mean and log-std heads are orthogonal separately (Mineral's two Linear heads)
    last = _squashed().net[-1].weight.detach()
    for rows in (last[:ACT], last[ACT:]):
        torch.testing.assert_close(rows @ rows.T, torch.eye(ACT), atol=1e-5, rtol=0)


def test_diffrl_style_is_elu_then_layernorm():
    assert [type(m) for m in _gaussian().mu_net][:3] == [nn.Linear, nn.ELU, nn.LayerNorm]


def test_output_shapes():
    obs = torch.randn(4, 5, OBS)  # (T, N, obs_dim)
    a, logp = _gaussian()(obs)
    assert a.shape == (4, 5, ACT) and logp.shape == (4, 5)
    a, logp = _squashed()(obs)
    assert a.shape == (4, 5, ACT) and logp.shape == (4, 5)
    assert _critic()(obs).shape == (4, 5)


def test_gaussian_actor_is_tanh_of_the_gaussian_sample():
    actor = _gaussian()
    obs = torch.randn(6, OBS)
    torch.testing.assert_close(actor(obs, deterministic=True)[0], torch.tanh(actor.mu_net(obs)))
    assert not torch.allclose(actor(obs)[0], actor(obs)[0])
    # no action ever leaves (-1, 1) and none loses its gradient (a clamp would zero it for |u| > 1)
    with torch.no_grad():
        actor.mu_net[-1].bias.fill_(3.0)
    obs.requires_grad_(True)
    a, _ = actor(obs)
    assert torch.all(a.abs() < 1.0)
    a.sum().backward()
    assert torch.all(actor.mu_net[-1].bias.grad > 0)


def test_gaussian_actor_noise_scale_matches_logstd():
    actor = _gaussian()
    with torch.no_grad():
        actor.mu_net[-1].weight.zero_()
        actor.mu_net[-1].bias.zero_()  # mean 0: tanh is nearly linear at the noise scale e^-1
    obs = torch.randn(1, OBS).expand(200_000, OBS)
    with torch.no_grad():
        u = torch.atanh(actor(obs)[0])
    torch.testing.assert_close(u.std(0), torch.full((ACT,), math.exp(-1.0)), rtol=1e-2, atol=0)
    torch.testing.assert_close(u.mean(0), torch.zeros(ACT), rtol=0, atol=5e-3)


def test_gaussian_rsample_carries_pathwise_gradient():
    actor = _gaussian()
    obs = torch.randn(16, OBS)
    actor(obs)[0].pow(2).sum().backward()
    for name, p in actor.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_squashed_gaussian_log_prob_matches_torch_distributions():
    actor = _squashed().double()
    obs = torch.randn(64, OBS, dtype=DT)
    a, logp = actor(obs)
    mean, log_std = actor.head(obs).chunk(2, dim=-1)
    ref_dist = TransformedDistribution(Normal(mean, log_std.exp()), [TanhTransform()])
    ref = ref_dist.log_prob(a).sum(-1)
    torch.testing.assert_close(logp, ref, rtol=1e-6, atol=1e-6)
    # Deterministic mode: tanh(mean), log-prob at u = mean.
    a_det, logp_det = actor(obs, deterministic=True)
    torch.testing.assert_close(a_det, torch.tanh(mean))
    torch.testing.assert_close(logp_det, ref_dist.log_prob(a_det).sum(-1), rtol=1e-6, atol=1e-6)


def test_squashed_gaussian_actions_in_open_interval():
    a, _ = _squashed().double()(torch.randn(256, OBS, dtype=DT))
    assert torch.all(a.abs() < 1.0)
    assert a.abs().max() > 0.1  # not trivially zero


def test_squashed_gaussian_log_prob_finite_when_saturated():
    actor = _squashed()
    with torch.no_grad():
        actor.net[-1].bias[:ACT] = 30.0  # tanh(u) rounds to exactly 1.0 in float32
    a, logp = actor(torch.randn(256, OBS))
    assert torch.all(a.abs() <= 1.0)
    # The naive log(1 - tanh(u)^2) would be log(0) = -inf here.
    assert torch.isfinite(logp).all()


def test_squashed_gaussian_log_std_clamped():
    actor = _squashed()
    with torch.no_grad():
        actor.net[-1].bias[ACT:] = 50.0
    _, log_std = actor.head(torch.randn(4, OBS)).chunk(2, dim=-1)
    assert torch.all(log_std == 2.0)
    with torch.no_grad():
        actor.net[-1].bias[ACT:] = -50.0
    _, log_std = actor.head(torch.randn(4, OBS)).chunk(2, dim=-1)
    assert torch.all(log_std == -5.0)


def test_squashed_gaussian_gradient_through_action_and_log_prob():
    actor = _squashed()
    a, logp = actor(torch.randn(32, OBS))
    (a.sum() + 0.1 * logp.sum()).backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in actor.parameters())


def test_critic_gradient_flows_to_obs():
    critic = _critic()
    obs = torch.randn(5, OBS, requires_grad=True)
    critic(obs).sum().backward()
    assert obs.grad.abs().sum() > 0


# ---------------------------------------------------------------- RunningMeanStd


def test_running_mean_std_matches_numpy_over_batches():
    rng = np.random.default_rng(0)
    scale = rng.uniform(0.5, 2.0, size=4)
    batches = [rng.normal(loc=3.0, scale=2.0, size=(n, 4)) * scale for n in (1, 7, 50, 3)]
    rms = RunningMeanStd((4,))
    for b in batches:
        rms.update(torch.from_numpy(b))
    allx = np.concatenate(batches)
    np.testing.assert_allclose(rms.mean.numpy(), allx.mean(0), rtol=1e-12)
    np.testing.assert_allclose(rms.var.numpy(), allx.var(0), rtol=1e-12)
    assert rms.count.item() == len(allx)
    assert rms.mean.dtype == torch.float64


def test_running_mean_std_flattens_leading_dims_and_accepts_float32():
    x = torch.randn(5, 6, 3)
    rms = RunningMeanStd((3,))
    rms.update(x)
    flat = x.double().reshape(-1, 3)
    torch.testing.assert_close(rms.mean, flat.mean(0))
    torch.testing.assert_close(rms.var, flat.var(0, unbiased=False))


def test_normalize_formula_no_clamp_by_default_and_gradient():
    rms = RunningMeanStd((2,))
    rms.update(torch.tensor([[0.0, 10.0], [2.0, 14.0]], dtype=DT))  # mean (1, 12), var (1, 4)
    x = torch.tensor([[2.0, 12.0], [100.0, -100.0]], dtype=DT, requires_grad=True)
    y = rms.normalize(x)
    expected0 = torch.tensor([1.0 / math.sqrt(1.0 + 1e-5), 0.0], dtype=DT)
    torch.testing.assert_close(y[0], expected0)
    std = torch.sqrt(torch.tensor([1.0, 4.0], dtype=DT) + 1e-5)
    torch.testing.assert_close(y[1], torch.tensor([99.0, -112.0], dtype=DT) / std)
    y.sum().backward()
    assert x.grad[0, 0] > 0 and x.grad[1, 0] > 0  # no clamp cuts the gradient of a far observation
    clamped = RunningMeanStd((2,), clip=5.0)
    clamped.update(torch.tensor([[0.0, 10.0], [2.0, 14.0]], dtype=DT))
    torch.testing.assert_close(clamped.normalize(x.detach())[1], torch.tensor([5.0, -5.0], dtype=DT))
    assert rms.normalize(torch.ones(2, dtype=torch.float32)).dtype == torch.float32


def test_running_mean_std_state_dict_round_trip():
    rms = RunningMeanStd((3,))
    for _ in range(3):
        rms.update(torch.randn(20, 3) * 4 + 1)
    restored = RunningMeanStd((3,))
    restored.load_state_dict(rms.state_dict())
    x = torch.randn(10, 3)
    torch.testing.assert_close(restored.normalize(x), rms.normalize(x))
    assert restored.count.item() == 60
    more = torch.randn(8, 3)
    rms.update(more)
    restored.update(more)
    torch.testing.assert_close(restored.mean, rms.mean)
    torch.testing.assert_close(restored.var, rms.var)


def test_running_mean_std_ignores_dtype_casts():
    parent = nn.Sequential(RunningMeanStd((2,)))
    parent.float()
    assert parent[0].mean.dtype == torch.float64 and parent[0].var.dtype == torch.float64
