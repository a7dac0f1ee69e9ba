"""A differentiable vector env for your own algorithms: any registered task on any registered engine,
in the convention of DiffRL's and Rewarped's envs.

    from harness.diffenv import make_diff_env

    env = make_diff_env("ant", "newton", num_envs=64, horizon=32)
    obs = env.reset()
    for iteration in range(100):
        obs = env.initialize_trajectory()  # a window boundary: nothing later reaches back past it
        loss = 0.0
        for t in range(env.horizon):
            obs, reward, done, extras = env.step(policy(obs))
            loss = loss - reward.mean()
        loss.backward()  # through the engine: Newton's tape, MuJoCo-Warp's finite differences
        ...

``step(actions)`` returns torch tensors that carry the autograd graph back to every action since the
last window boundary: ``obs`` (N, num_obs) to act on next (a fresh episode's first observation where
``done``), ``reward`` (N,), ``done`` (N,) long (the episode ended: terminated or truncated) and
``extras`` with ``obs_before_reset`` (N, num_obs: the observation the step reached, before any reset,
for a critic's bootstrap), ``episode_end`` (N,) long (ended by the task's termination, not by the time
limit), ``truncated`` (N,) bool, and ``episode_return`` / ``episode_length`` (N,) of the episodes that
just ended (valid where ``done``). An env that ends its episode is reset in the same step and its graph
is cut there; the others keep theirs until :meth:`DiffEnv.initialize_trajectory` or
:meth:`DiffEnv.clear_grad`. A backward pass may reach at most ``horizon`` steps back: cut the graph at
least that often.

It is :class:`tasks.env.TaskEnv`, the env the harness's own algorithms train on, under the field's
names; gradients of its steps are the ones the gradient checks validate (docs/gradient-checks.md).
"""

from __future__ import annotations

import torch

from harness.envs import make_env
from tasks.env import TaskEnv


class DiffEnv:
    """A differentiable vector env (module docstring). Attributes: ``num_envs``, ``num_obs``,
    ``num_actions``, ``episode_length``, ``horizon``, ``device``, ``task``, ``sim`` (the adapter)."""

    def __init__(self, env: TaskEnv, horizon: int):
        self.env = env
        self.task, self.sim = env.task, env.sim
        self.num_envs, self.device = env.num_envs, env.device
        self.num_obs, self.num_actions = env.obs_dim, env.action_dim
        self.episode_length, self.horizon = env.episode_length, horizon

    def reset(self) -> torch.Tensor:
        """Every env back to a fresh episode; the first observations (N, num_obs), no graph."""
        return self.env.reset().detach()

    def clear_grad(self) -> None:
        """Cut the graph of every env: no backward pass reaches past this point."""
        self.env.cut_graph()

    def initialize_trajectory(self) -> torch.Tensor:
        """:meth:`clear_grad`, then the observations to start a window from (N, num_obs)."""
        return self.env.cut_graph()

    def step(self, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict]:
        """One control step of every env under ``actions`` (N, num_actions) in [-1, 1]: ``(obs, reward,
        done, extras)`` (module docstring)."""
        result = self.env.step(actions)
        extras = {
            "obs_before_reset": result.final_obs,
            "episode_end": result.terminated.long(),
            "truncated": result.truncated,
            "episode_return": result.episode_return,
            "episode_length": result.episode_length,
        }
        return result.obs, result.reward, result.done.long(), extras

    def get_checkpoint(self) -> dict:
        """Everything needed to continue every episode exactly from here (tensors, no graph)."""
        return self.env.state_dict()

    def load_checkpoint(self, checkpoint: dict) -> None:
        """Continue from a :meth:`get_checkpoint`; the graph starts anew."""
        self.env.load_state_dict(checkpoint)


def make_diff_env(
    task: str,
    backend: str = "newton",
    num_envs: int = 64,
    horizon: int = 32,
    device: str = "cpu",
    seed: int = 0,
    preset: str | None = None,
    options: dict | None = None,
) -> DiffEnv:
    """``task`` (a registered task name) on ``backend`` (a registered engine, see ``python -m harness
    list``) with ``num_envs`` envs, graphs up to ``horizon`` steps deep, seeded by ``seed`` (initial
    states); ``preset``: the task's physics preset; ``options``: the adapter's options (as
    ``--backend-option``)."""
    from tasks import make_task

    task_object = make_task(task) if preset is None else make_task(task, preset=preset)
    env = make_env(task_object, backend, num_envs, device, seed, horizon, options=options)
    return DiffEnv(env, horizon)
