"""A run folder checked before anything in it is used, and nothing in it written until the check passes.

Three layers, each refusing with one :class:`~harness.results.RunError` line (the CLI's exit 2):

* :func:`read_config`: ``config.json`` parses and every field has its type and range. Enough for a
  report, which reads runs made on other machines, with engines or devices this one may lack.
* :func:`check_here`: this machine can run it: its task, physics preset and backend are installed,
  its backend options are accepted, its device exists.
* :func:`read_checkpoint` with the config: the checkpoint belongs to this run. Checkpoints record the
  run they were written for (task, backend, seed, algorithm, env count and horizon); for every
  checkpoint, the networks must have the shapes this config builds for its task, and the saved env
  state one row per configured env.

:func:`open_run` does all three for the verbs that load a policy: ``eval``, ``train --resume``,
``landscape``, ``grad-growth``, ``render`` (and the bench's jobs through them).
"""

from __future__ import annotations

import json
from pathlib import Path

from algorithms.config import REMOVED_HYPERPARAMETERS, AlgoConfig
from harness.bounds import INT_MAX, MAX_EPOCHS
from harness.results import RunError

# -- the files of a run folder: every module names them through these ----------------------------------
CONFIG = "config.json"  # what the run is: task, backend, seed, physics, hyperparameters, provenance
CHECKPOINT = "checkpoint.pt"  # the latest (at the end: the final) policy, critic, optimisers and env state
INIT_CHECKPOINT = "checkpoint_init.pt"  # the untrained policy, for the initial-return evaluation
METRICS = "metrics.jsonl"  # one line per finished epoch
EVALUATION = "eval.json"  # the initial and final policies evaluated on the training engine
JOB = "job.json"  # the suite's plan of the run (bench-run reads it)
LANDSCAPE = "landscape.json"  # the final policy's actor-loss landscape (Fig. 3)
STEP_GAIN = "step_gain.json"  # the per-step Jacobian gain along the final policy (Proposition 1)
#: an evaluation on another engine (sim-to-sim) is ``sim2sim_on_<engine>.json``; the suite also writes
#: one for the training engine with the same protocol, as the comparison's reference
ON_ENGINE = "sim2sim_on_"
#: the same, as ``eval --backend`` named it before there was one name; read, never written
OLDER_ON_ENGINE = ("eval_on_",)


def evaluation_file(backend: str, trained_on: str) -> str:
    """Where ``eval`` writes by default: :data:`EVALUATION` on the training engine, else the
    evaluation on another engine (:data:`ON_ENGINE`)."""
    return EVALUATION if backend == trained_on else f"{ON_ENGINE}{backend}.json"


def engine_evaluations(run_dir: Path) -> list[tuple[str, str, Path]]:
    """Every evaluation on a named engine in ``run_dir``: (prefix, engine, path), older names included."""
    found = []
    for prefix in (ON_ENGINE, *OLDER_ON_ENGINE):
        for path in sorted(Path(run_dir).glob(f"{prefix}*.json")):
            found.append((prefix, path.stem[len(prefix) :], path))
    return found


IDENTITY = ("task", "backend", "seed", "algo", "num_envs", "horizon")  # what a checkpoint records of its run


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _config_problem(config: dict) -> str | None:
    """The first field of a parsed config.json that has the wrong type or range, as a phrase."""
    for key in ("task", "backend", "seed", "device", "epochs", "algo"):
        if key not in config:
            return f"it has no {key!r}"
    for key in ("task", "backend", "device"):
        if not isinstance(config[key], str) or not config[key]:
            return f"{key} is {config[key]!r}, not a name"
    if not _is_int(config["seed"]) or not 0 <= config["seed"] <= INT_MAX:
        return f"seed is {config['seed']!r}, not an integer in [0, {INT_MAX}]"
    if not _is_int(config["epochs"]) or not 1 <= config["epochs"] <= MAX_EPOCHS:
        return f"epochs is {config['epochs']!r}, not an integer in [1, {MAX_EPOCHS}]"
    if config.get("preset") is not None and not isinstance(config["preset"], str):
        return f"preset is {config['preset']!r}, not a name"
    if not isinstance(config.get("backend_options") or {}, dict):
        return f"backend_options is {config['backend_options']!r}, not a table"
    if not isinstance(config["algo"], dict):
        return "algo is not a table of hyperparameters"
    return None


