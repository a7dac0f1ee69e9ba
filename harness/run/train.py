"""Training and evaluation runs: configs, metrics files, checkpoints, resume, evaluation.

A run directory holds:

* ``config.json``: every hyperparameter, the task/backend/seed/device, the physics constants and
  the command; written first, before anything slow, so that from then on the folder is resumable.
* ``checkpoint_init.pt``: the initial policy and env state (the evaluation baseline, and the epoch-0
  checkpoint a run resumes from if it was stopped before its first epoch ended).
* ``metrics.jsonl``: one JSON object per epoch (flushed as written).
* ``checkpoint.pt``: algorithm, optimisers, env state and every random generator, taken only at an
  epoch boundary (every ``checkpoint_every`` epochs, default 1), written atomically (temporary file,
  fsync, rename), never with non-finite weights.
* ``eval.json``: written by :func:`evaluate`.

Interruptions. SIGINT (Ctrl-C) or SIGTERM: the current epoch finishes, a checkpoint is taken at
that boundary and the process exits (130 / 143); a second signal stops at once, and the folder
resumes from the last boundary checkpoint. SIGKILL (or a crash) at any moment, including during a
write, leaves the last complete checkpoint and at most a torn last metrics line. ``resume`` continues
from ``checkpoint.pt``, else from ``checkpoint_init.pt``, else from scratch with ``config.json``; it
drops metric rows written after that checkpoint (and a torn last line), and restores the env state
and every random generator, so the continuation is the same run: its metrics equal an
uninterrupted run's (wall-time fields aside; tested by killing real processes).
"""

from __future__ import annotations

import dataclasses
import json
import os
import random
import signal
import sys
import time
from pathlib import Path

import torch

import backends
from algorithms.actor_critic import FirstOrderActorCritic
from algorithms.config import AlgoConfig
from backends.contract import BackendError
from harness.envs import make_env, run_task
from harness.progress import ProgressLine, duration
from harness.results import (
    RunError,
    RunStopped,
    atomic_write_text,
    out_problem,
    provenance,
    read_metrics,
    slow_write_for_tests,
    write_json,
)
from harness.run.folder import (
    CHECKPOINT,
    CONFIG,
    EVALUATION,
    INIT_CHECKPOINT,
    JOB,
    METRICS,
    address,
    address_key,
    check_here,
    evaluation_file,
    open_run,
    read_checkpoint,
    read_config,
    run_identity,
    training_complete,
    upgrade_notes,
)
from harness.run.folder_claims import process_alive
from harness.run.tensorboard import FOLDER as TENSORBOARD_FOLDER
from harness.run.tensorboard import EpochScalars

# metrics that measure time, not the run: everything else is equal between a resumed and an uninterrupted run
WALL_TIME_FIELDS = (
    "wall_s",
    "epoch_s",
    "sim_forward_s",
    "backward_s",
    "update_s",
    "actor_update_s",
    "lambda_update_s",
    "critic_update_s",
)


def _rng_state() -> dict:
    return {"torch": torch.get_rng_state(), "python": random.getstate()}


def _set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    random.setstate(state["python"])


def save_checkpoint(path: Path, algo: FirstOrderActorCritic, env, progress: dict, run: dict | None = None) -> None:
    """Write a checkpoint atomically: temporary file, fsync, rename (a kill leaves the old one intact).
    ``run``: what it records of the run it belongs to (:func:`harness.run.folder.run_identity`)."""
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
        "run": run,
    }
    # a name of this writer's own: a worker presumed dead (run/folder_claims.py) never shares a half-written file
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    with tmp.open("wb") as fh:
        torch.save(payload, fh)
        fh.flush()
        os.fsync(fh.fileno())
    slow_write_for_tests()
    os.replace(tmp, path)


def load_checkpoint(path: Path, algo: FirstOrderActorCritic, env=None) -> dict:
    """Load a checkpoint into ``algo`` (and ``env``); check it against its run first (:func:`open_run`)."""
    return _apply_checkpoint(read_checkpoint(path), algo, env)


