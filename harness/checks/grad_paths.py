"""Where an actor gradient's size comes from: the policy's feedback path and the critic's bootstrap
path, each switched off, on the windows training records.

A first-order actor gradient reaches the policy's parameters theta along three kinds of path through
a window: the open-loop one (theta -> an action -> the simulator's later states -> later rewards),
the feedback loop (a later state -> the policy's observation of it -> its later action -> ...: a
product of the simulator's and the policy's Jacobians over the window, which grows with h when the
closed loop amplifies perturbations) and the bootstrap (the window's last states -> the critic's
value). The check trains an algorithm for ``epochs`` epochs as ``train`` does; before each epoch's
update it rolls the epoch's window out four times from the same start (simulator state, random
numbers and observation statistics restored): as in training, without feedback, without bootstrap,
and without both (:meth:`FirstOrderActorCritic.rollout`'s switches), and records the norm of each
unclipped gradient of the actor loss. The epoch then trains on the first of them, so the "as in
training" norm is the one ``train`` logs as ``actor_grad_norm``.

Read: when switching feedback off removes a blow-up, the closed loop amplifies it (the policy's
gain times the simulator's sensitivity exceeds one per step); when switching bootstrap off removes
it, the critic's gradient at the window's end does; when neither does, the open-loop simulator
Jacobians themselves grow (see ``grad-growth``).
"""

from __future__ import annotations

import copy
import math

import torch

from harness.formatting import markdown_table

#: (label, feedback, bootstrap)
VARIANTS = (
    ("as in training", True, True),
    ("no feedback", False, True),
    ("no bootstrap", True, False),
    ("neither", False, False),
)


def _norm(algo, window) -> float:
    params = [p for p in algo.actor.parameters()]
    grads = torch.autograd.grad(algo.actor_loss(window), params, allow_unused=True)
    total = sum(float(g.double().pow(2).sum()) for g in grads if g is not None)
    return math.sqrt(total)


def grad_paths(
    task_name: str,
    backend: str,
    algo_name: str = "shac",
    epochs: int = 10,
    num_envs: int = 16,
    horizon: int = 16,
    seed: int = 0,
    preset: str | None = None,
    device: str = "cpu",
    options: dict | None = None,
    progress=print,
) -> dict:
    """The check (module docstring): per epoch the four norms, and per variant a summary; ``options``
    are the adapter's (for MuJoCo-Warp, its finite-difference settings)."""
    import random

    from algorithms.actor_critic import FirstOrderActorCritic
    from algorithms.config import preset as algo_preset
    from harness.envs import make_sim
    from tasks import make_task
    from tasks.env import TaskEnv

    try:  # the configuration and the adapter's options, refused before any work as a ValueError
        task = make_task(task_name, preset=preset)
        cfg = algo_preset(algo_name).replace(num_envs=num_envs, horizon=horizon, max_epochs=epochs)
        torch.manual_seed(seed)
        random.seed(seed)
        env = TaskEnv(task, make_sim(backend, task, num_envs, device, seed, horizon, **(options or {})))
    except (KeyError, RuntimeError, ValueError) as exc:
        raise ValueError(f"grad-paths {backend}/{task_name}: {exc}") from exc
    algo = FirstOrderActorCritic(cfg, env.obs_dim, env.action_dim)
    env.reset()
    rows = []

    def restore(start) -> None:
        env.load_state_dict(start[0])
        torch.set_rng_state(start[1])
        algo.obs_rms = copy.deepcopy(start[2])

    for epoch in range(epochs):
        start = (env.state_dict(), torch.get_rng_state(), copy.deepcopy(algo.obs_rms))
        norms = {}
        for label, feedback, bootstrap in VARIANTS:
            restore(start)
            norms[label] = _norm(algo, algo.rollout(env, track_heads=False, feedback=feedback, bootstrap=bootstrap))
        restore(start)
        metrics = algo.train_epoch(env)
        rows.append(
            {
                "epoch": epoch,
                "norms": norms,
                "logged_actor_grad_norm": float(metrics["actor_grad_norm"]),
                "update_skipped": bool(metrics["actor_update_skipped"]),
            }
        )
        shown = ", ".join(f"{k} {v:.3g}" for k, v in norms.items())
        progress(f"  epoch {epoch + 1}/{epochs}: {shown}")
    limit = cfg.max_grad_norm_skip
    summary = {}
    full = torch.tensor([r["norms"]["as in training"] for r in rows], dtype=torch.float64)
    for label, _, _ in VARIANTS:
        values = torch.tensor([r["norms"][label] for r in rows], dtype=torch.float64)
        finite = torch.isfinite(values) & torch.isfinite(full) & (full > 0)
        summary[label] = {
            "median_norm": float(values.nanmedian()),
            "max_norm": float(values.nan_to_num(nan=math.inf).max()),
            "above_skip_threshold": int(((values > limit) | ~torch.isfinite(values)).sum()),
            "median_ratio_to_training": float((values[finite] / full[finite]).median()) if finite.any() else math.nan,
        }
    return {
        "task": task_name,
        "backend": backend,
        "preset": task.preset,
        "algo": algo_name,
        "epochs": epochs,
        "num_envs": num_envs,
        "horizon": horizon,
        "seed": seed,
        "options": dict(options or {}),
        "skip_threshold": limit,
        "summary": summary,
        "rows": rows,
    }


