"""Training and evaluation runs: configs, metrics files, checkpoints, resume, evaluation.

A run directory holds:

* ``config.json``: every hyperparameter, the task/backend/seed/device, and the command.
* ``metrics.jsonl``: one JSON object per epoch (flushed as written).
* ``checkpoint.pt``: the latest algorithm + env state (written atomically, never with
  non-finite weights); ``checkpoint_init.pt``: the initial policy, for evaluation baselines.
* ``eval.json``: written by :func:`evaluate`.

``--resume`` reloads the checkpoint, drops metric rows written after it, and continues: the
env state and every random generator are restored, so the continuation is the same run.
"""

from __future__ import annotations

import dataclasses
import json
import os
import random
import sys
import time
from pathlib import Path

import torch

from algorithms.actor_critic import FirstOrderActorCritic
from algorithms.config import AlgoConfig
from harness.envs import make_env
from harness.results import atomic_write_text, provenance, write_json

CHECKPOINT = "checkpoint.pt"
INIT_CHECKPOINT = "checkpoint_init.pt"


class RunError(RuntimeError):
    """A run directory or configuration problem, reported as one line."""


def _rng_state() -> dict:
    return {"torch": torch.get_rng_state(), "python": random.getstate()}


def _set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    random.setstate(state["python"])


def save_checkpoint(path: Path, algo: FirstOrderActorCritic, env, progress: dict) -> None:
    if not algo.parameters_finite():
        raise RunError(f"refusing to write {path.name}: the algorithm holds non-finite weights")
    payload = {
        "algo": algo.state_dict(),
        "optimizers": {
            name: getattr(algo, name).state_dict() for name in ("actor_opt", "critic_opt", "lambda_opt", "alpha_opt")
        },
        "epoch": algo.epoch,
        "env": env.state_dict() if env is not None else None,
        "rng": _rng_state(),
        "progress": progress,
    }
    tmp = path.with_suffix(".pt.tmp")
    torch.save(payload, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: Path, algo: FirstOrderActorCritic, env=None) -> dict:
    payload = torch.load(path, map_location="cpu", weights_only=False)
    algo.load_state_dict(payload["algo"])
    for name, state in payload["optimizers"].items():
        getattr(algo, name).load_state_dict(state)
    algo.epoch = payload["epoch"]
    if env is not None and payload["env"] is not None:
        env.load_state_dict(payload["env"])
    if env is not None:
        _set_rng_state(payload["rng"])
    return payload["progress"]