def read_config(run_dir: str | Path) -> dict:
    """A run's config.json with its hyperparameters as ``algo_config``, or one line saying why it cannot be used."""
    path = Path(run_dir) / CONFIG
    if not path.is_file():
        raise RunError(f"{run_dir} is not a run directory (no {CONFIG}); start a run there with train --out {run_dir}")
    try:
        config = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise RunError(f"{path} is unreadable ({exc}); start the run again in a new --out") from None
    problem = _config_problem(config) if isinstance(config, dict) else "it is not a JSON object"
    if problem is None:
        try:
            config["algo_config"] = AlgoConfig.from_dict(config["algo"])
        except (ValueError, TypeError) as exc:
            problem = f"its hyperparameters are invalid ({exc})"
    if problem is not None:
        raise RunError(f"{path}: {problem}; start the run again in a new --out")
    return config


def _version_problem(config: dict) -> str | None:
    """Whether ``config`` was written by a version whose fields differ from this one's in a way that
    changes meaning: a hyperparameter or physics constant it lacks (this version would fill a default
    the run never had) or a physics constant this version does not know. As a phrase, or None."""
    import dataclasses

    from harness.envs import physics_fields
    from simcore import PhysicsSpec

    recorded = set(config["algo"]) - REMOVED_HYPERPARAMETERS
    missing = sorted({f.name for f in dataclasses.fields(AlgoConfig)} - recorded)
    if missing:
        return f"has no hyperparameter {', '.join(missing)} (written by an older version)"
    if "preset" not in config or not isinstance(config.get("physics"), dict):
        return "records no physics preset or constants (written by an older version)"
    physics = set(physics_fields(config["physics"]))
    known = {f.name for f in dataclasses.fields(PhysicsSpec)}
    if physics - known:
        return f"has physics constant(s) {', '.join(sorted(physics - known))} this version does not know"
    if known - physics:
        return f"has no physics constant {', '.join(sorted(known - physics))} (written by an older version)"
    return None


def upgrade_notes(config: dict) -> list[str]:
    """The explicit upgrade of an older config.json that keeps its meaning, one phrase per change:
    renamed physics constants read under today's names, removed hyperparameters that were never read.
    A resume says them before it continues."""
    from harness.envs import PHYSICS_RENAMED

    notes = [
        f"physics constant {old} read as {new} (renamed)"
        for old, new in PHYSICS_RENAMED.items()
        if old in (config.get("physics") or {})
    ]
    notes += [
        f"hyperparameter {name!r} dropped (never read)"
        for name in sorted(REMOVED_HYPERPARAMETERS & set(config["algo"]))
    ]
    return notes


def check_here(config: dict, backend: str | None = None) -> None:
    """Refuse a run this machine cannot run (on ``backend``, default its own): an engine, task or
    preset that is not installed, backend options the adapter rejects, a device it lacks."""
    import backends
    import tasks
    from backends.contract import BackendError
    from harness.envs import device_problem, run_task
    from simcore import UnknownNameError
    from tasks import UnknownPresetError

    for kind, name, installed in (
        ("backend", config["backend"], backends.available()),
        ("backend", backend, backends.available()),
        ("task", config["task"], tasks.available()),
    ):
        if name is not None and name not in installed:
            raise RunError(f"{CONFIG} of this run: {UnknownNameError(kind, name, installed)}")
    problem = _version_problem(config)
    if problem:
        raise RunError(
            f"{CONFIG} of this run {problem}: filling today's defaults could change what the run is; train it again"
        )
    try:
        task = run_task(config)
    except (UnknownPresetError, TypeError, ValueError) as exc:  # a preset or constants this task does not have
        raise RunError(f"{CONFIG} of this run: {exc}") from None
    options = config.get("backend_options") or {}
    adapter = backends.get(config["backend"])
    try:
        adapter.merged_options(task, options)  # a name the adapter does not have
        adapter.gradient_settings(task, options)  # a value it does not take
    except (ValueError, BackendError) as exc:
        raise RunError(f"{CONFIG} of this run: {config['backend']} options {options}: {exc}") from None
    problem = device_problem(config["device"])
    if problem:
        raise RunError(f"{CONFIG} of this run: {problem}")


def training_complete(run_dir: Path, epochs: int) -> bool:
    """True when the run's last checkpoint is at its planned epoch count (a torn run resumes instead),
    or, for a run whose checkpoints were not kept (the store's files in git), when its metrics log every
    planned epoch: finished, though analyses that need the final policy cannot run on it again."""
    ckpt = run_dir / CHECKPOINT
    if not ckpt.is_file():
        return logged_epochs(run_dir / METRICS) >= epochs
    import torch

    try:
        return int(torch.load(ckpt, map_location="cpu", weights_only=False)["epoch"]) >= epochs
    except Exception:  # unreadable: the job's resume will say why
        return False


