"""A first-order policy trained through the simulator, outside the harness's algorithms: the
differentiable env (harness/diffenv.py), a linear policy, and the h-step return backpropagated
through the engine. No critic, no TD-lambda: the smallest thing that learns from simulator gradients.

    python examples/first_order_policy.py [--task ant] [--backend newton] [--iterations 50]
"""

from __future__ import annotations

import argparse

import torch

from harness.diffenv import make_diff_env


def train(task="ant", backend="newton", num_envs=16, horizon=16, iterations=50, lr=1e-2, seed=0, log=print):
    """Train; returns the mean reward per step of each iteration's window."""
    torch.manual_seed(seed)
    env = make_diff_env(task, backend, num_envs=num_envs, horizon=horizon, seed=seed)
    policy = torch.nn.Linear(env.num_obs, env.num_actions)
    optimizer = torch.optim.Adam(policy.parameters(), lr=lr)
    env.reset()
    history = []
    for iteration in range(iterations):
        obs = env.initialize_trajectory()
        rewards = []
        for _ in range(horizon):
            obs, reward, done, extras = env.step(torch.tanh(policy(obs)))
            rewards.append(reward)
        loss = -torch.stack(rewards).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        history.append(-loss.item())
        log(f"iteration {iteration}: mean reward per step {history[-1]:.3f}")
    return history


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="ant")
    parser.add_argument("--backend", default="newton")
    parser.add_argument("--iterations", type=int, default=50)
    args = parser.parse_args()
    train(args.task, args.backend, iterations=args.iterations)
