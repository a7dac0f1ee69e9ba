"""Actor-gradient variance: the statistic behind the paper's Fig. 2 and Fig. 7 (left).

Definition used by this benchmark
---------------------------------
Split the N environments of one actor update into K disjoint groups of equal size
m = N / K (contiguous blocks: env n is in group n // m). For each group k let

    g_k = grad_theta L_k  (flattened over all actor parameters, length P),
    L_k = mean of the per-env actor losses of the envs in group k,

so that the mean of the K group losses is the actor loss of eq. 9 / eq. 12 and
the mean of the g_k is the gradient the optimiser actually receives. The reported
statistic is the trace of the sample covariance of the K group gradients:

    Var_K = 1/(K-1) * sum_k || g_k - g_bar ||^2,    g_bar = (1/K) sum_k g_k.

If the environments are independent given theta (they are: each env runs its own
trajectory) and a single env's gradient has covariance Sigma, then E[Var_K] =
tr(Sigma) / m exactly. Two rescalings follow and are provided:

    per_env_gradient_variance = m * Var_K   estimates tr(Sigma), the variance of a
                                            single env's gradient; comparable across
                                            runs with different N or K.
    batch_gradient_variance   = Var_K / K   estimates tr(Sigma) / N, the variance of
                                            the full-batch update gradient g_bar.

Always state K and N next to any of the three numbers. The group gradients themselves come
from one backward pass (``FirstOrderActorCritic.group_gradients``), taken before the optimiser
step so that they are the gradients of the update.

Scale-free statistics
---------------------
Var_K scales with the square of the loss: multiply the loss by c and it grows by c^2, so two losses
of different size (the h-step return weights the window's rewards by sum gamma^l, the TD-lambda
return by about sum (gamma lambda)^l) differ in Var_K even at equal noise. Adam, which every
algorithm here uses, is invariant to that scale, so the statistics that predict training are ratios
(:func:`gradient_statistics`):

    signal  S = ||g_bar||^2 - Var_K / K     unbiased for ||E g_k||^2, since
                                            E ||g_bar||^2 = ||E g_k||^2 + tr Cov(g_k) / K
    noise-to-signal NSR = Var_K / S         per-group noise over signal; +inf when S <= 0 (the K
                                            groups do not resolve a mean direction)
    cosine  = mean over pairs i < j of g_i . g_j / (||g_i|| ||g_j||)

The naive ratio Var_K / ||g_bar||^2 is biased low and saturates near K as the noise grows (its
denominator holds the noise it divides by); subtracting Var_K / K removes that bias from the
denominator. NSR is a ratio of unbiased estimates, so it is consistent but not itself unbiased; its
reciprocal 1 / NSR is the squared signal-to-noise ratio of one group's gradient, and for the
full-batch gradient g_bar the noise-to-signal is NSR / K. All three are unchanged when the loss is
multiplied by a constant.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = ["gradient_variance", "per_env_gradient_variance", "batch_gradient_variance", "gradient_statistics"]


def gradient_variance(group_grads: Tensor) -> Tensor:
    """Trace of the sample covariance of K gradients: 1/(K-1) * sum_k ||g_k - g_bar||^2.

    Args:
        group_grads: (K, P) tensor, one flattened gradient per row, K >= 2.

    Returns:
        0-dim tensor in the dtype of ``group_grads``.
    """
    if group_grads.dim() != 2:
        raise ValueError(f"group_grads must be (K, P), got shape {tuple(group_grads.shape)}")
    num_groups = group_grads.shape[0]
    if num_groups < 2:
        raise ValueError("need at least 2 groups to estimate a variance")
    centered = group_grads - group_grads.mean(dim=0, keepdim=True)
    return centered.pow(2).sum() / (num_groups - 1)


def per_env_gradient_variance(group_grads: Tensor, group_size: int) -> Tensor:
    """Estimate of tr Cov of one environment's gradient: group_size * gradient_variance."""
    return gradient_variance(group_grads) * group_size


def batch_gradient_variance(group_grads: Tensor) -> Tensor:
    """Estimate of tr Cov of the full-batch (mean over all N envs) gradient: Var_K / K."""
    return gradient_variance(group_grads) / group_grads.shape[0]


def gradient_statistics(group_grads: Tensor) -> dict[str, float]:
    """The raw variance and the scale-free statistics of K group gradients (module docstring).

    Returns ``grad_var`` (Var_K), ``grad_mean_norm`` (||g_bar||), ``grad_nsr`` (Var_K / S, +inf when
    the bias-corrected signal S is not positive) and ``grad_cosine`` (mean pairwise cosine; a zero
    gradient counts as orthogonal to every other).
    """
    grads = group_grads.double()  # sums of squares of float32 gradients lose digits the ratios need
    var = gradient_variance(grads)
    k = grads.shape[0]
    mean_sq = grads.mean(dim=0).pow(2).sum()
    signal = mean_sq - var / k
    unit = grads / grads.norm(dim=1, keepdim=True).clamp_min(torch.finfo(grads.dtype).tiny)
    gram = unit @ unit.T
    return {
        "grad_var": float(var),
        "grad_mean_norm": float(mean_sq.sqrt()),
        "grad_nsr": float(var / signal) if signal > 0 else math.inf,
        "grad_cosine": float((gram.sum() - gram.diagonal().sum()) / (k * (k - 1))),
    }