def logged_epochs(path: Path) -> int:
    """How many epochs ``path`` (a run's metrics.jsonl) logs: its last epoch + 1, 0 if unreadable."""
    try:
        lines = path.read_text().splitlines()
    except OSError:
        return 0
    last = -1
    for line in lines:
        try:
            last = max(last, int(json.loads(line).get("epoch", -1)))
        except (ValueError, TypeError, AttributeError):
            continue  # a torn last line
    return last + 1


def address_key(payload) -> str:
    """The 12 hex digits a run folder's name ends in: a hash of its address (:func:`address`), and the
    suite's key of any planned job."""
    import hashlib

    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:12]


def address(config: dict) -> dict:
    """What a run folder is addressed by, read from its config (:func:`read_config`): the fields that make
    the result (task, backend, seed, device, epochs, hyperparameters, physics, engine options and
    gradient settings). The suite plans the same fields (:meth:`harness.suite.bench.RunSpec.identity`) and
    refuses a folder whose address differs from its plan's."""
    recorded = {k: config[k] for k in ("task", "backend", "seed", "device", "epochs")}
    recorded["algo"] = config["algo_config"].as_dict()
    recorded["physics"] = config.get("physics_record")
    if config.get("backend_options"):
        recorded["backend_options"] = config["backend_options"]
    if config.get("gradients"):
        recorded["gradients"] = config["gradients"]
    return recorded


def run_identity(config: dict) -> dict:
    """What a checkpoint records of the run it belongs to (:data:`IDENTITY`)."""
    cfg = config["algo_config"]
    return {
        "task": config["task"],
        "backend": config["backend"],
        "seed": config["seed"],
        "algo": cfg.algo,
        "num_envs": cfg.num_envs,
        "horizon": cfg.horizon,
    }


def _mismatch(payload: dict, config: dict) -> str | None:
    """How the checkpoint ``payload`` disagrees with ``config``, as a phrase, or None."""
    import torch

    from algorithms.actor_critic import FirstOrderActorCritic
    from harness.envs import run_task

    expected = run_identity(config)
    recorded = payload.get("run") or {}
    for key in IDENTITY:
        if key in recorded and recorded[key] != expected[key]:
            return f"it was written for {key} {recorded[key]!r}, {CONFIG} says {expected[key]!r}"
    task = run_task(config)
    with torch.random.fork_rng(devices=[]):  # building the networks draws weights: the caller's stream stays
        model = FirstOrderActorCritic(config["algo_config"], task.obs_dim, task.action_dim).state_dict()
    saved = payload["algo"]
    if not isinstance(saved, dict) or set(saved) != set(model):
        return f"its networks are not the ones {CONFIG}'s algorithm builds"
    for name, tensor in model.items():
        if tuple(getattr(saved[name], "shape", ())) != tuple(tensor.shape):
            return (
                f"its {name} has shape {tuple(saved[name].shape)}, {CONFIG}'s {config['task']} "
                f"({task.obs_dim} observations, {task.action_dim} actions) builds {tuple(tensor.shape)}"
            )
    env = payload.get("env")
    if env is not None:
        rows = getattr(env.get("prev_actions"), "shape", (None,))[0]
        if rows != config["algo_config"].num_envs:
            return f"its env state has {rows} envs, {CONFIG} says {config['algo_config'].num_envs}"
    return None


def read_checkpoint(path: Path, config: dict | None = None) -> dict:
    """A checkpoint's contents, refused in one line if torn or foreign, or (given the run's ``config``)
    written for another run than the one its folder's config.json describes."""
    import torch

    try:
        payload = torch.load(path, map_location="cpu", weights_only=False)
        if not isinstance(payload, dict) or not {"algo", "optimizers", "epoch", "rng", "progress"} <= set(payload):
            raise ValueError("not a diffsim-bench checkpoint")
    except Exception as exc:  # torch raises assorted types for torn or foreign files
        detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise RunError(
            f"{path} is unreadable ({detail[:120]}); it was not written by a finished checkpoint: "
            "start the run again in a new --out"
        ) from None
    problem = _mismatch(payload, config) if config is not None else None
    if problem:
        raise RunError(f"{path} does not belong to this run: {problem}; start the run again in a new --out")
    return payload


def open_run(run_dir: str | Path, checkpoints: tuple[str, ...] = (CHECKPOINT,), backend: str | None = None) -> dict:
    """The config of a run about to be loaded, after every check: config.json's fields, this machine
    (and ``backend``, for a policy moved to another engine), and each of ``checkpoints``, which must exist."""
    run_dir = Path(run_dir)
    config = read_config(run_dir)
    check_here(config, backend)
    for name in checkpoints:
        if not (run_dir / name).is_file():
            raise RunError(f"{run_dir} has no {name} yet: train (or --resume) it first")
        read_checkpoint(run_dir / name, config)
    return config
