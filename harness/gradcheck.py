"""Check an adapter's autograd gradients against central finite differences.

The loss is the task's own objective over a short rollout, ``L = sum_t sum_envs r_t``, so the
check covers exactly the path SHAC differentiates: actions -> engine -> state -> observation ->
reward. Gradients are taken w.r.t. every action of every step and w.r.t. the initial generalized
state (root pose and velocity, joint positions and velocities).

Envs are independent, so one perturbation of coordinate ``i`` in *every* env at once gives the
finite difference of each env's own loss: the cost is two rollouts per coordinate of one env,
whatever the number of envs.

The error reported is, per env, ``||g_autograd - g_fd|| / ||g_fd||`` over all coordinates of a
kind (actions or initial state), maximised over envs. A vector norm rather than element-wise
ratios, because the simulation is float32: a coordinate whose true derivative is ~0 has a finite
difference of pure round-off, which an element-wise ratio turns into a meaningless huge error.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch

from backends.contract import BatchedSim
from tasks.rollout import rollout_reward

# Why these numbers: the engines run in float32 (~7 significant digits). With losses of O(1-10)
# and steps of 1e-2 (actions, i.e. 2 N m of torque) and 1e-3 (state), round-off in a central
# difference is ~1e-6 * |L| / eps ~ 1e-4-1e-3 relative, truncation error is O(eps^2). A correct
# adapter lands well below 1e-2 on a contact-free segment; a wrong one (a missing chain-rule term,
# stale tape data) is off by O(1).
DEFAULT_TOLERANCE = 2e-2
ACTION_EPS = 1e-2
STATE_EPS = 1e-3


@dataclass
class GradcheckResult:
    action_rel_error: float
    state_rel_error: float
    steps: int
    num_envs: int
    loss: float

    @property
    def max_rel_error(self) -> float:
        return max(self.action_rel_error, self.state_rel_error)


def rollout_loss(sim: BatchedSim, q0: torch.Tensor, qd0: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """Per-env loss (N,): the task's rewards summed over actions (T, N, A) from generalized state (q0, qd0),
    with the env's step semantics (:func:`tasks.rollout.rollout_reward`)."""
    return rollout_reward(sim, sim.state_from_generalized(q0, qd0), actions)


def _fd_per_env(fn, x: torch.Tensor, eps: float) -> torch.Tensor:
    """d(fn(x)[n]) / d(x[..., n, i]) by central differences; the env axis of ``x`` is dim -2.

    Each perturbation moves coordinate ``(..., i)`` of every env at once (envs are independent).
    """
    x = x.detach()
    grad = torch.zeros_like(x, dtype=torch.float64)
    lead_shape, width = x.shape[:-2], x.shape[-1]
    for lead in itertools.product(*(range(s) for s in lead_shape)):
        for i in range(width):
            where = (*lead, slice(None), i)
            plus, minus = x.clone(), x.clone()
            plus[where] += eps
            minus[where] -= eps
            with torch.no_grad():
                grad[where] = (fn(plus) - fn(minus)) / (2.0 * eps)
    return grad


def _rel_error(autograd: torch.Tensor, fd: torch.Tensor) -> float:
    """max over envs of ||a - f|| / ||f||; env axis at dim -2."""
    a = autograd.double().movedim(-2, 0).reshape(autograd.shape[-2], -1)
    f = fd.double().movedim(-2, 0).reshape(fd.shape[-2], -1)
    err = (a - f).norm(dim=1) / f.norm(dim=1).clamp_min(1e-12)
    return float(err.max())


def gradcheck(
    sim: BatchedSim,
    steps: int = 8,
    seed: int = 0,
    start_height: float | None = None,
    action_scale: float = 0.5,
) -> GradcheckResult:
    """Compare autograd and central-difference gradients of the rollout loss.

    ``start_height`` lifts the root (floating-base tasks) so the whole rollout is in the air:
    a smooth, contact-free segment where finite differences are trustworthy. ``None`` keeps
    the task's own initial height (contact included).
    """
    gen = torch.Generator().manual_seed(seed)
    q0, qd0 = sim.task.sample_initial_state(sim.num_envs, gen)
    if start_height is not None:
        q0[:, 2] = start_height
    q0, qd0 = q0.to(sim.device), qd0.to(sim.device)
    actions = action_scale * (2.0 * torch.rand(steps, sim.num_envs, sim.task.action_dim, generator=gen) - 1.0)
    actions = actions.to(sim.device)

    q_var = q0.clone().requires_grad_(True)
    qd_var = qd0.clone().requires_grad_(True)
    a_var = actions.clone().requires_grad_(True)
    loss = rollout_loss(sim, q_var, qd_var, a_var)
    loss.sum().backward()

    fd_actions = _fd_per_env(lambda a: rollout_loss(sim, q0, qd0, a), actions, ACTION_EPS)
    fd_q = _fd_per_env(lambda q: rollout_loss(sim, q, qd0, actions), q0, STATE_EPS)
    fd_qd = _fd_per_env(lambda qd: rollout_loss(sim, q0, qd, actions), qd0, STATE_EPS)
    # a missing gradient (no autograd path at all) counts as zero, i.e. 100% error
    grads = [v.grad if v.grad is not None else torch.zeros_like(v) for v in (q_var, qd_var, a_var)]
    state_ad = torch.cat(grads[:2], dim=-1)
    state_fd = torch.cat((fd_q, fd_qd), dim=-1)
    return GradcheckResult(
        action_rel_error=_rel_error(grads[2], fd_actions),
        state_rel_error=_rel_error(state_ad, state_fd),
        steps=steps,
        num_envs=sim.num_envs,
        loss=float(loss.detach().sum()),
    )
