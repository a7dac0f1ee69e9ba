"""Actor and critic networks for SHAC / SAPO and their TD-lambda variants.

The architecture follows DiffRL's SHAC (the paper's baseline [13]): ELU MLPs with a
LayerNorm on every hidden layer, an actor with hidden sizes [128, 64, 32] and a
state-independent log-std initialised at -1.0, and a critic with hidden sizes
[64, 64]. Layer order: DiffRL builds each hidden layer as Linear -> ELU -> LayerNorm
(checked against its models/actor.py and models/critic.py); that is the default
here, and ``norm_before_activation=True`` gives Linear -> LayerNorm -> ELU instead.
Initialisation also follows DiffRL: the actor keeps torch's default Linear init,
the critic uses orthogonal weights (gain sqrt(2)) and zero biases.

Actions are sampled with the reparameterisation ``mean + std * eps`` so that the
pathwise gradient (eq. 2-4) flows from the simulator's rewards back into the actor.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["MLP", "DeterministicActor", "GaussianActor", "SquashedGaussianActor", "Critic"]

ACTOR_HIDDEN = (128, 64, 32)
CRITIC_HIDDEN = (64, 64)
_LOG_2 = math.log(2.0)
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


class MLP(nn.Sequential):
    """Feed-forward net: per hidden size a Linear, an activation and a LayerNorm; then a Linear.

    Args:
        in_dim: input features.
        hidden_sizes: widths of the hidden layers (may be empty: a single Linear).
        out_dim: output features. The output layer has no activation or norm.
        activation: module class for the hidden activation (ELU as in DiffRL).
        layer_norm: put a LayerNorm on every hidden layer.
        norm_before_activation: False gives DiffRL's Linear -> ELU -> LayerNorm,
            True gives Linear -> LayerNorm -> ELU.
        init_gain: None keeps torch's default Linear init; a number uses orthogonal
            weights with that gain and zero biases (DiffRL's critic uses sqrt(2)).
    """

    def __init__(
        self,
        in_dim: int,
        hidden_sizes: Sequence[int],
        out_dim: int,
        activation: type[nn.Module] = nn.ELU,
        layer_norm: bool = True,
        norm_before_activation: bool = False,
        init_gain: float | None = None,
    ):
        layers: list[nn.Module] = []
        width = in_dim
        for size in hidden_sizes:
            layers.append(nn.Linear(width, size))
            block = [activation(), nn.LayerNorm(size)] if layer_norm else [activation()]
            if norm_before_activation:
                block.reverse()
            layers.extend(block)
            width = size
        layers.append(nn.Linear(width, out_dim))
        super().__init__(*layers)
        if init_gain is not None:
            for m in self.modules():
                if isinstance(m, nn.Linear):
                    nn.init.orthogonal_(m.weight, gain=init_gain)
                    nn.init.zeros_(m.bias)


class DeterministicActor(nn.Module):
    """a = mu_theta(s). ``deterministic`` is accepted for interface parity and ignored."""

    def __init__(self, obs_dim: int, act_dim: int, hidden_sizes: Sequence[int] = ACTOR_HIDDEN, **mlp_kwargs):
        super().__init__()
        self.mu_net = MLP(obs_dim, hidden_sizes, act_dim, **mlp_kwargs)

    def forward(self, obs: Tensor, deterministic: bool = True) -> Tensor:
        return self.mu_net(obs)


class GaussianActor(nn.Module):
    """SHAC's stochastic actor: a ~ N(mu_theta(s), diag(exp(logstd)^2)).

    ``logstd`` is a learnable, state-independent vector (DiffRL init -1.0). Sampling
    is ``mean + std * eps`` with eps ~ N(0, I) drawn outside the graph, so the action
    is differentiable w.r.t. the MLP parameters and ``logstd`` (pathwise gradient).
    The mean is not squashed; environments clip actions themselves, as in DiffRL.
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden_sizes: Sequence[int] = ACTOR_HIDDEN,
        init_logstd: float = -1.0,
        **mlp_kwargs,
    ):
        super().__init__()
        self.mu_net = MLP(obs_dim, hidden_sizes, act_dim, **mlp_kwargs)
        self.logstd = nn.Parameter(torch.full((act_dim,), float(init_logstd)))

    def distribution(self, obs: Tensor) -> torch.distributions.Normal:
        """The action distribution (for log-probs / entropy logging)."""
        return torch.distributions.Normal(self.mu_net(obs), self.logstd.exp())

    def head(self, obs: Tensor) -> Tensor:
        """``[mean, log_std]`` per sample (log_std broadcast): every way theta reaches an action."""
        mean = self.mu_net(obs)
        return torch.cat((mean, self.logstd.expand_as(mean)), dim=-1)

    @staticmethod
    def act(head: Tensor, eps: Tensor) -> tuple[Tensor, Tensor]:
        """(action, log-prob) for noise ``eps`` (zeros: the deterministic action)."""
        mean, log_std = head.chunk(2, dim=-1)
        log_prob = (-0.5 * eps.pow(2) - log_std - _HALF_LOG_2PI).sum(dim=-1)
        return mean + log_std.exp() * eps, log_prob

    def forward(self, obs: Tensor, deterministic: bool = False) -> Tensor:
        head = self.head(obs)
        eps = torch.zeros_like(head[..., : self.logstd.numel()])
        if not deterministic:
            eps.normal_()
        return self.act(head, eps)[0]


