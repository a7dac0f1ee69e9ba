"""The task's objective over a rollout, with exactly the env's step semantics.

One control step (:func:`transition`) is: the adapter advances the state under the actions
(``sim.advance``: validation, ``task.actions_to_control``, ``simulate``), the task observes the new
state with these actions as the "previous actions" of the next decision, and rewards the
transition with the same actions. :class:`tasks.env.TaskEnv` steps through this function, and
:func:`rollout_reward` sums its rewards over k steps from a given state: the loss that
``gradcheck``, ``crosscheck`` and ``grad-growth`` differentiate is therefore the env's own.

``sim`` is any adapter instance (a ``backends.BatchedSim``); this module does not import backends.
"""

from __future__ import annotations

import torch

from simcore import SimState


def transition(
    sim, state: SimState, actions: torch.Tensor, prev_actions: torch.Tensor
) -> tuple[SimState, torch.Tensor, torch.Tensor]:
    """(next state, observation, reward) of one control step from ``state`` under ``actions`` (N, A);
    ``prev_actions`` are the actions of the step before (zeros after a reset)."""
    task = sim.task
    next_state = sim.advance(state, actions)
    obs = task.observe(next_state, actions)
    return next_state, obs, task.reward(next_state, obs, actions, prev_actions)


def rollout(
    sim, state: SimState, actions: torch.Tensor, prev_actions: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-env sum (N,) float64 of the task's rewards over ``actions`` (T, N, A) from ``state``, and
    the observation (N, obs_dim) after the last step (what a critic would value).

    ``prev_actions`` (N, A): the actions before the first step (default zeros, as after a reset).
    No episode bookkeeping: termination and resets are the env's business, so callers choose
    segments short enough (or states far enough from termination) for the sum to be one episode's.
    """
    total = torch.zeros(actions.shape[1], dtype=torch.float64, device=actions.device)
    prev = torch.zeros_like(actions[0]) if prev_actions is None else prev_actions
    obs = None
    for t in range(actions.shape[0]):
        state, obs, reward = transition(sim, state, actions[t], prev)
        total = total + reward.double()
        prev = actions[t]
    return total, obs


def rollout_reward(
    sim, state: SimState, actions: torch.Tensor, prev_actions: torch.Tensor | None = None
) -> torch.Tensor:
    """Per-env sum (N,) float64 of the task's rewards over ``actions`` (T, N, A) from ``state``
    (:func:`rollout`)."""
    return rollout(sim, state, actions, prev_actions)[0]
