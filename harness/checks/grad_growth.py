"""Do the simulator's action gradients blow up along a policy's own trajectories?

Drives ``num_envs`` envs with a trained run's stochastic policy for ``windows`` windows of
``horizon`` steps (no gradient), recording each window's start state and actions. Then, per
physics variant, replays each window open-loop from its start state with the recorded actions
as leaves and takes the gradient of the summed task reward w.r.t. the window's first actions.
A sound configuration gives per-env gradient norms of O(1-10); an unstable adjoint gives some
envs norms of 1e3 and far above while the forward pass stays finite.

``python -m harness grad-growth --run DIR --variant contact_kf=3000 --variant contact_kf=300``
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import torch

from algorithms.actor_critic import FirstOrderActorCritic
from harness.run.folder import CHECKPOINT, open_run
from harness.run.train import load_checkpoint


def parse_variant(text: str) -> dict:
    """``"contact_kf=300,joint_limit_ke=100"`` -> changes to the run's PhysicsSpec (``""``: none)."""
    from simcore import PhysicsSpec

    types = {f.name: f.type for f in dataclasses.fields(PhysicsSpec)}  # annotations as text: "int", "float", ...
    names = set(types)
    changes = {}
    for item in filter(None, text.split(",")):
        key, _, value = item.partition("=")
        if key not in names:
            raise ValueError(f"unknown physics constant {key!r}; choose from: {', '.join(sorted(names))}")
        try:
            changes[key] = int(value) if types[key] == "int" else float(value)
        except ValueError:
            raise ValueError(f"--variant {key}={value!r}: expected a number") from None
    return changes


def grad_growth(run: str | Path, variants: list[str], windows: int = 3, seed: int = 0) -> dict:
    from harness.envs import make_env, make_sim, run_task
    from tasks.rollout import rollout_reward

    run = Path(run)
    config = open_run(run, (CHECKPOINT,))
    algo_cfg = config["algo_config"]
    n, h = algo_cfg.num_envs, algo_cfg.horizon
    task = run_task(config)
    physics = task.physics
    torch.manual_seed(seed)
    env = make_env(task, config["backend"], n, seed=seed, horizon=h)
    algo = FirstOrderActorCritic(algo_cfg, env.obs_dim, env.action_dim)
    load_checkpoint(run / CHECKPOINT, algo, env)
    recorded = []
    with torch.no_grad():
        for _ in range(windows):
            start = env.sim.state.detach()
            actions = []
            for _ in range(h):
                actions.append(algo.act(env.obs, deterministic=False))
                env.step(actions[-1])
            recorded.append((start, torch.stack(actions)))

    out = {"run": str(run), "windows": windows, "num_envs": n, "horizon": h, "variants": []}
    for text in variants:
        variant_task = run_task(config, dataclasses.replace(physics, **parse_variant(text)))
        sim = make_sim(config["backend"], variant_task, n, seed=seed, horizon=h)
        norms = []
        for start, actions in recorded:
            a = actions.clone().requires_grad_(True)
            rollout_reward(sim, start, a).sum().backward()
            norms.append(a.grad[0].norm(dim=1))
        g = torch.cat(norms)
        out["variants"].append(
            {
                "physics": text or "task defaults",
                "max_grad_norm": float(g.max()),
                "median_grad_norm": float(g.median()),
                "env_windows_above_1e3": int((g > 1e3).sum()),
                "env_windows": int(g.numel()),
            }
        )
        print(json.dumps(out["variants"][-1]), flush=True)
    return out