def _apply_checkpoint(payload: dict, algo: FirstOrderActorCritic, env=None) -> dict:
    algo.load_state_dict(payload["algo"])
    for name, state in payload["optimizers"].items():
        getattr(algo, name).load_state_dict(state)
    algo.epoch = payload["epoch"]
    if env is not None and payload["env"] is not None:
        env.load_state_dict(payload["env"])
    if env is not None:
        _set_rng_state(payload["rng"])
    return payload["progress"]


class _EpochProgress:
    """Training's progress bar: epochs done, return, lambda, rate and ETA (:class:`harness.progress.ProgressLine`)."""

    def __init__(self, total: int, start: int, stream=None):
        stream = stream or sys.stdout  # the stdout of now, not of import time
        self.total, self.start = total, start
        self.line = ProgressLine(stream, every=max(1, total // 20))
        self.t0 = time.perf_counter()

    def update(self, epoch: int, row: dict) -> None:
        done = epoch + 1
        ret = row.get("train_episode_return_avg")
        ret_s = f"{ret:8.1f}" if ret is not None else "     n/a"
        rate = (done - self.start) / max(time.perf_counter() - self.t0, 1e-9)
        eta = (self.total - done) / rate if rate > 0 else float("nan")
        width = 24
        filled = int(width * done / self.total)
        self.line.show(
            f"[{'#' * filled}{'.' * (width - filled)}] epoch {done}/{self.total} "
            f"return {ret_s}  lambda {row['lam']:.3f}  {rate:.2f} ep/s  eta {duration(eta) if eta == eta else 'n/a'}",
            final=done == self.total,
        )


def _append_metrics(path: Path, row: dict) -> None:
    line = json.dumps(row) + "\n"
    with path.open("a") as fh:
        half = len(line) // 2
        fh.write(line[:half])
        fh.flush()
        slow_write_for_tests()  # tests widen the window in which a kill tears the line
        fh.write(line[half:])
        fh.flush()


def _truncate_metrics(path: Path, before_epoch: int) -> None:
    """Keep only rows of epochs before ``before_epoch`` (later ones are re-run); drop a torn last line."""
    if not path.exists():
        return
    keep = [row for row in read_metrics(path) if row.get("epoch", before_epoch) < before_epoch]
    atomic_write_text(path, "".join(json.dumps(row) + "\n" for row in keep))


class _SignalStop:
    """SIGINT/SIGTERM: finish the epoch, checkpoint, stop. A second signal stops at once."""

    def __init__(self, stream):
        self.signum: int | None = None
        self.stream = stream
        self.previous: dict = {}

    def __enter__(self):
        for signum in (signal.SIGINT, signal.SIGTERM):
            try:
                self.previous[signum] = signal.signal(signum, self._handle)
            except ValueError:  # not the main thread: leave signals alone
                pass
        return self

    def _handle(self, signum, frame):
        if self.signum is not None:
            raise KeyboardInterrupt
        self.signum = signum
        name = signal.Signals(signum).name
        print(f"\n{name}: finishing this epoch, then checkpoint and stop (again to stop now)", file=self.stream)

    def __exit__(self, *exc):
        for signum, handler in self.previous.items():
            signal.signal(signum, handler)
        return False


def check_output_dir(out: str | Path) -> Path:
    """Refuse an output path that cannot hold a new run, before any work starts (one-line RunError)."""
    problem = out_problem(out, "folder")
    if problem:
        raise RunError(problem)
    path = Path(out)
    if (path / CONFIG).exists():
        raise RunError(f"{out} already holds a run; continue it with --resume {out} or choose another --out")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RunError(f"--out {out}: cannot create it ({exc.strerror})") from None
    return path


def train(
    run_dir: str | Path,
    task: str,
    backend: str,
    algo_config: AlgoConfig,
    epochs: int,
    seed: int = 0,
    device: str = "cpu",
    checkpoint_every: int = 1,
    command: str | None = None,
    stream=None,
    preset: str | None = None,
    backend_options: dict[str, object] | None = None,
) -> Path:
    """Start a new run in ``run_dir`` (which must not hold one) and train it for ``epochs`` epochs on the
    task's physics ``preset`` (its default when ``None``), the adapter built with ``backend_options``
    (``--backend-option``: finite-difference scheme and steps, for example; recorded, and kept on resume)."""
    stream = stream or sys.stdout  # the stdout of now, not of import time
    run_dir = check_output_dir(run_dir)
    algo_config = algo_config.replace(max_epochs=algo_config.max_epochs or epochs)
    config = {
        "task": task,
        "backend": backend,
        "seed": seed,
        "device": device,
        "epochs": epochs,
        "algo": algo_config.as_dict(),
        "preset": preset,
        "provenance": provenance(command),
    }
    if backend_options:
        config["backend_options"] = {str(k): v for k, v in backend_options.items()}
    return _run(run_dir, config, algo_config, checkpoint_every=checkpoint_every, stream=stream)


def resume(
    run_dir: str | Path,
    epochs: int | None = None,
    checkpoint_every: int = 1,
    command: str | None = None,
    stream=None,
) -> Path:
    """Continue the run in ``run_dir`` from its last checkpoint, up to ``epochs`` in total (default: as planned)."""
    stream = stream or sys.stdout  # the stdout of now, not of import time
    run_dir = Path(run_dir)
    config = read_config(run_dir)
    check_here(config)
    if epochs is not None and epochs < config["epochs"]:
        raise RunError(f"--epochs {epochs} is fewer than the run's planned {config['epochs']}; give a larger total")
    # a torn, foreign or unreadable checkpoint or metrics file is refused before anything is written
    source = _resume_source(run_dir, config)
    for note in upgrade_notes(config):
        print(f"{run_dir.name}: {CONFIG} was written by an older version: {note}", file=stream, flush=True)
    algo_config = config.pop("algo_config")
    read_metrics(run_dir / METRICS)
    _remove_stale_checkpoint_temps(run_dir, stream)
    config["epochs"] = epochs or config["epochs"]
    config.setdefault("resumed", []).append(provenance(command))  # the original command stays
    return _run(run_dir, config, algo_config, checkpoint_every=checkpoint_every, stream=stream, source=source)


def _remove_stale_checkpoint_temps(run_dir: Path, stream) -> None:
    """Remove the temporary files of checkpoint writes whose writer is gone (a SIGKILL mid-write leaves
    ``NAME.PID.tmp`` behind; the checkpoint it was replacing is intact)."""
    for tmp in run_dir.glob("*.pt.*.tmp"):
        pid = tmp.name.rsplit(".", 2)[-2]
        if pid.isdigit() and not process_alive(int(pid)):
            tmp.unlink(missing_ok=True)
            print(f"removed {tmp.name}: a checkpoint write that was interrupted", file=stream, flush=True)


def _resume_source(run_dir: Path, config: dict) -> tuple[Path, dict] | None:
    """The checkpoint a resume starts from and its contents: checkpoint.pt, else checkpoint_init.pt,
    else None (from scratch)."""
    for name in (CHECKPOINT, INIT_CHECKPOINT):
        path = run_dir / name
        if path.exists():
            return path, read_checkpoint(path, config)
    return None


def _record_physics(run_dir: Path, config: dict, task_spec, resuming: bool) -> None:
    """Write the physics and the gradient settings a run is made with into ``config``; on a resume,
    refuse when this installation would make either differently (the run would change meaning)."""
    task, backend = config["task"], config["backend"]
    config.setdefault("physics", dataclasses.asdict(task_spec.physics))
    current = json.loads(json.dumps(task_spec.physics_record()))  # as config.json holds it
    if resuming and config.get("physics_record") != current:
        made = (config.get("physics_record") or {}).get("preset", "a physics from before physics presets")
        raise RunError(
            f"{run_dir} was made with {made}, task {task!r} now runs preset {current['preset']} "
            f"({current['backend_options'] or 'no engine settings'}): continuing would change the physics "
            "mid-run; start a new run"
        )
    config["physics_record"] = current
    options = config.get("backend_options") or {}
    try:
        gradients = json.loads(json.dumps(backends.get(backend).gradient_settings(task_spec, options)))
    except ValueError as exc:  # a bad --backend-option value
        raise RunError(f"{backend} options {options}: {exc}") from None
    if resuming and config.get("gradients", {}).get(backend, gradients) != gradients:
        raise RunError(
            f"{run_dir} was trained with {backend} gradient settings {config['gradients'][backend]}, this "
            f"installation makes {gradients}: continuing would change the gradients mid-run; start a new run"
        )
    if gradients:
        config["gradients"] = {backend: gradients}


def _print_cost(env, backend: str, horizon: int, epochs_to_go: int, stream) -> None:
    """Finite-difference gradients: say what this run will cost before it starts."""
    cost = env.sim.gradient_step_cost()
    if cost is None:
        return
    per_epoch = cost["seconds_per_step"] * horizon
    print(
        f"cost estimate ({backend}, measured on {cost['sample_worlds']} worlds in {cost['sample_seconds']:.1f} s): "
        f"{duration(cost['seconds_per_step'])} per control step with gradients "
        f"({cost['worlds_per_step']} worlds), "
        f"{duration(per_epoch)} per epoch of {horizon} steps, "
        f"{duration(per_epoch * epochs_to_go)} for the {epochs_to_go} epochs to go (simulation only)",
        file=stream,
        flush=True,
    )


def _epoch_row(algo, progress: dict, metrics: dict, elapsed: float) -> dict:
    """Count an epoch into ``progress`` and return its metrics.jsonl row."""
    progress["env_steps"] += algo.cfg.num_envs * algo.cfg.horizon
    progress["wall_s"] += elapsed
    recent = (progress["recent_returns"] + [metrics["train_episode_return"]])[-20:]
    progress["recent_returns"] = [r for r in recent if r is not None]
    returns = progress["recent_returns"]
    return {
        "epoch": algo.epoch - 1,
        "env_steps": progress["env_steps"],
        "wall_s": progress["wall_s"],
        "epoch_s": elapsed,
        **metrics,
        "train_episode_return_avg": sum(returns) / len(returns) if returns else None,
    }


def _epochs(run_dir, algo, env, progress, identity, epochs, checkpoint_every, stop, stream) -> None:
    """The training loop: epochs until ``epochs`` or a signal, each row to metrics.jsonl, TensorBoard and
    the progress line, a checkpoint every ``checkpoint_every`` epochs, at the end and at a signal."""
    from backends.contract import NonFiniteStateError

    bar = _EpochProgress(epochs, algo.epoch, stream)
    scalars = EpochScalars(run_dir, algo.epoch)  # TensorBoard's view of metrics.jsonl
    try:
        while algo.epoch < epochs and stop.signum is None:
            start = time.perf_counter()
            try:
                metrics = algo.train_epoch(env)
            except NonFiniteStateError as exc:  # the simulation blew up: log it, restart episodes
                progress["nonfinite_events"] += 1
                print(f"\nwarning: epoch {algo.epoch}: {exc}; resetting all envs", file=stream, flush=True)
                env.reset()
                continue
            row = _epoch_row(algo, progress, metrics, time.perf_counter() - start)
            _append_metrics(run_dir / METRICS, row)
            scalars.write(row)
            bar.update(algo.epoch - 1, row)
            if algo.epoch % checkpoint_every == 0 or algo.epoch == epochs or stop.signum is not None:
                save_checkpoint(run_dir / CHECKPOINT, algo, env, progress, identity)
    except KeyboardInterrupt:  # a second signal mid-epoch: no checkpoint of a half-done epoch
        print(f"\nstopped now: {run_dir} resumes from its last checkpoint with --resume", file=stream)
        raise
    finally:
        scalars.close()


def _run(
    run_dir: Path,
    config: dict,
    algo_config: AlgoConfig,
    checkpoint_every: int,
    stream,
    source: tuple[Path, dict] | None = None,
) -> Path:
    """Train from ``source`` (a resume's checkpoint path and contents), or from the start if None."""
    from tasks import make_task

    task, backend, seed, device, epochs = (config[k] for k in ("task", "backend", "seed", "device", "epochs"))
    config_path, metrics_path = run_dir / CONFIG, run_dir / METRICS
    task_spec = make_task(task, preset=config.get("preset"))
    _record_physics(run_dir, config, task_spec, resuming=source is not None)
    options = config.get("backend_options") or {}
    torch.manual_seed(seed)
    random.seed(seed)
    # the adapter before config.json: a bad --backend-option is refused with nothing written
    try:
        env = make_env(task_spec, backend, algo_config.num_envs, device, seed, algo_config.horizon, options=options)
    except (ValueError, TypeError, BackendError) as exc:
        raise RunError(f"cannot build {backend}/{task} with options {options}: {exc}") from None
    write_json(config_path, config)  # from here on the folder is resumable
    identity = run_identity({**config, "algo_config": algo_config})
    algo = FirstOrderActorCritic(algo_config, env.obs_dim, env.action_dim)
    progress = {"env_steps": 0, "wall_s": 0.0, "recent_returns": [], "nonfinite_events": 0}
    if source is None:
        env.reset()
        save_checkpoint(run_dir / INIT_CHECKPOINT, algo, env, progress, identity)
        _truncate_metrics(metrics_path, 0)
    else:
        path, payload = source
        progress = _apply_checkpoint(payload, algo, env)
        _truncate_metrics(metrics_path, algo.epoch)
        print(f"resuming {run_dir} at epoch {algo.epoch}/{epochs} from {path.name}", file=stream, flush=True)
    _print_cost(env, backend, algo_config.horizon, epochs - algo.epoch, stream)
    with _SignalStop(stream) as stop:
        _epochs(run_dir, algo, env, progress, identity, epochs, checkpoint_every, stop, stream)
    if stop.signum is not None and algo.epoch < epochs:
        raise RunStopped(run_dir, algo.epoch, stop.signum)
    paths = (config_path, metrics_path, run_dir / CHECKPOINT, run_dir / INIT_CHECKPOINT)
    names = [p.name for p in paths if p.exists()]
    names.append(f"{TENSORBOARD_FOLDER}/ (tensorboard --logdir {run_dir})")
    print(f"wrote {run_dir}: {', '.join(names)}", file=stream, flush=True)
    return run_dir


def evaluate(
    run_dir: str | Path,
    seeds: int = 10,
    num_envs: int | None = None,
    checkpoint: str = CHECKPOINT,
    max_steps: int | None = None,
    stream=None,
    backend: str | None = None,
    out: str | Path | None = None,
) -> dict:
    """Deterministic-policy returns of the first episode of every env, over ``seeds`` eval seeds.

    ``backend``: evaluate on another engine than the run trained on (sim-to-sim: the same task, eval
    protocol and policy; the observation statistics travel with the checkpoint). Written to
    ``sim2sim_on_<backend>.json`` instead of ``eval.json``, unless ``out`` names the file.
    """
    stream = stream or sys.stdout  # the stdout of now, not of import time
    run_dir = Path(run_dir)
    config = open_run(run_dir, (INIT_CHECKPOINT, checkpoint), backend)
    cfg = config["algo_config"]
    trained_on = config["backend"]
    backend = backend or trained_on
    n = num_envs or 2 * cfg.num_envs
    results = {}
    line, total, t0 = ProgressLine(stream), 2 * seeds, time.perf_counter()
    for k, name in enumerate((INIT_CHECKPOINT, checkpoint)):
        per_seed = []
        for i in range(seeds):
            eval_seed = 10_000 + i  # disjoint from training seeds
            torch.manual_seed(eval_seed)
            # the run's adapter options on its own engine (another engine has options of its own)
            options = config.get("backend_options") if backend == trained_on else None
            env = make_env(run_task(config), backend, n, config["device"], eval_seed, cfg.horizon, options=options)
            algo = FirstOrderActorCritic(cfg, env.obs_dim, env.action_dim)
            load_checkpoint(run_dir / name, algo)
            evaluated_epoch = algo.epoch  # the final policy's: a later resume makes this evaluation stale
            obs = env.reset()
            first_return = torch.full((n,), float("nan"))
            first_length = torch.zeros(n, dtype=torch.long)
            # the forward velocity at the start of every step of the first episode: never a reset state's
            forward_sum, has_forward = torch.zeros(n, dtype=torch.float64), False
            limit = max_steps or env.episode_length
            with torch.no_grad():
                for _ in range(limit):
                    velocity = env.task.forward_velocity(env.sim.state)
                    if velocity is not None:
                        forward_sum += torch.where(torch.isnan(first_return), velocity.double().cpu(), 0.0)
                        has_forward = True
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
            if has_forward:
                per_seed[-1]["mean_forward_velocity"] = float((forward_sum / first_length.clamp(min=1)).mean())
            done = k * seeds + i + 1
            elapsed = time.perf_counter() - t0
            line.show(
                f"  eval {done}/{total} ({name}, seed {eval_seed}): return {per_seed[-1]['mean_return']:.1f}"
                f" · elapsed {duration(elapsed)} · ETA {duration(elapsed / done * (total - done))}",
                final=done == total,
            )
        means = torch.tensor([s["mean_return"] for s in per_seed])
        block = {
            "mean_return": float(means.mean()),
            "std_over_seeds": float(means.std()) if len(means) > 1 else 0.0,
            "per_seed": per_seed,
        }
        if "mean_forward_velocity" in per_seed[0]:  # m/s along +x, each env's first-episode mean
            block["mean_forward_velocity"] = sum(s["mean_forward_velocity"] for s in per_seed) / len(per_seed)
        results["initial" if name == INIT_CHECKPOINT else "final"] = block
    payload = {
        "num_envs": n,
        "seeds": seeds,
        "deterministic": True,
        "max_steps": max_steps,
        "backend": backend,
        "trained_on": trained_on,
        "policy_epoch": evaluated_epoch,
        **results,
        "provenance": provenance(),
    }
    written = write_json(Path(out) if out else run_dir / evaluation_file(backend, trained_on), payload)
    print(f"wrote {written}", file=stream, flush=True)
    return payload


def job_problem(job) -> str | None:
    """What a job.json lacks to be run, as a phrase, or None."""
    if not isinstance(job, dict):
        return "not a JSON object"
    missing = [k for k in ("task", "backend", "seed", "device", "epochs", "algo", "eval", "key") if k not in job]
    if missing:
        return f"it has no {', '.join(missing)}"
    if not isinstance(job["eval"], dict) or any(k not in job["eval"] for k in ("seeds", "num_envs", "max_steps")):
        return "its eval is not a table of seeds, num_envs and max_steps"
    return None


def _evaluated(run_dir: Path, ev: dict) -> bool:
    """Whether eval.json holds the evaluation ``ev`` plans."""
    try:
        payload = json.loads((run_dir / EVALUATION).read_text())
    except (OSError, ValueError):
        return False
    expect = {"seeds": ev["seeds"], "max_steps": ev["max_steps"]} | (
        {"num_envs": ev["num_envs"]} if ev["num_envs"] else {}
    )
    return all(payload.get(k) == v for k, v in expect.items())


def train_planned(run_dir: Path, job: dict, stream) -> None:
    """The per-run part of ``bench-run``: train the run the suite planned (``job``, its job.json), or
    resume it, unless another worker finished it, then evaluate it as planned. A config.json that is
    not the planned run's is refused rather than continued."""
    problem = job_problem(job)
    if problem:
        raise RunError(f"{run_dir / JOB}: {problem}; plan the run again with bench")
    ev = job["eval"]
    if training_complete(run_dir, job["epochs"]) and (not ev["seeds"] or _evaluated(run_dir, ev)):
        print(f"{run_dir.name}: already finished (by another worker)", file=stream, flush=True)
        return
    if (run_dir / CONFIG).is_file():
        config = read_config(run_dir)
        if address_key(address(config)) != job["key"]:
            raise RunError(f"{run_dir}: config.json does not match the planned run (job.json): move the folder away")
        if not training_complete(run_dir, job["epochs"]):
            resume(run_dir, command="python -m harness bench-run " + str(run_dir), stream=stream)
    else:
        cfg = AlgoConfig.from_dict(job["algo"])
        train(
            run_dir,
            job["task"],
            job["backend"],
            cfg,
            job["epochs"],
            seed=job["seed"],
            device=job["device"],
            command="python -m harness bench-run " + str(run_dir),
            stream=stream,
            preset=job.get("preset"),  # None: the task's default
            backend_options=job.get("backend_options"),
        )
    if ev["seeds"]:
        evaluate(run_dir, seeds=ev["seeds"], num_envs=ev["num_envs"], max_steps=ev["max_steps"], stream=stream)
