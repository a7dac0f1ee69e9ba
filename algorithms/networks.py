"""Actor and critic networks for SHAC / SAPO and their TD-lambda variants.

Two styles (``AlgoConfig.network_style``), each that of the reference code of its algorithm:

* ``diffrl`` (SHAC and its TD variants; DiffRL's ``models/actor.py`` and ``models/critic.py``):
  every hidden layer is Linear -> ELU -> LayerNorm; the actor keeps torch's default Linear
  init, the critic uses orthogonal weights (gain sqrt(2)) and zero biases.
* ``mineral`` (SAPO and its TD variants; Mineral's ``DFlexAntSHAC2``/``DFlexAntSAPO`` configs):
  every hidden layer is Linear -> LayerNorm -> SiLU, and every Linear (hidden layers, the actor's
  mean and log-std heads, the critic's output) has orthogonal weights of gain 1 and zero biases.

Actions are sampled with the reparameterisation ``u = mean + std * eps`` so that the pathwise
gradient (eq. 2-4) flows from the simulator's rewards back into the actor, and both actors
return ``a = tanh(u)``: the simulator only ever sees actions in (-1, 1) and the gradient is never
cut by a clamp (DiffRL and Mineral pass ``tanh(actions)`` to the env for SHAC; SAPO's squashed
Gaussian has the tanh inside the distribution).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["MLP", "GaussianActor", "SquashedGaussianActor", "Critic", "STYLES"]

_LOG_2 = math.log(2.0)
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)

# MLP keyword arguments of each style: (actor, critic)
STYLES: dict[str, tuple[dict, dict]] = {
    "diffrl": (
        {"activation": nn.ELU, "norm_before_activation": False, "init_gain": None},
        {"activation": nn.ELU, "norm_before_activation": False, "init_gain": math.sqrt(2.0)},
    ),
    "mineral": (
        {"activation": nn.SiLU, "norm_before_activation": True, "init_gain": 1.0},
        {"activation": nn.SiLU, "norm_before_activation": True, "init_gain": 1.0},
    ),
}


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
        for name, value in (("in_dim", in_dim), ("out_dim", out_dim), *(("a hidden size", h) for h in hidden_sizes)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"MLP {name} must be an integer >= 1, got {value!r}")
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


class _Actor(nn.Module):
    """What both actors share: ``head(obs)`` gives ``[mean, log_std]``, ``act(head, eps)`` the action."""

    def forward(self, obs: Tensor, deterministic: bool = False) -> tuple[Tensor, Tensor]:
        """(action, log-prob) for observations ``obs``; fresh noise unless ``deterministic``."""
        head = self.head(obs)
        eps = torch.zeros_like(head[..., : head.shape[-1] // 2])
        if not deterministic:
            eps.normal_()
        return self.act(head, eps)


class GaussianActor(_Actor):
    """SHAC's stochastic actor: u ~ N(mu_theta(s), diag(exp(logstd)^2)), action a = tanh(u).

    ``logstd`` is a learnable, state-independent vector (DiffRL init -1.0). Sampling is
    ``mean + std * eps`` with eps ~ N(0, I) drawn outside the graph, so the action is
    differentiable w.r.t. the MLP parameters and ``logstd`` (pathwise gradient). The tanh is
    DiffRL's ``env.step(torch.tanh(actions))``; the log-prob is that of the Gaussian u (SHAC
    uses it for logging only, as DiffRL has none).
    """

    def __init__(self, obs_dim: int, act_dim: int, hidden_sizes: Sequence[int], init_logstd: float = -1.0, **mlp):
        super().__init__()
        self.mu_net = MLP(obs_dim, hidden_sizes, act_dim, **mlp)
        self.logstd = nn.Parameter(torch.full((act_dim,), float(init_logstd)))

    def head(self, obs: Tensor) -> Tensor:
        """``[mean, log_std]`` per sample (log_std broadcast): every way theta reaches an action."""
        mean = self.mu_net(obs)
        return torch.cat((mean, self.logstd.expand_as(mean)), dim=-1)

    @staticmethod
    def act(head: Tensor, eps: Tensor) -> tuple[Tensor, Tensor]:
        """(tanh(u), log-prob of u) for noise ``eps`` (zeros: the deterministic action tanh(mean))."""
        mean, log_std = head.chunk(2, dim=-1)
        log_prob = (-0.5 * eps.pow(2) - log_std - _HALF_LOG_2PI).sum(dim=-1)
        return torch.tanh(mean + log_std.exp() * eps), log_prob


class SquashedGaussianActor(_Actor):
    """SAPO's actor: a = tanh(u), u ~ N(mean(s), diag(std(s)^2)), std state-dependent.

    A trunk MLP and two linear heads (mean and log-std of u, as Mineral's ``mu`` and ``sigma``
    heads; with ``init_gain`` each head gets its own orthogonal init). The log-std is clamped to
    ``log_std_bounds`` ([-5, 2], Mineral's minlogstd/maxlogstd). The log-prob is summed over
    action dimensions and includes the tanh change of variables::

        log pi(a|s) = sum_i [ log N(u_i; mean_i, std_i) - log(1 - tanh(u_i)^2) ]
        log(1 - tanh(u)^2) = 2 * (log 2 - u - softplus(-2u))

    The right-hand form is exact and never evaluates log(0) when tanh(u) rounds to +-1.
    In deterministic mode the action is ``tanh(mean)``.
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden_sizes: Sequence[int],
        log_std_bounds: tuple[float, float] = (-5.0, 2.0),
        **mlp,
    ):
        super().__init__()
        self.act_dim = act_dim
        self.log_std_bounds = log_std_bounds
        self.net = MLP(obs_dim, hidden_sizes, 2 * act_dim, **mlp)
        gain = mlp.get("init_gain")
        if gain is not None:  # the two heads are separate matrices in Mineral: orthogonal each
            last = self.net[-1]
            with torch.no_grad():
                for rows in (slice(0, act_dim), slice(act_dim, 2 * act_dim)):
                    nn.init.orthogonal_(last.weight[rows], gain=gain)

    def head(self, obs: Tensor) -> Tensor:
        """``[mean, clamped log_std]`` of the pre-tanh Gaussian: every way theta reaches an action."""
        mean, log_std = self.net(obs).split(self.act_dim, dim=-1)
        lo, hi = self.log_std_bounds
        return torch.cat((mean, log_std.clamp(lo, hi)), dim=-1)

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
    """V_phi(s): an MLP -> 1. Returns values of shape ``obs.shape[:-1]`` (the trailing 1 squeezed),
    so a (T, N, obs_dim) batch gives (T, N) values, matching ``returns.py``."""

    def __init__(self, obs_dim: int, hidden_sizes: Sequence[int], **mlp):
        super().__init__()
        self.v_net = MLP(obs_dim, hidden_sizes, 1, **mlp)

    def forward(self, obs: Tensor) -> Tensor:
        return self.v_net(obs).squeeze(-1)
