"""The benchmark suite: one declarative grid of checks, training runs and analyses, then tables and plots.

``python -m harness bench --profile smoke|standard|paper`` (the profiles are TOML files in
``harness/profiles/``) or ``--spec FILE.toml`` (a user's own, same format). A spec names:

* ``[suite]``: ``name``, ``description``, ``jobs`` (processes at once; one per core on a CPU machine,
  since a Warp CPU kernel runs on one thread), ``device``, ``order`` (``"seed"``, the default: training
  runs start seed-major across blocks; ``"block"``: each [[train]] block's seeds before the next's);
* ``[eval]``: the evaluation protocol of every training run (``seeds``, optional ``num_envs``, default
  2N, and ``max_steps``);
* ``[[train]]``: a grid ``backends x tasks x algos x seeds x horizons`` with ``epochs``, ``num_envs``,
  an optional physics ``preset`` (a name from ``harness list``; default: each task's own) and any
  AlgoConfig field under ``[train.hyperparameters]``, adapter options per backend under
  ``[train.backend_options.BACKEND]`` (``--backend-option``); ``[train.per_task.TASK]`` overrides
  ``epochs``, ``num_envs``, ``horizons``, ``seeds``, ``preset`` or hyperparameters for one task, and
  ``[train.eval]`` the evaluation protocol for the block (``seeds = 0``: no evaluation); ``sequential =
  true``: the block's ``seeds`` are the most the pre-registered group-sequential design
  (:mod:`harness.report.sequential`) may use, and the suite plans the first as many of them as the design
  wants for each algorithm's claims (5 before the first look, 10 where a claim continues), and every run
  already started (:func:`_sequential_design`);
* ``[[check]]``: ``kind`` (gradcheck, throughput, crosscheck, parity, contact-jacobians, grad-paths, and
  the performance kinds scaling, fd-schemes, solver-probe and peer), ``backends`` (for ``peer``: the
  peer simulators, ``rewarped``), ``tasks`` and the verb's extra ``args`` (a list of command-line
  words), optionally ``[check.per_task.TASK]`` with ``args``;
* ``[[sim_to_sim]]``: runs of the train grid (``task``, ``train_backend``, ``algos``, ``seeds``,
  ``horizon``, ``preset``, and ``epochs``/``train_num_envs`` where two train blocks share the rest;
  runs built with adapter options only when ``backend_options`` names them)
  evaluated on ``train_backend`` and ``eval_backend`` with one protocol (``eval_seeds``, ``num_envs``,
  ``max_steps``);
* ``[[landscape]]``: runs of the grid (selected as for sim-to-sim, ``backend`` for ``train_backend``)
  whose h-step and TD-lambda actor losses are mapped over a ``grid`` x ``grid`` plane (``span``,
  ``num_envs``);
* ``[[step_gain]]``: runs of the grid (selected as for a landscape) whose one-step Jacobian gains are
  measured along their final policy (``states``, ``stride``, ``num_envs``; Proposition 1,
  :mod:`harness.checks.step_gain`);
* analysis blocks select runs without hyperparameters unless they name the runs' ``hyperparameters``
  (an ablation's), and skip, with a line, finished runs whose final checkpoint was not kept;
* ``[[render]]``: runs of the grid (selected as for a landscape) whose final policy is rendered
  (``max_steps``, ``frames``, ``compare`` for both engines side by side): a video and a filmstrip in the
  run's folder, the filmstrips shown in the report's index.

Layout: ``STORE/NAME/`` (``--store``, default ``results/bench``; NAME is the spec's ``[suite] name``)
holds the tables and plots, ``runs/``, ``checks/`` and ``logs/``. Give two specs the same name (or
the same ``--store``) to share runs between them.

Content addressing. A training run's directory is named by its task, backend, algorithm, horizon,
seed and a hash of its full configuration (task, backend, seed, device, epochs, every
hyperparameter and the physics record: preset, constants, engine settings):
``runs/ant_newton_shac_h32_s0_3f2a9c1b7d0e``, ``runs/ant.rewarped_newton_shac_h32_s0_...`` for a
preset other than the task's default. The same configuration in any spec,
profile or session lands in the same directory, so a finished run is reused, an interrupted one
resumed from its last checkpoint (``train --resume`` semantics), and none is ever computed twice. A run
finished on another device (``bench --device cuda`` on a GPU machine, into the same store) stands in for
the same configuration on this one: it is reused, and its provenance says where it ran.
Checks and analyses are addressed the same way by their command line. How the jobs run (their
own processes, logs, failures, Ctrl-C): :mod:`harness.suite.runner`.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import sys
import tomllib
from pathlib import Path

from harness.checks.kinds import KINDS
from harness.checks.peers import PEERS
from harness.results import RunError
from harness.run.folder import (
    CHECKPOINT,
    CONFIG,
    EVALUATION,
    JOB,
    LANDSCAPE,
    METRICS,
    ON_ENGINE,
    STEP_GAIN,
    address_key,
    logged_epochs,
    training_complete,
)

PROFILES_DIR = Path(__file__).resolve().parents[1] / "profiles"

# The first ETA's seconds per env step where an adapter measured nothing for a task (a plug-in's, say):
# a guess; finished jobs correct it. Adapters ship their own (backends.contract.TaskCost).
GUESS_TRAIN_S, GUESS_EVAL_S = 5e-3, 1e-4
_STARTUP_S = 12.0  # a job's process start, imports and model build (Warp kernels cached)


_hash = address_key  # every job of the suite is addressed as a run folder is


# -- the spec -------------------------------------------------------------------------------------


def _names(value, where: str) -> list:
    if isinstance(value, str | int):
        return [value]
    if not isinstance(value, list) or not value:
        raise RunError(f"{where}: expected a non-empty list")
    return value


def load_spec(profile: str | None = None, spec_file: str | None = None) -> tuple[dict, Path]:
    """The parsed TOML of a profile or a user's spec file, and where it came from (one-line errors)."""
    if (profile is None) == (spec_file is None):
        raise RunError("give exactly one of --profile NAME or --spec FILE")
    if profile is not None:
        path = PROFILES_DIR / f"{profile}.toml"
        if not path.is_file():
            known = ", ".join(sorted(p.stem for p in PROFILES_DIR.glob("*.toml")))
            raise RunError(f"unknown profile {profile!r}; choose from: {known}")
    else:
        path = Path(spec_file)
        if not path.is_file():
            raise RunError(f"--spec {spec_file}: no such file")
    try:
        data = tomllib.loads(path.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise RunError(f"{path}: not UTF-8 ({exc.reason} at byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise RunError(f"{path}: not valid TOML ({exc})") from None
    return check_spec(data, str(path)), path


def check_spec(data: dict, where: str) -> dict:
    """``data`` if every key of the spec is valid (:mod:`harness.suite.schema`, one pass, one line)."""
    from harness.suite.schema import validate_spec

    return validate_spec(data, where)


def physics_identity(task: str, preset: str | None = None) -> dict:
    """The physics record (preset, constants, engine settings) of ``task``'s ``preset`` (default: the
    task's default), as a run's config.json holds it: part of every run's and check's address, so a
    changed default is new work."""
    import tasks

    return copy.deepcopy(_physics_identity(task, preset or tasks.task_class(task).default_preset))


@functools.cache
def _physics_identity(task: str, preset: str) -> dict:
    from tasks import make_task

    return json.loads(json.dumps(make_task(task, preset=preset).physics_record()))


def _preset_suffix(args: list[str]) -> str:
    """``.PRESET`` when a check's arguments name a physics preset (two checks of a task on different
    presets keep apart labels), else ``""``."""
    return f".{args[args.index('--preset') + 1]}" if "--preset" in args[:-1] else ""


def _check_physics(args: list[str]) -> tuple[str | None, dict]:
    """The preset and adapter options a check's arguments name (``--preset P``, ``--backend-option
    K=V``): its gradients are made with them, so its address carries their gradient settings."""
    from harness.words import parse_option, physics_words

    preset, options = physics_words(args)
    return preset, dict(parse_option(text) for text in options)


def gradient_identity(backend_names, task: str, preset: str | None = None, options: dict | None = None) -> dict:
    """``{"gradients": {backend: settings}}`` for the backends whose gradients depend on settings
    (:meth:`BatchedSim.gradient_settings`; finite differences), ``{}`` when none does (exact gradients):
    part of the address of a run and of a check that differentiates, so a changed default is new work."""
    frozen = tuple(sorted((options or {}).items()))
    settings = {b: _gradient_settings(b, task, preset, frozen) for b in backend_names}
    settings = {b: s for b, s in settings.items() if s}
    return {"gradients": settings} if settings else {}


@functools.cache
def _known_preset(task: str, preset: str | None) -> None:
    """Refuse (ValueError, one line) a physics preset the task does not define."""
    from tasks import make_task

    if preset:
        make_task(task, preset=preset)


@functools.cache
def _gradient_settings(backend: str, task: str, preset: str | None, options: tuple = ()) -> dict:
    import backends
    from tasks import make_task

    settings = backends.get(backend).gradient_settings(make_task(task, preset=preset), dict(options))
    return json.loads(json.dumps(settings))


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One training run: everything that determines its result, plus how it is evaluated."""

    task: str
    backend: str
    algo: str
    seed: int
    epochs: int
    num_envs: int
    horizon: int
    device: str
    hyperparameters: tuple = ()  # sorted (field, value) pairs applied on top of the preset
    eval_seeds: int = 10
    eval_num_envs: int | None = None
    eval_max_steps: int | None = None
    preset: str | None = None  # a physics preset other than the task's default (None: the default)
    backend_options: tuple = ()  # sorted (option, value) pairs the adapter is built with (--backend-option)

    def algo_config(self):
        from algorithms.config import preset

        changes = dict(self.hyperparameters)
        changes = {k: tuple(v) if isinstance(v, list) else v for k, v in changes.items()}
        return preset(self.algo).replace(num_envs=self.num_envs, horizon=self.horizon, **changes)

    def identity(self) -> dict:
        """What the run's directory is addressed by: the fields of its config.json that make the result."""
        cfg = self.algo_config()
        cfg = cfg.replace(max_epochs=cfg.max_epochs or self.epochs)  # as train() records it
        return {
            "task": self.task,
            "backend": self.backend,
            "seed": self.seed,
            "device": self.device,
            "epochs": self.epochs,
            "algo": cfg.as_dict(),
            # the physics the run rests on (preset, constants, engine settings): a changed default is a new run
            "physics": physics_identity(self.task, self.preset),
            **gradient_identity([self.backend], self.task, self.preset, dict(self.backend_options)),
        } | ({"backend_options": dict(self.backend_options)} if self.backend_options else {})

    @property
    def key(self) -> str:
        return _hash(self.identity())

    @property
    def dirname(self) -> str:
        task = self.task if self.preset is None else f"{self.task}.{self.preset}"
        return f"{task}_{self.backend}_{self.algo}_h{self.horizon}_s{self.seed}_{self.key}"

    @property
    def env_steps(self) -> int:
        return self.epochs * self.num_envs * self.horizon

    def eval_settings(self) -> dict:
        return {"seeds": self.eval_seeds, "num_envs": self.eval_num_envs, "max_steps": self.eval_max_steps}


def _train_blocks(data: dict, device: str, known: dict) -> list[list[tuple[int, RunSpec]]]:
    """Each [[train]] block's runs, seed-major, every one with its seed's place in the block's seed list
    for its task (a sequential block plans a prefix of that list: :func:`_sequential_design`)."""
    ev = data.get("eval", {})
    blocks: list[list[tuple[int, RunSpec]]] = []
    for i, block in enumerate(data.get("train", [])):
        where = f"[[train]] #{i + 1}"
        block_eval = {**ev, **block.get("eval", {})}
        block_runs: list[tuple[int, RunSpec]] = []
        options = {b: tuple(sorted(opts.items())) for b, opts in block.get("backend_options", {}).items()}
        per_task = block.get("per_task", {})
        for backend in _names(block["backends"], f"{where} backends"):
            for task in _names(block["tasks"], f"{where} tasks"):
                merged = {**block, **per_task.get(task, {})}
                preset = _preset(task, merged.get("preset"), where)
                hyper = {**block.get("hyperparameters", {}), **per_task.get(task, {}).get("hyperparameters", {})}
                for algo in _names(block["algos"], f"{where} algos"):
                    for rank, seed in enumerate(_names(merged.get("seeds", [0]), f"{where} seeds")):
                        for horizon in _names(merged.get("horizons", [32]), f"{where} horizons"):
                            run = RunSpec(
                                task=task,
                                backend=backend,
                                algo=algo,
                                seed=int(seed),
                                epochs=int(merged["epochs"]),
                                num_envs=int(merged.get("num_envs", 64)),
                                horizon=int(horizon),
                                device=device,
                                hyperparameters=tuple(sorted(hyper.items())),
                                eval_seeds=int(block_eval.get("seeds", 10)),
                                eval_num_envs=block_eval.get("num_envs"),
                                eval_max_steps=block_eval.get("max_steps"),
                                preset=preset,
                                backend_options=options.get(backend, ()),
                            )
                            try:
                                run.algo_config()
                            except (ValueError, TypeError) as exc:
                                raise RunError(f"{where}: bad configuration for {algo} on {task}: {exc}") from None
                            block_runs.append((rank, run))
        # seed-major order: wherever a long suite stops, every algorithm has the same number of seeds
        order = {name: i for i, name in enumerate(known["algos"])}
        block_runs.sort(key=lambda pair: (pair[1].seed, pair[1].horizon, order[pair[1].algo]))
        blocks.append(block_runs)
    return blocks


def _train_grid(data: dict, blocks: list[list[tuple[int, RunSpec]]], keep=None) -> list[RunSpec]:
    """The training runs of the spec's blocks (:func:`_train_blocks`) in the order they start, each once;
    ``keep(block_index, rank, run)``, where given, says which runs of a block are planned."""
    runs: list[RunSpec] = []
    seen: set[str] = set()
    for i, block_runs in enumerate(blocks):
        for rank, run in block_runs:
            if keep is not None and not keep(i, rank, run):
                continue
            if run.key not in seen:  # the same run listed twice (two blocks) is one run
                seen.add(run.key)
                runs.append(run)
    # seed-major across blocks too (a stable sort keeps the blocks' order within a seed): wherever a long
    # suite stops, every block and algorithm has the same number of seeds and every table has rows.
    # order = "block": each block's seeds before the next block's (a suite whose first block decides)
    if data["suite"].get("order", "seed") == "seed":
        runs.sort(key=lambda r: r.seed)
    return runs


def _preset(task: str, name, where: str) -> str | None:
    """A block's preset for ``task``, checked: None for the task's default (named or not), so naming the
    default addresses the same runs as leaving it out."""
    import tasks

    cls = tasks.task_class(task)
    if name is None or name == cls.default_preset:
        return None
    _known(name, list(cls.presets), f"physics preset of {task}", where)
    return str(name)


def _known(name, names, kind: str, where: str) -> None:
    if name not in names:
        raise RunError(f"{where}: unknown {kind} {name!r}; choose from: {', '.join(names)}")


# -- jobs -------------------------------------------------------------------------------------------


@dataclasses.dataclass
class Job:
    """One process of the suite: its command, the file whose presence (and content) means done, its cost."""

    label: str
    kind: str  # train, a check's kind, sim_to_sim, landscape, step_gain, render
    argv: list[str]
    output: Path
    estimate_s: float
    cost_key: tuple = ()
    run: RunSpec | None = None
    run_dir: Path | None = None
    expect: dict = dataclasses.field(default_factory=dict)  # fields the output must hold to count as done
    after: list[str] = dataclasses.field(default_factory=list)  # labels of jobs that must finish first
    state: str = "pending"  # pending, reused, running, done, failed, skipped

    def is_done(self) -> bool:
        if not self.output.is_file():
            return False
        if self.kind == "train" and (
            damage(self.run_dir) is not None or not training_complete(self.run_dir, self.run.epochs)
        ):
            return False
        if self.output.suffix == ".jsonl":  # a run without evaluation: training complete is done
            return True
        try:
            payload = json.loads(self.output.read_text())
        except (OSError, ValueError):
            return False
        if not isinstance(payload, dict):  # whole JSON, but not a result
            return False
        if self.kind == "gradcheck" and not payload.get("result", {}).get("passed"):
            return False  # a failed check is run (and reported) again, never reused as if it passed
        return all(payload.get(k) == v for k, v in self.expect.items())


def damage(run_dir: Path) -> str | None:
    """Why the run folder's config.json cannot be used (torn, not JSON, a field out of range), or None
    where it reads or does not exist yet."""
    from harness.run.folder import read_config

    if not (run_dir / CONFIG).exists():
        return None
    try:
        read_config(run_dir)
    except RunError as exc:
        return str(exc).removesuffix("; start the run again in a new --out")
    return None


def _distinct_labels(checks: list[Job], args: list[list[str]]) -> None:
    """Checks of one kind, backend, task and preset that differ in their other words (``--with-contact``)
    get those words in their labels, so no two jobs share one."""
    counts: dict[str, int] = {}
    for job in checks:
        counts[job.label] = counts.get(job.label, 0) + 1
    for job, words in zip(checks, args, strict=True):
        if counts[job.label] > 1:
            extra = [w for k, w in enumerate(words) if w != "--preset" and (k == 0 or words[k - 1] != "--preset")]
            job.label += f" [{' '.join(extra)}]" if extra else ""


def _check_targets(kind: str, backend_names: list[str], task: str) -> list[tuple[str, list[str]]]:
    """(label backend, the verb's words naming what it checks) of each job of a check block's task."""
    if KINDS[kind].targets == "backends":
        return [("-".join(backend_names), ["--task", task, "--backends", *backend_names])]
    if KINDS[kind].targets == "simulator":  # the words name the task only
        return [(b, ["--task", task]) for b in backend_names]
    return [(b, ["--backend", b, "--task", task]) for b in backend_names]


def _harness(*words) -> list[str]:
    return [sys.executable, "-m", "harness", *[str(w) for w in words]]


def _episode(task: str, cap: int | None) -> int:
    import tasks

    return min(cap or 10**9, int(tasks.task_class(task).episode_length))


def memory_problem(jobs: list[Job], at_once: int, device: str = "cpu") -> str | None:
    """Why the training jobs cannot fit in this machine's memory ``at_once`` at a time (the largest ones
    together), as a phrase with the estimate and the limit; None when they may (harness.resources)."""
    from harness.resources import available_bytes, estimate_bytes, gib

    needs = []
    for job in jobs:
        run = job.run
        if job.kind != "train" or run is None:
            continue
        options = dict(run.backend_options)
        train = estimate_bytes(run.backend, run.task, run.num_envs, run.horizon, options=options)
        eval_envs = run.eval_num_envs or 2 * run.num_envs
        evaluation = estimate_bytes(run.backend, run.task, eval_envs, grads=False, options=options)
        if train is not None:
            needs.append((max(train, evaluation or 0.0), job.label))
    have = available_bytes(device)
    if not needs or have is None:
        return None
    top = sorted(needs, reverse=True)[: max(at_once, 1)]
    total = sum(need for need, _ in top)
    if total <= have:
        return None
    largest, label = top[0]
    together = f", the {len(top)} largest at once {gib(total)}" if len(top) > 1 else ""
    fits = int(have // largest)
    advice = f"run at most {fits} at once (--jobs {fits})" if fits >= 1 else "give it fewer envs or a shorter horizon"
    return f"{label} needs at least {gib(largest)}{together}; {device} has {gib(have)} free: {advice}"


def _check_scale(backend_names: list[str], task: str) -> float:
    """How much longer than on the reference engine a check takes on ``backend_names``: 5x where one of
    them takes over 1e-2 s per training env step (finite-difference gradients), else 1x."""
    slowest = max(_seconds_per_env_step(b, task) for b in backend_names)
    return 5.0 if slowest > 1e-2 else 1.0


def _seconds_per_env_step(backend: str, task: str, options: dict | None = None, train: bool = True) -> float:
    """The first ETA's seconds per env step of ``task`` on ``backend`` built with ``options``: training
    (with gradients) or evaluation, as the adapter measured them, else the guess."""
    from harness.resources import task_cost

    cost = task_cost(backend, task, options)
    if cost is None:
        return GUESS_TRAIN_S if train else GUESS_EVAL_S
    return cost.train_s if train else cost.eval_s


def train_job(run: RunSpec, run_dir: Path) -> Job:
    """The job that trains (or resumes) ``run`` in ``run_dir`` and evaluates it: ``bench-run RUN_DIR``. Its
    cost counts the epochs a resumed run has left, not the ones its log already holds."""
    # initial and final policy, every seed, at most one episode each
    eval_envs = run.eval_num_envs or 2 * run.num_envs
    eval_steps = 2 * run.eval_seeds * eval_envs * _episode(run.task, run.eval_max_steps)
    left = max(run.epochs - logged_epochs(run_dir / METRICS), 0) / max(run.epochs, 1)
    options = dict(run.backend_options)
    estimate = _STARTUP_S + left * run.env_steps * _seconds_per_env_step(run.backend, run.task, options)
    estimate += eval_steps * _seconds_per_env_step(run.backend, run.task, options, train=False)
    return Job(
        label=run_dir.name,
        kind="train",
        argv=_harness("bench-run", run_dir),
        output=run_dir / (EVALUATION if run.eval_seeds else METRICS),
        estimate_s=estimate,
        cost_key=("train", run.backend, run.task),
        run=run,
        run_dir=run_dir,
        expect={"seeds": run.eval_seeds, "max_steps": run.eval_max_steps}
        | ({"num_envs": run.eval_num_envs} if run.eval_num_envs else {}),
    )


def _finished_elsewhere(run: RunSpec, runs_dir: Path) -> Job | None:
    """The same configuration as ``run`` finished on another device (a GPU session's run, say), as the job
    that reuses it, or None. The device is part of a run's address (its numbers are the device's), so
    such a run lives in its own folder; the suite reuses it rather than computing the run again, and its
    config.json and eval.json say where it ran."""
    stem = run.dirname[: -len(run.key)]
    for path in sorted(runs_dir.glob(f"{stem}*/job.json")):
        try:
            device = json.loads(path.read_text())["device"]
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if not isinstance(device, str) or device == run.device:
            continue
        twin = dataclasses.replace(run, device=device)
        if path.parent.name == twin.dirname and (job := train_job(twin, path.parent)).is_done():
            return job
    return None


def _resolved(run: RunSpec, runs_dir: Path) -> Job:
    """The job of ``run``: its own folder's, or a finished twin's from another device
    (:func:`_finished_elsewhere`)."""
    job = train_job(run, runs_dir / run.dirname)
    return job if job.is_done() else _finished_elsewhere(run, runs_dir) or job


def _started(job: Job) -> bool:
    """Whether a run's folder holds anything of it: finished, in flight, or stopped and resumable."""
    return job.is_done() or any((job.run_dir / name).is_file() for name in (JOB, CONFIG, METRICS))


def _design_key(run: RunSpec) -> tuple:
    """The group the report pools ``run`` in (:attr:`harness.report.records.RunRecord.group`, labels as the
    report makes them): the key of :func:`harness.report.claims.seeds_wanted`."""
    from harness.report.records import backend_label, task_label

    task = task_label(run.task, {"physics_record": {"preset": run.preset}})
    backend = backend_label(run.backend, {"backend_options": dict(run.backend_options)})
    return (task, backend, run.num_envs, run.epochs, run.horizon, run.algo)


def _sequential_design(data: dict, blocks: list[list[tuple[int, RunSpec]]], runs_dir: Path):
    """Which runs of the spec's ``sequential = true`` blocks to plan, as ``keep(block_index, rank, run)``
    for :func:`_train_grid`, and lines that say why (one per claim the block tests, one per setting).

    The pre-registered design (:mod:`harness.report.sequential`, docs/statistics.md) decides how many seeds
    a claim gets: a sequential block's seed list is the most it may use, and seed s of an algorithm is
    planned when s is among the first n of the list, n the seeds the design wants for the algorithm's
    setting (:func:`harness.report.claims.seeds_wanted`; the first look's where none of the algorithm's
    claims has an evaluated pair yet). The design reads the evaluated runs of the spec's whole grid that
    share the block's hyperparameters (an ablation's runs, whose hyperparameters differ, are no seeds of
    the algorithm's claims). A run that has started (finished, in flight or stopped) is always planned:
    none is orphaned. The design is read when the suite is planned; runs it wants later are planned by
    the next ``bench`` of the spec."""
    from harness.report import claims as paper
    from harness.report.records import load_run
    from harness.report.sequential import LOOKS

    jobs: dict[str, Job] = {}  # run key -> its job (the first block's, as the grid keeps it)
    for block_runs in blocks:
        for _, run in block_runs:
            if run.key not in jobs:
                jobs[run.key] = _resolved(run, runs_dir)
    records = {}  # run key -> RunRecord of an evaluated run
    for key, job in jobs.items():
        if (job.run_dir / EVALUATION).is_file() and (record := load_run(job.run_dir)) is not None:
            if record.evaluation is not None:
                records[key] = record
    designs: dict[tuple, tuple] = {}  # hyperparameters -> (seeds wanted by group, claims and locomotion tables)

    def design(hyperparameters: tuple) -> tuple:
        if hyperparameters not in designs:
            mine = [r for key, r in records.items() if jobs[key].run.hyperparameters == hyperparameters]
            if mine:
                tables = (paper.claims_table(mine), paper.locomotion_table(mine))
                designs[hyperparameters] = (paper.seeds_wanted_of(*tables), *tables)
            else:
                designs[hyperparameters] = ({}, None, None)
        return designs[hyperparameters]

    def wanted(run: RunSpec) -> int:
        return int(design(run.hyperparameters)[0].get(_design_key(run), LOOKS[0]))

    sequential = [bool(block.get("sequential")) for block in data.get("train", [])]

    def keep(i: int, rank: int, run: RunSpec) -> bool:
        return not sequential[i] or rank < wanted(run) or _started(jobs[run.key])

    lines = []
    for i, block_runs in enumerate(blocks):
        if not sequential[i]:
            continue
        settings: dict[tuple, dict[str, list]] = {}  # (setting, hyperparameters) -> algo -> [(rank, run)]
        for rank, run in block_runs:
            setting = (_design_key(run)[:-1], run.hyperparameters)
            settings.setdefault(setting, {}).setdefault(run.algo, []).append((rank, run))
        for (setting, hyperparameters), by_algo in settings.items():
            task, backend, num_envs, epochs, horizon = setting
            where = f"{backend}, N {num_envs}, h {horizon}, {epochs} epochs"
            lines += _claim_lines(setting, by_algo, *design(hyperparameters)[1:])
            counts, beyond = [], 0
            for algo, ranked in by_algo.items():
                counts.append(f"{algo} {sum(keep(i, rank, run) for rank, run in ranked)}")
                beyond += sum(rank >= wanted(run) and keep(i, rank, run) for rank, run in ranked)
            note = f"; {beyond} started run(s) beyond that kept" if beyond else ""
            seeds = len({rank for ranked in by_algo.values() for rank, _ in ranked})
            lines.append(
                f"sequential: [[train]] #{i + 1} {task} ({where}) plans {', '.join(counts)} of its {seeds} seeds{note}"
            )
    return keep, lines


def plan(data: dict, store: Path, stream=None) -> list[Job]:
    """Every job of the spec, in the order they may start: the first seed's training runs, the checks,
    the other seeds' runs, then analyses of runs (the runner starts an analysis as soon as its run is
    done). A spec with sequential [[train]] blocks has the runs its design wants (:func:`_sequential_design`),
    and the lines that say why are written to ``stream`` (default: standard output)."""
    import backends
    import tasks
    from algorithms.config import ALGORITHMS

    stream = stream or sys.stdout  # the stdout of now, not of import time
    known = {"backends": backends.available(), "tasks": tasks.available(), "algos": list(ALGORITHMS)}
    check_spec(data, "spec")
    device = data["suite"].get("device", "cpu")
    blocks = _train_blocks(data, device, known)
    keep = None
    if any(block.get("sequential") for block in data.get("train", [])):
        keep, lines = _sequential_design(data, blocks, store / "runs")
        for line in lines:
            print(line, file=stream, flush=True)
    runs = _train_grid(data, blocks, keep)
    trains = [_resolved(run, store / "runs") for run in runs]
    checks = _check_jobs(data, store, device, known)
    if data["suite"].get("order", "seed") == "block":
        jobs = trains + checks
    else:
        first_seed = min((r.seed for r in runs), default=0)
        first = [j for j in trains if j.run.seed == first_seed]
        jobs = first + checks + [j for j in trains if j.run.seed != first_seed]
    analyses = _Analyses([j for j in jobs if j.kind == "train"], stream)
    return (
        jobs + analyses.sim_to_sim(data) + analyses.landscape(data) + analyses.step_gain(data) + analyses.render(data)
    )


def _check_jobs(data: dict, store: Path, device: str, known: dict) -> list[Job]:
    """One job per check block x task x target (:data:`harness.checks.kinds.KINDS`), labelled apart."""
    jobs: list[Job] = []
    check_args: list[list[str]] = []  # each check job's extra words, in order
    for i, block in enumerate(data.get("check", [])):
        where = f"[[check]] #{i + 1}"
        kind = block.get("kind")
        blist = _names(block.get("backends", []), f"{where} backends")
        for b in blist:
            if kind == "peer":
                _known(b, list(PEERS), "peer", where)
            else:
                _known(b, known["backends"], "backend", where)
            only = KINDS[kind].only_backend
            if only is not None and b != only:
                raise RunError(f"{where}: {kind} measures {only} only, not {b!r}")
        for task in _names(block.get("tasks", []), f"{where} tasks"):
            args = [str(a) for a in block.get("args", []) + block.get("per_task", {}).get(task, {}).get("args", [])]
            for label_backend, words in _check_targets(kind, blist, task):
                differentiates = KINDS[kind].differentiates
                preset, options = _check_physics(args)
                try:
                    _known_preset(task, preset)
                    gradients = (
                        gradient_identity(label_backend.split("-"), task, preset, options) if differentiates else {}
                    )
                except ValueError as exc:  # a preset the task lacks, an option the adapter refuses
                    raise RunError(f"{where} on {task}: {exc}") from None
                key = _hash([kind, *words, *args, device, physics_identity(task)] + ([gradients] if gradients else []))
                out = store / "checks" / f"{kind}_{task}_{label_backend}_{key}.json"
                if KINDS[kind].takes_device:
                    words = [*words, "--device", device]
                check_args.append(args)
                jobs.append(
                    Job(
                        label=f"{kind} {label_backend}/{task}{_preset_suffix(args)}",
                        kind=kind,
                        argv=_harness(kind, *words, *args, "--out", out),
                        output=out,
                        estimate_s=_STARTUP_S + KINDS[kind].seconds * _check_scale(label_backend.split("-"), task),
                        cost_key=(kind, label_backend, task),
                    )
                )

    _distinct_labels(jobs, check_args)
    return jobs


class _Analyses:
    """The jobs that analyse finished runs of the [[train]] grid: evaluation on another engine, the
    landscape, the step gain and the video, each after the run it reads."""

    def __init__(self, train_jobs: list[Job], stream) -> None:
        self.train_jobs, self.stream = train_jobs, stream

    def select(self, block: dict, where: str, backend_key: str) -> list[Job]:
        """The grid's runs an analysis block names. ``epochs`` and ``train_num_envs`` tell apart runs of
        two [[train]] blocks that share task, backend, algorithm, seed, horizon and preset; a block that
        would select both is refused rather than silently given one of them."""
        epochs, train_envs = block.get("epochs"), block.get("train_num_envs")
        options = tuple(sorted(block.get("backend_options", {}).items()))  # the runs' adapter options
        hyperparameters = tuple(sorted(block.get("hyperparameters", {}).items()))  # an ablation's runs
        found = [
            job
            for job in self.train_jobs
            if job.run.task == block.get("task")
            and job.run.backend == block.get(backend_key)
            and job.run.algo in _names(block.get("algos", [job.run.algo]), f"{where} algos")
            and job.run.seed in [int(s) for s in _names(block.get("seeds", [job.run.seed]), f"{where} seeds")]
            and job.run.horizon == int(block.get("horizon", job.run.horizon))
            and job.run.preset == _preset(job.run.task, block.get("preset"), where)
            and (epochs is None or job.run.epochs == int(epochs))
            and (train_envs is None or job.run.num_envs == int(train_envs))
            and job.run.backend_options == options
            and job.run.hyperparameters == hyperparameters
        ]
        if not found:
            raise RunError(f"{where}: selects no run of the [[train]] grid; it needs runs to analyse")
        seen: dict[tuple, Job] = {}
        for job in found:
            r = job.run
            twin = seen.setdefault((r.algo, r.seed), job)
            if twin is not job:
                raise RunError(
                    f"{where}: {r.algo} seed {r.seed} matches runs of two [[train]] blocks "
                    f"({twin.run.epochs} epochs x {twin.run.num_envs} envs and {r.epochs} x {r.num_envs}); "
                    "name epochs and/or train_num_envs to choose one"
                )
        return found

    def with_final_policy(self, sources: list[Job], where: str, output_of) -> list[Job]:
        """``sources`` less the runs finished without their final checkpoint (a store whose checkpoints
        were not kept) and without the analysis made before (the file ``output_of(job)``): nothing can
        analyse their final policy, so the block says so once and skips them."""
        lost = [
            j for j in sources if j.is_done() and not (j.run_dir / CHECKPOINT).is_file() and not output_of(j).is_file()
        ]
        if lost:
            names = ", ".join(f"{j.run.algo} s{j.run.seed}" for j in lost)
            print(
                f"{where}: skips {len(lost)} finished runs whose final policy was not kept: {names}", file=self.stream
            )
        return [j for j in sources if j not in lost]

    def sim_to_sim(self, data: dict) -> list[Job]:
        """Each selected run evaluated on both engines of its block (the same protocol on each)."""
        jobs: list[Job] = []
        for i, block in enumerate(data.get("sim_to_sim", [])):
            where = f"[[sim_to_sim]] #{i + 1}"
            for source in self.select(block, where, "train_backend"):
                protocol = {
                    "seeds": int(block.get("eval_seeds", 2)),
                    "num_envs": int(block.get("num_envs", 8)),
                    "max_steps": block.get("max_steps"),
                }
                for backend in (block["train_backend"], block["eval_backend"]):
                    out = source.run_dir / f"{ON_ENGINE}{backend}.json"
                    words = ["--eval-seeds", protocol["seeds"], "--num-envs", protocol["num_envs"]]
                    if protocol["max_steps"]:
                        words += ["--max-steps", protocol["max_steps"]]
                    steps = (
                        2 * protocol["seeds"] * protocol["num_envs"] * _episode(source.run.task, protocol["max_steps"])
                    )
                    jobs.append(
                        Job(
                            label=f"sim-to-sim {source.label} on {backend}",
                            kind="sim_to_sim",
                            argv=_harness("eval", "--run", source.run_dir, "--backend", backend, *words, "--out", out),
                            output=out,
                            estimate_s=_STARTUP_S
                            + steps * _seconds_per_env_step(backend, source.run.task, train=False),
                            cost_key=("sim_to_sim", backend, source.run.task),
                            expect={"backend": backend} | {k: v for k, v in protocol.items()},
                            after=[source.label],
                        )
                    )

        return jobs

    def landscape(self, data: dict) -> list[Job]:
        """The actor-loss landscape of each selected run's final policy (Fig. 3)."""
        jobs: list[Job] = []
        for i, block in enumerate(data.get("landscape", [])):
            where = f"[[landscape]] #{i + 1}"
            for source in self.with_final_policy(
                self.select(block, where, "backend"), where, lambda j: j.run_dir / LANDSCAPE
            ):
                grid, span = int(block.get("grid", 40)), float(block.get("span", 1.0))
                num_envs = int(block.get("num_envs", source.run.num_envs))
                out = source.run_dir / LANDSCAPE
                jobs.append(
                    Job(
                        label=f"landscape {source.label}",
                        kind="landscape",
                        argv=_harness(
                            "landscape", "--run", source.run_dir, "--grid", grid, "--span", span, "--num-envs", num_envs
                        ),
                        output=out,
                        estimate_s=_STARTUP_S + grid * grid * num_envs * source.run.horizon * 5e-4,
                        cost_key=("landscape", source.run.backend, source.run.task),
                        expect={"grid": grid, "span": span, "num_envs": num_envs},
                        after=[source.label],
                    )
                )
        return jobs

    def step_gain(self, data: dict) -> list[Job]:
        """The per-step Jacobian gain along each selected run's final policy (Proposition 1)."""
        jobs: list[Job] = []
        for i, block in enumerate(data.get("step_gain", [])):
            where = f"[[step_gain]] #{i + 1}"
            for source in self.with_final_policy(
                self.select(block, where, "backend"), where, lambda j: j.run_dir / STEP_GAIN
            ):
                states, stride = int(block.get("states", 256)), int(block.get("stride", 8))
                num_envs = int(block.get("num_envs", source.run.num_envs))
                out = source.run_dir / STEP_GAIN
                # the Jacobians (a backward pass per state coordinate, about 40, through the states and one window)
                gradient_steps = 40 * (states + source.run.horizon * num_envs)
                jobs.append(
                    Job(
                        label=f"step gain {source.label}",
                        kind="step_gain",
                        argv=_harness(
                            "step-gain",
                            "--run",
                            source.run_dir,
                            "--states",
                            states,
                            "--stride",
                            stride,
                            "--num-envs",
                            num_envs,
                        ),
                        output=out,
                        estimate_s=_STARTUP_S
                        + gradient_steps * _seconds_per_env_step(source.run.backend, source.run.task),
                        cost_key=("step_gain", source.run.backend, source.run.task),
                        expect={"states": states, "stride": stride, "num_envs": num_envs},
                        after=[source.label],
                    )
                )
        return jobs

    def render(self, data: dict) -> list[Job]:
        """A video of each selected run's final policy, beside the other engine's with ``compare``."""
        jobs: list[Job] = []
        from harness.run.render import compared_backends, record_stem

        for i, block in enumerate(data.get("render", [])):
            where = f"[[render]] #{i + 1}"
            compare = bool(block.get("compare", False))

            def video_of(job: Job, compare: bool = compare) -> Path:
                shown = compared_backends(job.run.backend, job.run.task) if compare else [job.run.backend]
                return record_stem(job.run_dir, shown).with_suffix(".json")

            for source in self.with_final_policy(self.select(block, where, "backend"), where, video_of):
                max_steps, frames = int(block.get("max_steps", 300)), int(block.get("frames", 60))
                words = ["--max-steps", max_steps, "--frames", frames] + (["--compare"] if compare else [])
                out = video_of(source)
                per_frame = (2.0 if source.run.task == "soft_jumper" else 0.5) * (2 if compare else 1)
                jobs.append(
                    Job(
                        label=f"render {source.label}" + (" (compare)" if compare else ""),
                        kind="render",
                        argv=_harness("render", "--run", source.run_dir, *words),
                        output=out,
                        estimate_s=_STARTUP_S + frames * per_frame,
                        cost_key=("render", source.run.backend, source.run.task),
                        expect={"max_steps": max_steps, "frames": frames},
                        after=[source.label],
                    )
                )
        return jobs


def _claim_lines(setting: tuple, by_algo: dict, claims, locomotion) -> list[str]:
    """One line per paper claim a sequential block's setting tests (its algorithms are in ``by_algo``): what
    the design read (``claims`` and ``locomotion``: the report's tables of the block's runs, None before any
    is evaluated) and the seeds it asks for."""
    from harness.report import claims as paper
    from harness.report.sequential import LOOKS

    task, backend, num_envs, epochs, horizon = setting
    where = f"{backend}, N {num_envs}, h {horizon}, {epochs} epochs"

    def rows(table, columns: tuple, values: tuple) -> list:
        """The table's rows at the setting whose ``columns`` hold ``values``."""
        if table is None:
            return []
        keys = ("task", "backend", "num_envs", "epochs", "horizon", *columns)
        return [r for _, r in table.iterrows() if tuple(r[k] for k in keys) == (*setting, *values)]

    def why(found: list, unit: str) -> str:
        if not found:
            return f"no evaluated {unit} yet -> {LOOKS[0]} seeds"
        row = found[0]
        count = int(row["pairs" if unit == "pair" else "seeds"])
        said = [f"{count} {unit}{'' if count == 1 else 's'}", str(row["verdict"])]
        said += [] if row["design"] == "before first look" else [str(row["design"])]
        return f"{', '.join(said)} -> {int(row['seeds_wanted'])} seeds"

    lines = []
    for claim in paper.PAPER_CLAIMS:
        if claim.task == task and claim.algo in by_algo and claim.base in by_algo:
            what = f"{claim.algo} vs {claim.base}" + ("" if claim.metric == "return" else f" ({claim.metric})")
            found = rows(claims, ("algo", "base", "metric"), (claim.algo, claim.base, claim.metric))
            lines.append(f"sequential: {task} {what} ({where}): {why(found, 'pair')}")
    for said in paper.PAPER_LOCOMOTION:
        if said.task == task and said.algo in by_algo:
            found = rows(locomotion, ("algo",), (said.algo,))
            lines.append(f"sequential: {task} {said.algo} moves forward? ({where}): {why(found, 'seed')}")
    return lines