class SquashedGaussianActor(nn.Module):
    """SAPO's actor: a = tanh(u), u ~ N(mean(s), diag(std(s)^2)), std state-dependent.

    The MLP outputs ``2 * act_dim`` numbers: the mean and the log-std of u; the log-std
    is clamped to ``log_std_bounds`` (default [-5, 2]) to keep std away from 0 and inf.
    ``forward`` returns ``(action, log_prob)`` with ``log_prob`` of shape ``obs.shape[:-1]``,
    summed over action dimensions and including the tanh change of variables::

        log pi(a|s) = sum_i [ log N(u_i; mean_i, std_i) - log(1 - tanh(u_i)^2) ]
        log(1 - tanh(u)^2) = 2 * (log 2 - u - softplus(-2u))

    The right-hand form is exact and never evaluates log(0) when tanh(u) rounds to +-1.
    In deterministic mode the action is ``tanh(mean)`` and the log-prob is evaluated
    at u = mean.
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden_sizes: Sequence[int] = ACTOR_HIDDEN,
        log_std_bounds: tuple[float, float] = (-5.0, 2.0),
        **mlp_kwargs,
    ):
        super().__init__()
        self.act_dim = act_dim
        self.log_std_bounds = log_std_bounds
        self.net = MLP(obs_dim, hidden_sizes, 2 * act_dim, **mlp_kwargs)

    def dist_params(self, obs: Tensor) -> tuple[Tensor, Tensor]:
        """(mean, log_std) of the pre-tanh Gaussian, log_std already clamped."""
        mean, log_std = self.net(obs).split(self.act_dim, dim=-1)
        lo, hi = self.log_std_bounds
        return mean, log_std.clamp(lo, hi)

    def head(self, obs: Tensor) -> Tensor:
        """``[mean, clamped log_std]`` of the pre-tanh Gaussian: every way theta reaches an action."""
        return torch.cat(self.dist_params(obs), dim=-1)

    def forward(self, obs: Tensor, deterministic: bool = False) -> tuple[Tensor, Tensor]:
        mean, log_std = self.dist_params(obs)
        eps = torch.zeros_like(mean) if deterministic else torch.randn_like(mean)
        return self.act(torch.cat((mean, log_std), dim=-1), eps)

    @staticmethod
    def act(head: Tensor, eps: Tensor) -> tuple[Tensor, Tensor]:
        """(tanh-squashed action, its log-prob) for noise ``eps`` (zeros: deterministic)."""
        mean, log_std = head.chunk(2, dim=-1)
        u = mean + log_std.exp() * eps
        # Gaussian log-density written with eps directly: (u - mean) / std == eps
        # exactly, and avoiding the division keeps it accurate for tiny std.
        gauss_logp = -0.5 * eps.pow(2) - log_std - _HALF_LOG_2PI
        log_det = 2.0 * (_LOG_2 - u - F.softplus(-2.0 * u))
        log_prob = (gauss_logp - log_det).sum(dim=-1)
        return torch.tanh(u), log_prob


class Critic(nn.Module):
    """V_phi(s): MLP [64, 64] -> 1, orthogonal init (gain sqrt(2)) as in DiffRL.

    Returns values of shape ``obs.shape[:-1]`` (the trailing 1 is squeezed) so that a
    (T, N, obs_dim) batch gives (T, N) values, matching ``returns.py``.
    """

    def __init__(
        self,
        obs_dim: int,
        hidden_sizes: Sequence[int] = CRITIC_HIDDEN,
        init_gain: float | None = math.sqrt(2.0),
        **mlp_kwargs,
    ):
        super().__init__()
        self.v_net = MLP(obs_dim, hidden_sizes, 1, init_gain=init_gain, **mlp_kwargs)

    def forward(self, obs: Tensor) -> Tensor:
        return self.v_net(obs).squeeze(-1)
