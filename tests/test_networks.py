"""Tests for algorithms/networks.py and algorithms/normalization.py."""

import math

import numpy as np
import pytest
import torch
from torch import nn
from torch.distributions import Normal, TanhTransform, TransformedDistribution

from algorithms.networks import MLP, Critic, DeterministicActor, GaussianActor, SquashedGaussianActor
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


def test_default_sizes():
    actor = GaussianActor(OBS, ACT)
    hidden = [m.out_features for m in actor.mu_net if isinstance(m, nn.Linear)]
    assert hidden == [128, 64, 32, ACT]
    critic = Critic(OBS)
    assert [m.out_features for m in critic.v_net if isinstance(m, nn.Linear)] == [64, 64, 1]
    torch.testing.assert_close(actor.logstd.detach(), torch.full((ACT,), -1.0))


def test_output_shapes():
    obs = torch.randn(4, 5, OBS)  # (T, N, obs_dim)
    assert DeterministicActor(OBS, ACT)(obs).shape == (4, 5, ACT)
    assert GaussianActor(OBS, ACT)(obs).shape == (4, 5, ACT)
    a, logp = SquashedGaussianActor(OBS, ACT)(obs)
    assert a.shape == (4, 5, ACT) and logp.shape == (4, 5)
    assert Critic(OBS)(obs).shape == (4, 5)


def test_gaussian_actor_deterministic_is_mean_and_sampling_is_noisy():
    actor = GaussianActor(OBS, ACT)
    obs = torch.randn(6, OBS)
    torch.testing.assert_close(actor(obs, deterministic=True), actor.mu_net(obs))
    assert not torch.allclose(actor(obs), actor(obs))


def test_gaussian_actor_noise_scale_matches_logstd():
    actor = GaussianActor(OBS, ACT)
    obs = torch.randn(1, OBS).expand(200_000, OBS)
    with torch.no_grad():
        a = actor(obs)
        mean = actor(obs[:1], deterministic=True)
    torch.testing.assert_close(a.std(0), torch.full((ACT,), math.exp(-1.0)), rtol=1e-2, atol=0)
    torch.testing.assert_close(a.mean(0), mean[0], rtol=0, atol=5e-3)


def test_gaussian_rsample_carries_pathwise_gradient():
    actor = GaussianActor(OBS, ACT)
    obs = torch.randn(16, OBS)
    actor(obs).pow(2).sum().backward()
    for name, p in actor.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


def test_squashed_gaussian_log_prob_matches_torch_distributions():
    actor = SquashedGaussianActor(OBS, ACT).double()
    obs = torch.randn(64, OBS, dtype=DT)
    a, logp = actor(obs)
    mean, log_std = actor.dist_params(obs)
    ref_dist = TransformedDistribution(Normal(mean, log_std.exp()), [TanhTransform()])
    ref = ref_dist.log_prob(a).sum(-1)
    torch.testing.assert_close(logp, ref, rtol=1e-6, atol=1e-6)
    # Deterministic mode: tanh(mean), log-prob at u = mean.
    a_det, logp_det = actor(obs, deterministic=True)
    torch.testing.assert_close(a_det, torch.tanh(mean))
    torch.testing.assert_close(logp_det, ref_dist.log_prob(a_det).sum(-1), rtol=1e-6, atol=1e-6)


def test_squashed_gaussian_actions_in_open_interval():
    a, _ = SquashedGaussianActor(OBS, ACT).double()(torch.randn(256, OBS, dtype=DT))
    assert torch.all(a.abs() < 1.0)
    assert a.abs().max() > 0.1  # not trivially zero


def test_squashed_gaussian_log_prob_finite_when_saturated():
    actor = SquashedGaussianActor(OBS, ACT)
    with torch.no_grad():
        actor.net[-1].bias[:ACT] = 30.0  # tanh(u) rounds to exactly 1.0 in float32
    a, logp = actor(torch.randn(256, OBS))
    assert torch.all(a.abs() <= 1.0)
    # The naive log(1 - tanh(u)^2) would be log(0) = -inf here.
    assert torch.isfinite(logp).all()


def test_squashed_gaussian_log_std_clamped():
    actor = SquashedGaussianActor(OBS, ACT)
    with torch.no_grad():
        actor.net[-1].bias[ACT:] = 50.0
    _, log_std = actor.dist_params(torch.randn(4, OBS))
    assert torch.all(log_std == 2.0)
    with torch.no_grad():
        actor.net[-1].bias[ACT:] = -50.0
    _, log_std = actor.dist_params(torch.randn(4, OBS))
    assert torch.all(log_std == -5.0)


def test_squashed_gaussian_gradient_through_action_and_log_prob():
    actor = SquashedGaussianActor(OBS, ACT)
    a, logp = actor(torch.randn(32, OBS))
    (a.sum() + 0.1 * logp.sum()).backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in actor.parameters())


def test_critic_gradient_flows_to_obs():
    critic = Critic(OBS)
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


def test_normalize_formula_clamp_and_gradient():
    rms = RunningMeanStd((2,))
    rms.update(torch.tensor([[0.0, 10.0], [2.0, 14.0]], dtype=DT))  # mean (1, 12), var (1, 4)
    x = torch.tensor([[2.0, 12.0], [100.0, -100.0]], dtype=DT, requires_grad=True)
    y = rms.normalize(x)
    expected0 = torch.tensor([1.0 / math.sqrt(1.0 + 1e-5), 0.0], dtype=DT)
    torch.testing.assert_close(y[0], expected0)
    torch.testing.assert_close(y[1], torch.tensor([5.0, -5.0], dtype=DT))
    y[0].sum().backward()
    assert x.grad[0, 0] > 0  # differentiable in x (pathwise gradient through obs normalisation)
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