def table(result: dict) -> str:
    """Markdown: one row per variant."""
    lines = [
        f"{result['algo']} on {result['task']} ({result['preset']}), {result['backend']}: {result['num_envs']} envs, "
        f"h {result['horizon']}, {result['epochs']} epochs, seed {result['seed']}; unclipped actor-gradient norms",
        "",
    ]
    lines += markdown_table(
        ["gradient paths", "median norm", "max norm", "epochs above the skip threshold", "median ratio to training"],
        [
            [
                label,
                f"{s['median_norm']:.3g}",
                f"{s['max_norm']:.3g}",
                f"{s['above_skip_threshold']} of {result['epochs']}",
                f"{s['median_ratio_to_training']:.3g}",
            ]
            for label, s in result["summary"].items()
        ],
    )
    return "\n".join(lines) + "\n"


# -- the verb and its line in the suite's checks table ---------------------------------------------


def verb(args) -> int:
    """``python -m harness grad-paths``: actor-gradient norms with each gradient path switched off."""
    from algorithms.config import ALGORITHMS
    from harness.inputs import BadInput, preflight
    from harness.results import write_check_and_table

    if args.algo not in ALGORITHMS:
        raise BadInput(f"unknown algorithm {args.algo!r}; choose from: {', '.join(ALGORITHMS)}")
    memory = (args.num_envs, args.horizon)
    preflight(
        backends=args.backend, task=args.task, device=args.device, preset=args.preset, out=args.out, memory=memory
    )
    print(f"grad-paths {args.algo} on {args.backend}/{args.task}: {args.epochs} epochs, four rollouts of each window")
    try:
        result = grad_paths(
            args.task,
            args.backend,
            algo_name=args.algo,
            epochs=args.epochs,
            num_envs=args.num_envs,
            horizon=args.horizon,
            seed=args.seed,
            preset=args.preset,
            device=args.device,
            options=dict(args.backend_option or []),
            progress=lambda line: print(line, flush=True),
        )
    except ValueError as exc:  # an invalid configuration or adapter option, refused before any work
        raise BadInput(str(exc)) from None
    text = table(result)
    print(text)
    if args.out:
        for path in write_check_and_table(args.out, "grad-paths", result, text):
            print(f"wrote {path}")
    return 0


def summary(result: dict, kind: str) -> str:
    from harness.formatting import fmt

    s = result.get("summary", {})
    parts = [f"{label} {fmt(v.get('median_norm'))} ({v.get('above_skip_threshold')} skipped)" for label, v in s.items()]
    return f"{result.get('algo')} actor-gradient norms, median over {result.get('epochs')} epochs: " + ", ".join(parts)