class _Progress:
    """A one-line progress bar on a terminal, periodic plain lines otherwise."""

    def __init__(self, total: int, start: int, stream=sys.stdout):
        self.total, self.start, self.stream = total, start, stream
        self.tty = stream.isatty()
        self.t0 = time.perf_counter()

    def update(self, epoch: int, row: dict) -> None:
        done = epoch + 1
        ret = row.get("train_episode_return_avg")
        ret_s = f"{ret:8.1f}" if ret is not None else "     n/a"
        rate = (done - self.start) / max(time.perf_counter() - self.t0, 1e-9)
        eta = (self.total - done) / rate if rate > 0 else float("nan")
        width = 24
        filled = int(width * done / self.total)
        line = (
            f"[{'#' * filled}{'.' * (width - filled)}] epoch {done}/{self.total} "
            f"return {ret_s}  lambda {row['lam']:.3f}  {rate:.2f} ep/s  eta {eta / 60:.1f} min"
        )
        if self.tty:
            self.stream.write("\r" + line)
            if done == self.total:
                self.stream.write("\n")
        elif done == self.total or done % max(1, self.total // 20) == 0:
            self.stream.write(line + "\n")
        self.stream.flush()


def _append_metrics(path: Path, row: dict) -> None:
    with path.open("a") as fh:
        fh.write(json.dumps(row) + "\n")
        fh.flush()


def _truncate_metrics(path: Path, before_epoch: int) -> None:
    """Drop rows written after the checkpoint being resumed (they will be re-run)."""
    if not path.exists():
        return
    keep = [line for line in path.read_text().splitlines() if line and json.loads(line)["epoch"] < before_epoch]
    atomic_write_text(path, "".join(line + "\n" for line in keep))


def train(
    run_dir: str | Path,
    task: str,
    backend: str,
    algo_config: AlgoConfig,
    epochs: int,
    seed: int = 0,
    device: str = "cpu",
    checkpoint_every: int = 5,
    command: str | None = None,
    stream=sys.stdout,
) -> Path:
    """Start a new run in ``run_dir`` (which must not hold one) and train it for ``epochs`` epochs."""
    run_dir = Path(run_dir)
    if (run_dir / "config.json").exists():
        raise RunError(f"{run_dir} already holds a run; pass --resume to continue it or choose another --out")
    algo_config = algo_config.replace(max_epochs=algo_config.max_epochs or epochs)
    config = {
        "task": task,
        "backend": backend,
        "seed": seed,
        "device": device,
        "epochs": epochs,
        "algo": algo_config.as_dict(),
        "provenance": provenance(command),
    }
    return _run(run_dir, config, algo_config, resume=False, checkpoint_every=checkpoint_every, stream=stream)


def resume(
    run_dir: str | Path,
    epochs: int | None = None,
    checkpoint_every: int = 5,
    command: str | None = None,
    stream=sys.stdout,
) -> Path:
    """Continue the run in ``run_dir`` from its checkpoint, up to ``epochs`` in total (default: as planned)."""
    run_dir = Path(run_dir)
    config_path = run_dir / "config.json"
    if not config_path.exists() or not (run_dir / CHECKPOINT).exists():
        raise RunError(f"cannot resume {run_dir}: no config.json/checkpoint.pt there")
    config = json.loads(config_path.read_text())
    algo_config = AlgoConfig.from_dict(config["algo"])
    config["epochs"] = max(epochs, config["epochs"]) if epochs else config["epochs"]
    config.setdefault("resumed", []).append(provenance(command))  # the original command stays
    return _run(run_dir, config, algo_config, resume=True, checkpoint_every=checkpoint_every, stream=stream)


def _run(run_dir: Path, config: dict, algo_config: AlgoConfig, resume: bool, checkpoint_every: int, stream) -> Path:
    task, backend, seed, device, epochs = (config[k] for k in ("task", "backend", "seed", "device", "epochs"))
    config_path, metrics_path, ckpt_path = run_dir / "config.json", run_dir / "metrics.jsonl", run_dir / CHECKPOINT
    torch.manual_seed(seed)
    random.seed(seed)
    env = make_env(task, backend, algo_config.num_envs, device, seed, algo_config.horizon)
    config.setdefault("physics", dataclasses.asdict(env.task.physics))
    run_dir.mkdir(parents=True, exist_ok=True)
    write_json(config_path, config)
    algo = FirstOrderActorCritic(algo_config, env.obs_dim, env.action_dim)
    progress = {"env_steps": 0, "wall_s": 0.0, "recent_returns": [], "nonfinite_events": 0}
    if resume:
        progress = load_checkpoint(ckpt_path, algo, env)
        _truncate_metrics(metrics_path, algo.epoch)
        print(f"resuming {run_dir} at epoch {algo.epoch}/{epochs}", file=stream, flush=True)
    else:
        env.reset()
        save_checkpoint(run_dir / INIT_CHECKPOINT, algo, env, progress)
    bar = _Progress(epochs, algo.epoch, stream)
    from backends.contract import NonFiniteStateError

    try:
        while algo.epoch < epochs:
            start = time.perf_counter()
            try:
                metrics = algo.train_epoch(env)
            except NonFiniteStateError as exc:  # the simulation blew up: log it, restart episodes
                progress["nonfinite_events"] += 1
                print(f"\nwarning: epoch {algo.epoch}: {exc}; resetting all envs", file=stream, flush=True)
                env.reset()
                continue
            elapsed = time.perf_counter() - start
            progress["env_steps"] += algo_config.num_envs * algo_config.horizon
            progress["wall_s"] += elapsed
            recent = (progress["recent_returns"] + [metrics["train_episode_return"]])[-20:]
            progress["recent_returns"] = [r for r in recent if r is not None]
            avg = (
                sum(progress["recent_returns"]) / len(progress["recent_returns"])
                if progress["recent_returns"]
                else None
            )
            row = {
                "epoch": algo.epoch - 1,
                "env_steps": progress["env_steps"],
                "wall_s": progress["wall_s"],
                "epoch_s": elapsed,
                **metrics,
                "train_episode_return_avg": avg,
            }
            _append_metrics(metrics_path, row)
            bar.update(algo.epoch - 1, row)
            if algo.epoch % checkpoint_every == 0 or algo.epoch == epochs:
                save_checkpoint(ckpt_path, algo, env, progress)
    except KeyboardInterrupt:
        save_checkpoint(ckpt_path, algo, env, progress)
        _truncate_metrics(metrics_path, algo.epoch)
        print(f"\ninterrupted: checkpoint at epoch {algo.epoch} in {run_dir}; continue with --resume", file=stream)
        raise
    return run_dir


def evaluate(
    run_dir: str | Path,
    seeds: int = 10,
    num_envs: int | None = None,
    checkpoint: str = CHECKPOINT,
    max_steps: int | None = None,
    stream=sys.stdout,
) -> dict:
    """Deterministic-policy returns of the first episode of every env, over ``seeds`` eval seeds."""
    run_dir = Path(run_dir)
    config = json.loads((run_dir / "config.json").read_text())
    cfg = AlgoConfig.from_dict(config["algo"])
    n = num_envs or 2 * cfg.num_envs
    results = {}
    for name in (INIT_CHECKPOINT, checkpoint):
        per_seed = []
        for i in range(seeds):
            eval_seed = 10_000 + i  # disjoint from training seeds
            torch.manual_seed(eval_seed)
            env = make_env(config["task"], config["backend"], n, config["device"], eval_seed, cfg.horizon)
            algo = FirstOrderActorCritic(cfg, env.obs_dim, env.action_dim)
            load_checkpoint(run_dir / name, algo)
            obs = env.reset()
            first_return = torch.full((n,), float("nan"))
            first_length = torch.zeros(n, dtype=torch.long)
            limit = max_steps or env.episode_length
            with torch.no_grad():
                for _ in range(limit):
                    step = env.step(algo.act(obs, deterministic=True))
                    newly = step.done & torch.isnan(first_return)
                    first_return[newly] = step.episode_return[newly]
                    first_length[newly] = step.episode_length[newly]
                    obs = step.obs
                    if not torch.isnan(first_return).any():
                        break
            unfinished = torch.isnan(first_return)  # only when max_steps cut the episodes short
            first_return[unfinished] = env.returns[unfinished]
            first_length[unfinished] = env.steps[unfinished]
            per_seed.append(
                {
                    "seed": eval_seed,
                    "mean_return": float(first_return.mean()),
                    "mean_length": float(first_length.float().mean()),
                }
            )
            print(f"  {name}: eval seed {eval_seed}: return {per_seed[-1]['mean_return']:.1f}", file=stream, flush=True)
        means = torch.tensor([s["mean_return"] for s in per_seed])
        results["initial" if name == INIT_CHECKPOINT else "final"] = {
            "mean_return": float(means.mean()),
            "std_over_seeds": float(means.std()) if len(means) > 1 else 0.0,
            "per_seed": per_seed,
        }
    payload = {"num_envs": n, "seeds": seeds, "deterministic": True, **results, "provenance": provenance()}
    write_json(run_dir / "eval.json", payload)
    return payload
