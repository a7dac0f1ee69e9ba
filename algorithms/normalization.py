"""Running observation statistics for input normalisation (as used by SHAC / SAPO).

``RunningMeanStd`` keeps the mean and the population variance (ddof = 0) of every
sample it has seen, merged batch by batch with the parallel-variance formula of
Chan, Golub & LeVeque (1979). Accumulators are float64 so that millions of merged
float32 batches do not drift. ``normalize`` is differentiable w.r.t. its input:
in first-order RL the observations come out of the differentiable simulator and the
pathwise gradient has to pass through the normaliser.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

__all__ = ["RunningMeanStd"]


class RunningMeanStd(nn.Module):
    """Running mean / variance over the leading dims of ``(..., *shape)`` batches.

    An ``nn.Module`` with buffers ``mean``, ``var``, ``count`` (all float64), so it
    checkpoints through ``state_dict`` / ``load_state_dict`` on its own or as a
    submodule, and follows ``.to(device)``. Dtype casts such as ``.float()`` on a
    parent module are ignored for these buffers (see ``_apply``).

    Args:
        shape: shape of one sample (e.g. ``(obs_dim,)``).
        epsilon: added to the variance before the square root in ``normalize``.
        clip: ``normalize`` clamps its output to [-clip, clip]; None (the default, as DiffRL and
            Mineral) does not clamp, so no observation's pathwise gradient is cut.
    """

    def __init__(self, shape: Sequence[int] = (), epsilon: float = 1e-5, clip: float | None = None):
        super().__init__()
        self.shape = tuple(shape)
        self.epsilon = epsilon
        self.clip = clip
        self.register_buffer("mean", torch.zeros(self.shape, dtype=torch.float64))
        # var starts at 1 so that normalize() before any update is (x - 0) / ~1.
        self.register_buffer("var", torch.ones(self.shape, dtype=torch.float64))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))

    def _apply(self, fn, recurse=True):
        # nn.Module.float()/.half()/.to(dtype) would round the float64 accumulators
        # and lose the precision they exist for; keep device moves, drop dtype casts.
        def keep_float64(t: Tensor) -> Tensor:
            moved = fn(t)
            return moved if moved.dtype == t.dtype else t.to(device=moved.device)

        return super()._apply(keep_float64, recurse)

    @torch.no_grad()
    def update(self, x: Tensor) -> None:
        """Merge a batch ``x`` of shape ``(..., *shape)`` (all leading dims are samples)."""
        batch = x.detach().to(dtype=torch.float64, device=self.mean.device).reshape(-1, *self.shape)
        if batch.shape[0] == 0:
            return
        self.update_from_moments(batch.mean(dim=0), batch.var(dim=0, unbiased=False), batch.shape[0])

    @torch.no_grad()
    def update_from_moments(self, batch_mean: Tensor, batch_var: Tensor, batch_count: int) -> None:
        """Merge a batch given by its mean, population variance and size.

        With n = count, m = batch_count, delta = batch_mean - mean:
            mean' = mean + delta * m / (n + m)
            M2'   = var * n + batch_var * m + delta^2 * n * m / (n + m)
            var'  = M2' / (n + m)
        Exact for n = 0 as well, so no fake initial count is needed.
        """
        batch_mean = batch_mean.to(dtype=torch.float64, device=self.mean.device)
        batch_var = batch_var.to(dtype=torch.float64, device=self.mean.device)
        n = self.count
        total = n + batch_count
        delta = batch_mean - self.mean
        m2 = self.var * n + batch_var * batch_count + delta.pow(2) * n * batch_count / total
        self.mean.copy_(self.mean + delta * batch_count / total)
        self.var.copy_(m2 / total)
        self.count.copy_(total)

    def normalize(self, x: Tensor) -> Tensor:
        """(x - mean) / sqrt(var + epsilon) (clamped to +-clip if set), in x's dtype, differentiable in x."""
        mean = self.mean.to(dtype=x.dtype)
        std = torch.sqrt(self.var + self.epsilon).to(dtype=x.dtype)
        out = (x - mean) / std
        return out if self.clip is None else out.clamp(-self.clip, self.clip)

    def forward(self, x: Tensor) -> Tensor:
        return self.normalize(x)
