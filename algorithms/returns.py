"""Return estimators for first-order actor-critic (SHAC / SAPO with TD-lambda).

Equation numbers refer to "ARE: Adaptive TD-lambda Return Estimation for Learning
Control in Differentiable Simulation" (shared/paper/ARE-adaptive-td-lambda.md).

Conventions (every function in this module)
-------------------------------------------
All tensors are time-major over one rollout window of ``T`` steps for ``N``
parallel environments:

``rewards``      (T, N) float. ``r_t`` for ``t = 0..T-1``.
``next_values``  (T, N) float. ``V(s_{t+1})``: the critic's value of the state
                 reached *after* step ``t``. At a time-limit truncation this must be
                 the value of the true final state (not of the reset state). Where
                 ``terminated[t]`` the functions replace it by 0 themselves, so the
                 caller may leave any finite number there.
``terminated``   (T, N) bool. The episode ended after step ``t`` by termination:
                 bootstrap with 0.
``truncated``    (T, N) bool. The episode ended after step ``t`` by the time limit:
                 bootstrap with ``next_values[t]``. If both flags are set,
                 termination wins.

``done = terminated | truncated``. A *segment* (SHAC's mini-trajectory) is a
maximal run of steps of one episode inside the window: it starts at ``t = 0`` or
right after a done step, and ends at the next done step or at ``t = T-1``.
Returns never look across a segment end: the step after a done step belongs to a
new episode, and the window's last step has no successor. Both therefore
bootstrap with ``next_values`` (0 if terminated). Mask arguments of any dtype are
accepted and read as ``!= 0``.

``gamma`` and ``lam`` may be Python floats or 0-dim tensors. ``lam`` in particular
may require grad (adaptive lambda learns ``lam = sigmoid(phi)`` and differentiates
eq. 15 through these functions), so nothing here converts it with ``float()``.
All functions are differentiable w.r.t. ``rewards`` and ``next_values`` (the actor
loss backpropagates through rewards into the simulator).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = [
    "td_lambda_returns",
    "h_step_returns",
    "td_lambda_closed_form",
    "segment_starts",
    "actor_loss_per_env",
    "actor_loss_from_returns",
    "critic_targets",
]


def _prepare(
    rewards: Tensor, next_values: Tensor, terminated: Tensor, truncated: Tensor
) -> tuple[Tensor, Tensor, Tensor]:
    """Validate shapes; return (bootstrap values, terminated, done) with bool masks.

    The bootstrap value is ``next_values`` with terminated entries set to 0. We use
    ``torch.where`` rather than multiplying by ``1 - terminated`` so that whatever
    the caller left there (even inf/nan) never leaks into the result or its gradient.
    """
    if rewards.dim() != 2:
        raise ValueError(f"rewards must be (T, N), got shape {tuple(rewards.shape)}")
    if rewards.shape[0] == 0:
        raise ValueError("empty window: T must be >= 1")
    for name, x in (("next_values", next_values), ("terminated", terminated), ("truncated", truncated)):
        if x.shape != rewards.shape:
            raise ValueError(f"{name} has shape {tuple(x.shape)}, expected {tuple(rewards.shape)}")
    terminated = terminated.to(dtype=torch.bool)
    done = terminated | truncated.to(dtype=torch.bool)
    bootstrap = torch.where(terminated, torch.zeros_like(next_values), next_values)
    return bootstrap, terminated, done


def _continues(done: Tensor) -> Tensor:
    """(T, N) bool: True where the recursion may use G_{t+1} (same episode, not last step)."""
    cont = ~done
    cont[-1] = False  # the window's last step always bootstraps
    return cont


def td_lambda_returns(
    rewards: Tensor,
    next_values: Tensor,
    terminated: Tensor,
    truncated: Tensor,
    gamma: float | Tensor,
    lam: float | Tensor,
) -> Tensor:
    """Truncated TD-lambda return G^lambda_t for every t (eq. 10 via the recursion of eq. 14).

    Backward recursion, with ``V_{t+1} = next_values[t]`` zeroed where terminated::

        G_t = r_t + gamma * (1 - term_t) * [(1 - lam_t) V_{t+1} + lam_t G_{t+1}]

    where ``lam_t = lam`` inside a segment and ``lam_t = 0`` at its last step (a done
    step or ``t = T-1``), so the last step of every segment bootstraps with its own
    ``V_{t+1}`` and never reads ``G_{t+1}`` of the next episode. This reproduces the
    finite-horizon weights of eq. 10 per segment; see ``td_lambda_closed_form``.

    Cost is O(T) sequential steps, each vectorised over N.

    Returns:
        (T, N) tensor, differentiable w.r.t. rewards, next_values, gamma and lam.
    """
    bootstrap, _, done = _prepare(rewards, next_values, terminated, truncated)
    cont = _continues(done)
    out: list[Tensor] = []
    g_next = bootstrap[-1]  # never read at t = T-1 because cont[-1] is False
    for t in range(rewards.shape[0] - 1, -1, -1):
        v = bootstrap[t]
        # (1 - lam) V + lam G == V + lam (G - V): same value, one fewer product.
        # torch.where (not a 0/1 multiply) so a new episode's G_{t+1} is never read.
        mixed = torch.where(cont[t], v + lam * (g_next - v), v)
        g_next = rewards[t] + gamma * mixed
        out.append(g_next)
    # Collect and stack rather than write into a preallocated tensor: in-place writes
    # into a buffer would break autograd through lam / rewards.
    return torch.stack(out[::-1], dim=0)


def h_step_returns(
    rewards: Tensor,
    next_values: Tensor,
    terminated: Tensor,
    truncated: Tensor,
    gamma: float | Tensor,
) -> Tensor:
    """SHAC's bootstrapped return from every t to the end of its segment (G^(h) of eq. 8/9).

    For a step ``t`` whose segment ends at step ``e`` (next done step, or ``T-1``)::

        G_t = sum_{k=0}^{e-t} gamma^k r_{t+k} + gamma^(e-t+1) * V_{e+1}

    with ``V_{e+1} = next_values[e]``, or 0 if ``terminated[e]``. Written as the
    backward recursion ``G_t = r_t + gamma * (G_{t+1} inside the segment, else V_{t+1})``.
    Equal to ``td_lambda_returns(..., lam=1)``.

    Returns:
        (T, N) tensor, differentiable w.r.t. rewards, next_values and gamma.
    """
    bootstrap, _, done = _prepare(rewards, next_values, terminated, truncated)
    cont = _continues(done)
    out: list[Tensor] = []
    g_next = bootstrap[-1]
    for t in range(rewards.shape[0] - 1, -1, -1):
        g_next = rewards[t] + gamma * torch.where(cont[t], g_next, bootstrap[t])
        out.append(g_next)
    return torch.stack(out[::-1], dim=0)


def _segment_lengths(done: Tensor) -> Tensor:
    """(T, N) long: number of steps from t to the end of its segment, inclusive."""
    T = done.shape[0]
    lengths = torch.ones(done.shape, dtype=torch.long, device=done.device)
    for t in range(T - 2, -1, -1):
        lengths[t] = torch.where(done[t], 1, lengths[t + 1] + 1)
    return lengths


def td_lambda_closed_form(
    rewards: Tensor,
    next_values: Tensor,
    terminated: Tensor,
    truncated: Tensor,
    gamma: float | Tensor,
    lam: float | Tensor,
) -> Tensor:
    """Reference TD-lambda return straight from eq. 10. O(T^2); for tests only.

    For step ``t`` with ``L`` steps left in its segment (``L`` replaces the paper's
    ``h - t``; it is shorter when an episode ends inside the window)::

        G^lambda_t = sum_{k=1}^{L-1} (1 - lam) lam^(k-1) G^(k)_t + lam^(L-1) G^(L)_t
        G^(k)_t    = sum_{l=0}^{k-1} gamma^l r_{t+l} + gamma^k V_{t+k}

    with ``V_{t+k} = next_values[t+k-1]`` (0 where terminated). Every k-step return is
    formed explicitly and weighted, with no recursion, so that it is an independent
    check of ``td_lambda_returns``. Same conventions and return shape.
    """
    bootstrap, _, done = _prepare(rewards, next_values, terminated, truncated)
    lengths = _segment_lengths(done)
    T = rewards.shape[0]
    lam = torch.as_tensor(lam, dtype=rewards.dtype, device=rewards.device)
    zero = torch.zeros((), dtype=rewards.dtype, device=rewards.device)
    out = []
    for t in range(T):
        total = torch.zeros_like(rewards[t])
        reward_sum = torch.zeros_like(rewards[t])
        for k in range(1, T - t + 1):
            reward_sum = reward_sum + gamma ** (k - 1) * rewards[t + k - 1]
            g_k = reward_sum + gamma**k * bootstrap[t + k - 1]
            # k-step returns that run past the segment end get weight 0: they would
            # mix in the next episode.
            weight = torch.where(
                k < lengths[t],
                (1 - lam) * lam ** (k - 1),
                torch.where(k == lengths[t], lam ** (k - 1), zero),
            )
            total = total + weight * g_k
        out.append(total)
    return torch.stack(out, dim=0)


def segment_starts(terminated: Tensor, truncated: Tensor) -> Tensor:
    """(T, N) bool: True at t = 0 and wherever step t-1 ended an episode.

    These are the starts of SHAC's mini-trajectories tau_j inside the window.
    """
    done = terminated.to(dtype=torch.bool) | truncated.to(dtype=torch.bool)
    first = torch.ones_like(done[:1])
    return torch.cat([first, done[:-1]], dim=0)


def actor_loss_per_env(returns: Tensor, starts: Tensor, horizon: int) -> Tensor:
    """(N,) per-environment actor loss: -(1/h) * sum of G over the env's segment starts.

    The mean over environments is the actor loss of eq. 9 / eq. 12; keeping the
    per-env form lets ``grad_variance.group_gradients`` split the batch.
    """
    if returns.shape != starts.shape:
        raise ValueError(f"starts shape {tuple(starts.shape)} != returns shape {tuple(returns.shape)}")
    picked = torch.where(starts.to(dtype=torch.bool), returns, torch.zeros_like(returns))
    return -picked.sum(dim=0) / horizon


def actor_loss_from_returns(returns: Tensor, starts: Tensor, horizon: int) -> Tensor:
    """Actor loss of eq. 9 (returns = h-step) or eq. 12 (returns = TD-lambda).

        L = -(1 / (N h)) * sum over mini-trajectory starts (t, n) of G[t, n]

    with N = ``returns.shape[1]`` and h = ``horizon``. With h-step returns this equals
    SHAC's usual per-step accumulation (discount reset at every episode start plus a
    bootstrap at every segment end), summed over the window and divided by N*h.
    """
    return actor_loss_per_env(returns, starts, horizon).mean()


def critic_targets(
    rewards: Tensor,
    next_values: Tensor,
    terminated: Tensor,
    truncated: Tensor,
    gamma: float | Tensor,
    lam: float | Tensor,
) -> Tensor:
    """Detached TD-lambda targets V~^lambda(s_t) = G^lambda_t for the critic loss (eq. 11).

    For the lambda loss of eq. 15 call ``td_lambda_returns`` instead, with detached
    ``rewards``/``next_values`` and a ``lam`` that requires grad.
    """
    with torch.no_grad():
        return td_lambda_returns(rewards, next_values, terminated, truncated, gamma, lam).detach()
