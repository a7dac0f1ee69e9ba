"""A stateful vector environment: one task on one adapter, with episodes and automatic resets.

This is the layer algorithms talk to (harness -> algorithm -> this env -> adapter -> engine).
Observations and rewards are differentiable w.r.t. the actions through the adapter; one step is
:func:`tasks.rollout.transition`, the same function the gradient checks differentiate. ``sim`` is
an adapter instance (``backends.BatchedSim``); this module does not import backends.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from simcore import SimState
from tasks.base import Task
from tasks.rollout import transition


@dataclass
class StepResult:
    obs: torch.Tensor  # (N, obs_dim) observation to act on next (post-reset rows are fresh)
    reward: torch.Tensor  # (N,)
    terminated: torch.Tensor  # (N,) bool: ended by the task's termination condition
    truncated: torch.Tensor  # (N,) bool: ended by the episode time limit
    final_obs: torch.Tensor  # (N, obs_dim) observation reached by this step, before any reset
    episode_return: torch.Tensor  # (N,) return of the episode that just ended (valid where done)
    episode_length: torch.Tensor  # (N,) length of the episode that just ended (valid where done)

    @property
    def done(self) -> torch.Tensor:
        return self.terminated | self.truncated


class TaskEnv:
    def __init__(self, task: Task, sim, episode_length: int | None = None):
        self.task = task
        self.sim = sim
        self.num_envs = sim.num_envs
        self.device = sim.device
        self.episode_length = int(episode_length or task.episode_length)
        self.obs_dim = task.obs_dim
        self.action_dim = task.action_dim
        self.prev_actions = torch.zeros(self.num_envs, task.action_dim, device=self.device)
        self.steps = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)
        self.returns = torch.zeros(self.num_envs, device=self.device)
        self.obs = self._observe()

    def _observe(self) -> torch.Tensor:
        """The task's observation of the current state, refused unless it is (N, obs_dim): a task whose
        ``observe`` disagrees with its declared width would feed the networks the wrong inputs."""
        obs = self.task.observe(self.sim.state, self.prev_actions)
        if tuple(obs.shape) != (self.num_envs, self.obs_dim):
            raise ValueError(
                f"task {self.task.name!r} observed shape {tuple(obs.shape)}; it declares obs_dim {self.obs_dim} "
                f"for {self.num_envs} envs"
            )
        return obs

    def state_dict(self) -> dict:
        """Everything needed to continue the episodes exactly (for checkpoints)."""
        sim = self.sim
        return {
            "sim_state": {k: v.detach().clone() for k, v in sim.state.tensors().items()},
            "sim_generator": sim.generator.get_state(),
            "sim_step_count": sim.step_count,
            "prev_actions": self.prev_actions.detach().clone(),
            "steps": self.steps.clone(),
            "returns": self.returns.clone(),
            "obs": self.obs.detach().clone(),
        }

    def load_state_dict(self, state: dict) -> None:
        self.sim.state = SimState(**{k: v.to(self.device) for k, v in state["sim_state"].items()})
        self.sim.generator.set_state(state["sim_generator"])
        self.sim.step_count = state["sim_step_count"]
        self.prev_actions = state["prev_actions"].to(self.device)
        self.steps = state["steps"].to(self.device)
        self.returns = state["returns"].to(self.device)
        self.obs = state["obs"].to(self.device)

    def reset(self) -> torch.Tensor:
        self.sim.reset()
        self.prev_actions = torch.zeros_like(self.prev_actions)
        self.steps.zero_()
        self.returns.zero_()
        self.obs = self._observe()
        return self.obs

    def cut_graph(self) -> torch.Tensor:
        """Window boundary: no gradient path from anything later to anything before this call."""
        self.sim.cut_graph()
        self.prev_actions = self.prev_actions.detach()
        self.obs = self.obs.detach()
        return self.obs

    def step(self, actions: torch.Tensor) -> StepResult:
        state, obs, reward = transition(self.sim, self.sim.state, actions, self.prev_actions)
        self.sim.commit(state)
        self.steps += 1
        self.returns += reward.detach()
        terminated = self.task.terminated(state, obs)
        truncated = (self.steps >= self.episode_length) & ~terminated
        done = terminated | truncated
        episode_return = self.returns.clone()
        episode_length = self.steps.clone()
        final_obs = obs
        self.prev_actions = actions
        if bool(done.any()):
            ids = done.nonzero().flatten()
            self.sim.reset(ids)  # cuts the graph for these envs only
            keep = ~done
            self.prev_actions = torch.where(keep[:, None], actions, torch.zeros_like(actions))
            fresh = self.task.observe(self.sim.state, self.prev_actions)
            obs = torch.where(keep[:, None], obs, fresh.detach())
            self.steps[ids] = 0
            self.returns[ids] = 0.0
        self.obs = obs
        return StepResult(obs, reward, terminated, truncated, final_obs, episode_return, episode_length)
