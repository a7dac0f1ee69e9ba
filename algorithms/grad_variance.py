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
"""

from __future__ import annotations

from torch import Tensor

__all__ = ["gradient_variance", "per_env_gradient_variance", "batch_gradient_variance"]


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
