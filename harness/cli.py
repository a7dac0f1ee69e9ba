"""``python -m harness VERB ...``: the benchmark's command line.

Verbs: ``list``, ``gradcheck``, ``throughput``, ``train`` (and ``train --resume DIR``), ``eval``,
``report``, ``sweep``, ``grad-growth``, ``grad-paths``, ``crosscheck``, ``parity``, ``contact-jacobians``,
``solver-probe``, ``fd-schemes``, ``scaling``, ``scaling-plot``, ``bench`` (the suite), ``bench-run`` (one of its runs),
``landscape``. Every flag is declared once in :data:`FLAGS` (type, default, help) and every
hyperparameter flag is generated from :class:`algorithms.config.AlgoConfig`, whose field docs are
the ``--help`` text. Bad input (an
unknown backend or task, an invalid number or configuration) prints one ``error:`` line and exits 2.

Why argparse and not tyro (the CLI library CleanRL uses): tyro reports a bad value in a
nine-line framed panel (measured with tyro 1.0.17 on ``--critic-iterations 2.5``), which breaks the
one-line ``error:`` + exit 2 contract; generating the flags from the dataclass gives the same
single source of truth.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import types
import typing

from algorithms.config import ALGORITHMS

EXIT_BAD_INPUT = 2


class BadInput(Exception):
    """User input we refuse: reported as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors as a single line with exit code 2."""

    def error(self, message: str):
        raise BadInput(f"{self.prog}: {message}")


# -- value types ------------------------------------------------------------------------------


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def _nonnegative_int(text: str) -> int:
    value = _int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {value}")
    return value


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _option(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` with VALUE read as an int, a float or else a string."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    for kind in (int, float):
        try:
            return key.strip(), kind(value)
        except ValueError:
            pass
    return key.strip(), value.strip()


def _positive_float(text: str) -> float:
    value = _finite(text) if text.lower() not in ("nan", "inf", "-inf") else float("nan")
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return value


def _bool(text: str) -> bool:
    if text.lower() in ("1", "true", "yes"):
        return True
    if text.lower() in ("0", "false", "no"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def _optional_float(text: str) -> float | None:
    return None if text.lower() == "none" else _finite(text)


# -- every flag, declared once --------------------------------------------------------------------

FLAGS: dict[str, dict] = {
    "backend": {"help": "adapter name (see `list`)"},
    "backends": {"nargs": "+", "help": "two or more adapter names (see `list`)"},
    "preset": {"help": "the task's physics preset (see `list`; default: the task's own default)"},
    "episode_seeds": {"type": _positive_int, "default": 5, "help": "seeds of the random-policy episodes"},
    "task": {"help": "task name (see `list`)"},
    "algo": {"help": "one of: " + ", ".join(ALGORITHMS)},
    "algos": {"nargs": "+", "help": "algorithm presets to train, e.g. shac shac-tdadpt"},
    "num_envs": {"type": _positive_int, "help": "parallel environments N (eval: per seed, default twice the run's)"},
    "horizon": {"type": _positive_int, "help": "control steps per window h (the graph is cut after each)"},
    "device": {"default": "cpu", "help": "torch/warp device, e.g. cpu or cuda:0"},
    "seed": {"type": _int, "default": 0, "help": "random seed of the run (initial states, noise, weights)"},
    "seeds": {"type": _int, "nargs": "+", "default": [0], "help": "training seeds"},
    "steps": {"type": _positive_int, "default": 8, "help": "control steps in the differentiated rollout"},
    "epochs": {"type": _positive_int, "help": "total epochs (with --resume: a new, larger total)"},
    "out": {"help": "output path (a directory for runs, a file or prefix for results)"},
    "run": {"help": "run directory written by `train`"},
    "runs": {"nargs": "+", "help": "run directories written by `train`"},
    "windows": {
        "type": _positive_int,
        "help": "windows of h steps: timed per variant (throughput, the best is kept) or replayed (grad-growth)",
    },
    "eval_seeds": {"type": _positive_int, "default": 10, "help": "evaluation seeds (10000, 10001, ...)"},
    "max_steps": {"type": _positive_int, "help": "cap on steps per evaluation episode"},
    "checkpoint_every": {"type": _positive_int, "default": 1, "help": "epochs between checkpoints"},
    "tolerance": {"type": _positive_float, "help": "max relative gradient error allowed (default 2e-2)"},
    "jobs": {
        "type": _positive_int,
        "help": "jobs at once (bench: the spec's [suite] jobs; sweep: 1, in this process; ray: the cluster's CPUs)",
    },
    "launcher": {
        "choices": ("local", "ray"),
        "default": "local",
        "help": "where runs execute: local processes, one per core, or Ray tasks (pip install 'diffsim-bench[ray]')",
    },
    "address": {"help": "Ray head HOST:PORT to join (default: RAY_ADDRESS if set, else a new local Ray instance)"},
    "gpus_per_run": {
        "type": _positive_float,
        "default": 0.25,
        "help": "GPU fraction each run asks Ray for when the device is CUDA",
    },
    "backend_option": {
        "type": _option,
        "action": "append",
        "metavar": "KEY=VALUE",
        "help": "adapter option, repeatable, e.g. fd_scheme=central (see the adapter's docstring)",
    },
}

# the few flags whose default differs by verb, in one place
VERB_DEFAULTS: dict[str, dict] = {
    "gradcheck": {"num_envs": 2},  # finite differences perturb every env at once: 2 envs say as much as 64
    "crosscheck": {"num_envs": 4},
    "parity": {"num_envs": 64, "steps": 100, "max_steps": 300, "backends": ["newton", "mujoco_warp"]},
    "contact-jacobians": {"num_envs": 8},
    "throughput": {"num_envs": 64, "horizon": 32, "windows": 5},
    "sweep": {"num_envs": 64, "horizon": 32},
    "grad-growth": {"windows": 3},
    "grad-paths": {"algo": "shac", "num_envs": 16, "horizon": 16, "epochs": 10},
    "solver-probe": {"num_envs": 64, "task": "ant", "max_steps": 1000, "backend": "newton"},
    "fd-schemes": {"num_envs": 8, "windows": 3},
    "peer": {"windows": 5},
    "scaling": {"horizon": 8, "windows": 3},
}


def _add(p: argparse.ArgumentParser, verb: str, *names: str, required: tuple[str, ...] = ()) -> None:
    for name in names:
        spec = dict(FLAGS[name])
        if name in VERB_DEFAULTS.get(verb, {}):
            spec["default"] = VERB_DEFAULTS[verb][name]
        if "default" in spec and spec["default"] is not None:
            spec["help"] += " (default: %(default)s)"
        flag = "--" + name.replace("_", "-")
        p.add_argument(flag, dest=name, required=name in required, **spec)


def _hyperparameter_flags(p: argparse.ArgumentParser) -> None:
    """One flag per AlgoConfig field; its help is the field's documentation."""
    from algorithms.config import AlgoConfig

    group = p.add_argument_group("hyperparameters (default: the --algo preset's value)")
    hints = typing.get_type_hints(AlgoConfig)
    for f in dataclasses.fields(AlgoConfig):
        if f.name in ("algo", "num_envs", "horizon"):  # declared in FLAGS
            continue
        hint = hints[f.name]
        spec: dict = {"default": None, "help": f.metadata.get("help", "")}
        origin = typing.get_origin(hint)
        if origin is typing.Literal:
            spec["choices"] = typing.get_args(hint)
        elif hint is bool:
            spec.update(type=_bool, metavar="{true,false}")
        elif origin is tuple:
            args = typing.get_args(hint)
            spec["type"] = _int if args[0] is int else _finite
            spec["nargs"] = "+" if args[-1] is Ellipsis else len(args)
        elif origin in (typing.Union, types.UnionType):  # float | None
            spec.update(type=_optional_float, metavar="{NUMBER,none}")
        elif hint is int:
            spec["type"] = _int
        else:
            spec["type"] = _finite
        group.add_argument("--" + f.name.replace("_", "-"), dest=f.name, **spec)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="python -m harness", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="verb", required=True, parser_class=_Parser)

    sub.add_parser("list", help="registered backends and tasks")

    p = sub.add_parser("gradcheck", help="compare autograd gradients with central finite differences")
    _add(
        p,
        "gradcheck",
        "backend",
        "task",
        "num_envs",
        "device",
        "seed",
        "steps",
        "tolerance",
        "backend_option",
        "preset",
        "out",
        required=("backend", "task"),
    )
    p.add_argument(
        "--with-contact",
        action="store_true",
        help="start from the task's own initial height (contact) instead of a contact-free segment in the air",
    )
    p.add_argument(
        "--settle",
        type=_nonnegative_int,
        default=0,
        help="with --with-contact: zero-action steps before the checked segment (a robot in stance, a body at rest)",
    )

    p = sub.add_parser("train", help="train an algorithm; writes config.json, metrics.jsonl, checkpoints")
    _add(p, "train", "backend", "task", "algo", "num_envs", "horizon", "device", "seed", "epochs", "out")
    _add(p, "train", "checkpoint_every", "preset")
    p.add_argument("--resume", metavar="DIR", help="continue the interrupted run in DIR (only --epochs may change)")
    _hyperparameter_flags(p)

    p = sub.add_parser("eval", help="evaluate a run's final (and initial) policy; writes DIR/eval.json")
    _add(p, "eval", "run", "eval_seeds", "num_envs", "max_steps", "out", required=("run",))
    p.add_argument(
        "--backend",
        help="adapter name (see `list`): evaluate on this backend instead of the one the run "
        "trained on (sim-to-sim; default file DIR/eval_on_BACKEND.json)",
    )

    p = sub.add_parser("report", help="tables (md, csv: per run and mean over seeds) and curves (png)")
    _add(p, "report", "runs", "out", required=("runs", "out"))
    p.add_argument("--no-plot", action="store_true")

    p = sub.add_parser("sweep", help="train (or resume) and evaluate several algorithms and seeds, then report")
    names = ("backend", "task", "algos", "seeds", "epochs", "num_envs", "horizon", "device", "eval_seeds", "max_steps")
    _add(
        p,
        "sweep",
        *names,
        "out",
        "jobs",
        "launcher",
        "address",
        "gpus_per_run",
        required=("backend", "task", "algos", "epochs", "out"),
    )

    p = sub.add_parser("grad-growth", help="open-loop action-gradient norms along a run's policy trajectories")
    _add(p, "grad-growth", "run", required=("run",))
    p.add_argument("--variant", action="append", default=None, help="physics changes, e.g. contact_kf=300")
    _add(p, "grad-growth", "windows", "out")

    p = sub.add_parser(
        "grad-paths",
        help="actor-gradient norms on training's own windows with the policy's feedback path and the critic's "
        "bootstrap path each switched off",
    )
    _add(
        p,
        "grad-paths",
        *("backend", "task", "preset", "algo", "num_envs", "horizon", "epochs", "seed", "device", "out"),
        "backend_option",
        required=("backend", "task"),
    )

    p = sub.add_parser(
        "crosscheck",
        help="compare backends' gradients of the same loss, start and actions (soft bodies: forward COM paths)",
    )
    _add(p, "crosscheck", "task", "backends", "num_envs", "steps", "seed", "out", required=("task", "backends"))

    p = sub.add_parser(
        "parity",
        help="do two engines simulate the same task: settle, contact and limit probes, open-loop divergence, "
        "random-policy episode lengths (table, plot, JSON)",
    )
    _add(
        p,
        "parity",
        "task",
        "backends",
        "preset",
        "num_envs",
        "episode_seeds",
        "steps",
        "max_steps",
        "seed",
        "out",
        required=("task",),
    )

    p = sub.add_parser(
        "contact-jacobians",
        help="per-step Jacobians at states in contact against a reference (MuJoCo C float64, or Newton's own "
        "differences swept over step sizes), with the same states lifted clear of the ground as a control",
    )
    _add(
        p,
        "contact-jacobians",
        *("backend", "task", "preset", "num_envs", "device", "seed", "out", "backend_option"),
        required=("backend", "task"),
    )
    p.add_argument("--states", type=_positive_int, default=200, help="states in contact compared (default 200)")
    p.add_argument("--stride", type=_positive_int, default=5, help="steps between sampled states of an env")
    p.add_argument(
        "--policy-epochs",
        type=_nonnegative_int,
        default=30,
        help="half the states come from a SHAC policy trained this many epochs on newton, half from random "
        "actions (0: all random; default %(default)s)",
    )

    p = sub.add_parser("throughput", help="env-steps/s forward-only and forward+backward, and the bare engine")
    _add(
        p,
        "throughput",
        "backend",
        "task",
        "num_envs",
        "horizon",
        "device",
        "seed",
        "windows",
        "out",
        "backend_option",
        "preset",
        required=("backend", "task"),
    )
    p.add_argument(
        "--grad-cost-only",
        type=_positive_int,
        metavar="WORLDS",
        help="finite-difference adapters whose timed windows are out of reach (MuJoCo-Warp soft bodies): time one "
        "control step of WORLDS worlds and scale it to a step with gradients (forward-only windows still timed)",
    )

    p = sub.add_parser(
        "fd-schemes", help="MuJoCo-Warp finite-difference schemes: Jacobian accuracy (float64 reference) vs cost"
    )
    _add(p, "fd-schemes", "task", "num_envs", "seed", "windows", "out", required=("task",))
    p.add_argument(
        "--timing-envs",
        type=_nonnegative_int,
        default=16,
        help="envs of the timed step with gradients (0: accuracy only) (default: %(default)s)",
    )
    p.add_argument(
        "--contact-states",
        type=_nonnegative_int,
        default=48,
        help="states in contact each setting is compared on (a multiple of --num-envs) (default: %(default)s)",
    )
    p.add_argument(
        "--settle",
        type=_nonnegative_int,
        default=30,
        help="zero-action steps before the states in contact are sampled (default: %(default)s)",
    )

    p = sub.add_parser("scaling", help="forward and forward+backward env-steps/s over num_envs: CSV and log-log plot")
    names = ("backend", "task", "horizon", "device", "seed", "windows", "out", "backend_option")
    _add(p, "scaling", *names, required=("backend", "task"))
    p.add_argument(
        "--envs",
        type=_positive_int,
        nargs="+",
        default=[1, 4, 16, 64, 256],
        help="env counts, in increasing order (default: %(default)s)",
    )
    p.add_argument(
        "--max-seconds",
        type=_positive_float,
        default=600.0,
        help="skip an env count whose predicted measuring time exceeds this (default: %(default)s)",
    )
    p.add_argument(
        "--forward-only",
        action="store_true",
        help="time forward windows only (env counts whose steps with gradients are out of reach)",
    )

    p = sub.add_parser("scaling-plot", help="several `scaling` CSVs in one log-log plot")
    p.add_argument("--csv", nargs="+", required=True, help="CSV files written by `scaling`")
    _add(p, "scaling-plot", "out", required=("out",))

    p = sub.add_parser(
        "bench",
        help="the benchmark suite: checks, training grid, sim-to-sim, loss landscapes, then tables and plots",
    )
    p.add_argument("--profile", help="smoke (tox -e bench), standard (results/) or paper (a cluster's worth)")
    p.add_argument("--spec", help="a TOML spec of your own (format: harness/bench.py and README)")
    p.add_argument(
        "--store",
        default="results/bench",
        help="runs, checks, logs and tables go to STORE/NAME, NAME the spec's suite name (default: %(default)s)",
    )
    _add(p, "bench", "jobs", "launcher", "address", "gpus_per_run")
    p.add_argument("--dry-run", action="store_true", help="list the jobs, their state and estimated cost; run none")
    p.add_argument("--report-only", action="store_true", help="write the tables and plots from what is finished")

    p = sub.add_parser("bench-run", help="(used by bench) train or resume one planned run, then evaluate it")
    p.add_argument("run_dir", help="a run directory planned by bench (holds job.json)")

    p = sub.add_parser("landscape", help="h-step and TD-lambda actor losses over a plane of policy parameters")
    _add(p, "landscape", "run", "num_envs", "seed", required=("run",))
    p.add_argument("--grid", type=_positive_int, default=40, help="points per axis (default: %(default)s)")
    p.add_argument("--span", type=_positive_float, default=1.0, help="each axis spans [-span, span] (default: 1)")
    p.add_argument("--warmup-steps", type=_nonnegative_int, default=0, help="policy steps before the window")

    p = sub.add_parser("solver-probe", help="Newton solver/contact settings: forward stability and gradient size")
    _add(p, "solver-probe", "backend", "task", "num_envs", "max_steps", "out")

    p = sub.add_parser(
        "peer", help="a peer simulator's env-steps/s (Rewarped, in its own environment), written with provenance"
    )
    p.add_argument("--peer", default="rewarped", help="the peer simulator (default: %(default)s)")
    _add(p, "peer", "task", "num_envs", "horizon", "windows", "out", required=("task", "num_envs", "horizon", "out"))
    p.add_argument("--python", help="the peer environment's interpreter (default: $DIFFSIM_REWARPED_PYTHON)")
    p.add_argument(
        "--peer-arg",
        action="append",
        default=[],
        metavar="WORD",
        help="a further word for the peer's script, e.g. --peer-arg=--nograd-env (repeatable)",
    )
    return parser


# -- helpers --------------------------------------------------------------------------------------


def _command() -> str:
    return "python -m harness " + " ".join(sys.argv[1:])


def _validate_names(backend: str | None = None, task: str | None = None) -> None:
    import backends
    import tasks
    from simcore import UnknownNameError  # the registries' own message, without loading an entry point

    for kind, name, choices in (("backend", backend, backends.available()), ("task", task, tasks.available())):
        if name is not None and name not in choices:
            raise BadInput(str(UnknownNameError(kind, name, choices)))


def _check_device(device: str) -> None:
    import torch

    try:
        parsed = torch.device(device)
    except (RuntimeError, ValueError):
        raise BadInput(f"unknown device {device!r}; use cpu or cuda[:N]") from None
    if parsed.type not in ("cpu", "cuda"):
        raise BadInput(f"device {device!r} is not supported; use cpu or cuda[:N]")
    if parsed.type == "cuda" and not torch.cuda.is_available():
        raise BadInput(f"device {device!r}: this machine has no CUDA device; use cpu")


def _make_sim(args, horizon: int):
    # Imports here, not at module level: `list` and argument errors must not load an engine.
    from harness.envs import make_sim
    from tasks import make_task

    try:
        options = dict(getattr(args, "backend_option", None) or [])
        task = make_task(args.task, preset=getattr(args, "preset", None))
        return make_sim(args.backend, task, args.num_envs, args.device, args.seed, horizon, **options)
    except (RuntimeError, ValueError) as exc:
        raise BadInput(f"cannot build {args.backend}/{args.task} on {args.device}: {exc}") from exc


def _check_preset(task: str, preset: str | None) -> None:
    """Refuse a physics preset the task does not define, in one line naming the ones it does."""
    from tasks import UnknownPresetError, make_task

    try:
        make_task(task, preset=preset)
    except UnknownPresetError as exc:
        raise BadInput(str(exc)) from None


def _check_output_file(out: str) -> None:
    """A result file (or prefix) we may write: not empty, not a directory, in a writable place."""
    from pathlib import Path

    from harness.results import writable_parent

    if not out.strip():
        raise BadInput("--out is empty: name a file")
    if Path(out).is_dir():
        raise BadInput(f"--out {out} is a directory; name a file")
    if writable_parent(Path(out)) is None:
        raise BadInput(f"--out {out}: its nearest existing folder is not a writable directory")


def _algo_config(args, name: str):
    """The preset ``name`` with every hyperparameter flag the user gave applied (validated once)."""
    from algorithms.config import AlgoConfig, preset

    try:
        cfg = preset(name)
    except KeyError as exc:
        raise BadInput(exc.args[0]) from None
    changes = {}
    for f in dataclasses.fields(AlgoConfig):
        value = getattr(args, f.name, None)
        if value is not None and f.name != "algo":
            changes[f.name] = tuple(value) if isinstance(value, list) else value
    try:
        return cfg.replace(**changes)
    except ValueError as exc:
        raise BadInput(f"bad configuration: {exc}") from None


# -- verbs ----------------------------------------------------------------------------------------


def cmd_list(args) -> int:
    import backends
    import tasks

    print("backends: " + ", ".join(backends.available()))
    print("tasks:    " + ", ".join(tasks.available()))
    for name in tasks.available():
        cls = tasks.task_class(name)
        for preset, value in getattr(cls, "presets", {}).items():
            default = " (default)" if preset == cls.default_preset else ""
            print(f"  {name} preset {preset}{default}: {value.about}")
    return 0


def cmd_gradcheck(args) -> int:
    from harness.gradcheck import DEFAULT_TOLERANCE, gradcheck

    _validate_names(args.backend, args.task)
    _check_device(args.device)
    if args.out:
        _check_output_file(args.out)
    sim = _make_sim(args, horizon=args.steps)
    tolerance = args.tolerance or DEFAULT_TOLERANCE
    start_height = None
    lifted = "root" if sim.layout.floating_base else "lowest particle" if sim.layout.num_particles else None
    if not args.with_contact and lifted:
        start_height = sim.task.airborne_height  # high enough that `steps` of free fall never reach the ground
    segment = "with contact" if start_height is None else f"contact-free ({lifted} lifted to {start_height} m)"
    if args.settle:
        if start_height is not None:
            raise BadInput("--settle needs --with-contact (settling in the air would only fall)")
        segment += f", after {args.settle} zero-action steps"
    print(f"gradcheck {args.backend}/{args.task}: {args.num_envs} envs, {args.steps} steps, {segment}", flush=True)
    result = gradcheck(sim, steps=args.steps, seed=args.seed, start_height=start_height, settle_steps=args.settle)
    for label, error, mode in (
        ("d loss / d actions:      ", result.action_rel_error, result.action_mode),
        ("d loss / d initial state:", result.state_rel_error, result.state_mode),
    ):
        print(f"  {label}  max relative error {error:.3e} (central differences per {mode[:-1]})")
    ok = result.max_rel_error <= tolerance
    print(f"max relative error {result.max_rel_error:.3e} (tolerance {tolerance:.1e}): {'PASS' if ok else 'FAIL'}")
    if args.out:
        from harness.results import provenance, write_json

        summary = {
            "backend": args.backend,
            "task": args.task,
            "num_envs": args.num_envs,
            "steps": args.steps,
            "segment": segment,
            "action_rel_error": result.action_rel_error,
            "state_rel_error": result.state_rel_error,
            "max_rel_error": result.max_rel_error,
            "tolerance": tolerance,
            "passed": ok,
            **sim_physics(sim),
        }
        print(f"wrote {write_json(args.out, {'result': summary, 'provenance': provenance(_command())})}")
    return 0 if ok else 1


def cmd_throughput(args) -> int:
    from harness.results import provenance, write_json
    from harness.throughput import measure

    _validate_names(args.backend, args.task)
    _check_device(args.device)
    if args.out:
        _check_output_file(args.out)
    sim = _make_sim(args, horizon=args.horizon)
    print(
        f"throughput {args.backend}/{args.task} (preset {sim.task.preset_label}, {sim.integrator}): "
        f"{args.num_envs} envs, windows of {args.horizon} steps",
        flush=True,
    )
    if args.grad_cost_only:
        return _grad_cost_only(sim, args)
    result = measure(sim, horizon=args.horizon, windows=args.windows, seed=args.seed)
    print(f"  forward only:        {result.forward_steps_per_s:10.0f} env-steps/s")
    print(f"  forward + backward:  {result.forward_backward_steps_per_s:10.0f} env-steps/s")
    print(f"  gradient cost:       {result.gradient_cost_factor:10.2f} x a forward-only step")
    if result.bare_forward_steps_per_s is not None:
        print(f"  bare engine:         {result.bare_forward_steps_per_s:10.0f} env-steps/s (forward only)")
        print(f"  adapter / bare time: {result.forward_overhead_ratio:10.3f} (forward only)")
    if result.bare_engine_steps_per_s is not None:
        print(f"  bare engine:         {result.bare_engine_steps_per_s:10.0f} env-steps/s (forward + backward)")
        print(f"  adapter / bare time: {result.overhead_ratio:10.3f} (forward + backward)")
    if args.out:
        path = write_json(args.out, {"result": {**result.as_dict(), **sim_physics(sim)}, "provenance": provenance()})
        print(f"wrote {path}")
    return 0


def _grad_cost_only(sim, args) -> int:
    """``throughput --grad-cost-only WORLDS``: forward windows as usual, the step with gradients estimated."""
    from harness.results import provenance, write_json
    from harness.throughput import forward_rate

    cost = sim.gradient_step_cost(args.grad_cost_only)
    if cost is None:
        raise BadInput(f"--grad-cost-only: the {args.backend} adapter has no finite-difference cost to estimate")
    forward = forward_rate(sim, horizon=args.horizon, windows=args.windows, seed=args.seed)
    with_grad = args.num_envs / cost["seconds_per_step"]
    print(f"  forward only:        {forward:10.1f} env-steps/s")
    print(
        f"  forward + backward:  {with_grad:10.4f} env-steps/s (estimated: {cost['worlds_per_step']} worlds per step, "
        f"{cost['sample_worlds']} worlds timed in {cost['sample_seconds']:.1f} s)"
    )
    if args.out:
        result = {
            "backend": args.backend,
            "task": args.task,
            "num_envs": args.num_envs,
            "horizon": args.horizon,
            "windows": args.windows,
            "forward_steps_per_s": forward,
            "forward_backward_steps_per_s_estimated": with_grad,
            "gradient_step_cost": cost,
        }
        print(f"wrote {write_json(args.out, {'result': result, 'provenance': provenance()})}")
    return 0


def cmd_train(args) -> int:
    from harness.train import resume, train

    if args.resume:
        given = [
            "--" + name.replace("_", "-")
            for name, value in vars(args).items()
            if value is not None
            and name not in ("verb", "resume", "epochs", "checkpoint_every")
            and value != FLAGS.get(name, {}).get("default")
        ]
        if given:
            raise BadInput(f"--resume continues the run as configured; drop {', '.join(given)} (only --epochs)")
        resume(args.resume, args.epochs, checkpoint_every=args.checkpoint_every, command=_command())
        return 0
    missing = [name for name in ("backend", "task", "algo", "epochs", "out") if getattr(args, name) is None]
    if missing:
        raise BadInput("train needs " + ", ".join("--" + m.replace("_", "-") for m in missing) + " (or --resume DIR)")
    _validate_names(args.backend, args.task)
    _check_device(args.device)
    _check_preset(args.task, args.preset)
    cfg = _algo_config(args, args.algo)
    train(
        args.out,
        args.task,
        args.backend,
        cfg,
        args.epochs,
        seed=args.seed,
        device=args.device,
        checkpoint_every=args.checkpoint_every,
        command=_command(),
        preset=args.preset,
    )
    return 0


def cmd_eval(args) -> int:
    from pathlib import Path

    from harness.train import eval_file_name, evaluate, read_config

    config = read_config(Path(args.run))
    if args.backend:
        _validate_names(args.backend, config["task"])
    if args.out:
        _check_output_file(args.out)
    result = evaluate(
        args.run,
        seeds=args.eval_seeds,
        num_envs=args.num_envs,
        max_steps=args.max_steps,
        backend=args.backend,
        out=args.out,
    )
    print(f"initial policy: mean return {result['initial']['mean_return']:.1f}")
    print(
        f"final policy:   mean return {result['final']['mean_return']:.1f} "
        f"(std over {args.eval_seeds} seeds {result['final']['std_over_seeds']:.1f})"
    )
    written = args.out or Path(args.run) / eval_file_name(result["backend"], result["trained_on"])
    print(f"wrote {written}")
    return 0


def cmd_report(args) -> int:
    from pathlib import Path

    from harness.report import write_report
    from harness.train import read_config

    runs = [Path(r) for r in args.runs]
    for run in runs:
        read_config(run)
    _check_output_file(args.out)
    for path in write_report(runs, args.out, _command(), plot=not args.no_plot):
        print(f"wrote {path}")
    return 0


def cmd_sweep(args) -> int:
    from pathlib import Path

    from harness.report import write_report
    from harness.train import evaluate, resume, train

    _validate_names(args.backend, args.task)
    _check_device(args.device)
    configs = {name: _algo_config(args, name) for name in args.algos}  # refuse bad input before any training
    if not args.out.strip():
        raise BadInput("--out is empty: name a directory for the sweep")
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise BadInput(f"--out {args.out} is an existing file, not a directory")
    if args.launcher != "local" or (args.jobs or 1) > 1:
        return _sweep_on_launcher(args, configs)
    runs = []
    for name, cfg in configs.items():
        for seed in args.seeds:
            run = Path(args.out) / f"{args.task}_{args.backend}_{name}_s{seed}"
            resuming = (run / "config.json").exists()
            print(f"== {run.name}{' (resume)' if resuming else ''}", flush=True)
            if resuming:
                resume(run, args.epochs, command=_command())
            else:
                train(run, args.task, args.backend, cfg, args.epochs, seed=seed, device=args.device, command=_command())
            evaluate(run, seeds=args.eval_seeds, max_steps=args.max_steps)
            runs.append(run)
    paths = write_report(runs, Path(args.out) / "summary", _command())
    print(Path(paths[0]).read_text())
    return 0


def _sweep_on_launcher(args, configs: dict) -> int:
    """The sweep's runs as jobs of the suite's runner: local processes (--jobs N) or Ray tasks. Each run
    is one ``bench-run`` job in the sweep's folder; its log goes to OUT/logs."""
    from pathlib import Path

    from harness.bench import RunSpec, run_jobs, train_job
    from harness.launchers import make_launcher
    from harness.report import write_report

    out = Path(args.out).resolve()
    jobs = []
    for name in configs:
        for seed in args.seeds:
            spec = RunSpec(
                task=args.task,
                backend=args.backend,
                algo=name,
                seed=seed,
                epochs=args.epochs,
                num_envs=args.num_envs,
                horizon=args.horizon,
                device=args.device,
                eval_seeds=args.eval_seeds,
                eval_max_steps=args.max_steps,
            )
            jobs.append(train_job(spec, out / f"{args.task}_{args.backend}_{name}_s{seed}"))
    launcher = make_launcher(args.launcher, args.jobs, args.address, args.device, args.gpus_per_run)
    try:
        run_jobs(jobs, out, launcher.workers, "sweep", launcher=launcher)
    finally:
        launcher.close()
    failed = [job.label for job in jobs if job.state != "done" and job.state != "reused"]
    runs = [job.run_dir for job in jobs if job.state in ("done", "reused")]
    if runs:
        paths = write_report(runs, out / "summary", _command())
        print(Path(paths[0]).read_text())
    if failed:
        print(f"{len(failed)} run(s) failed (logs in {out / 'logs'}): {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


def cmd_bench(args) -> int:
    from harness.bench import run_suite

    return run_suite(
        profile=args.profile,
        spec_file=args.spec,
        store=args.store,
        jobs=args.jobs,
        dry_run=args.dry_run,
        report_only=args.report_only,
        command=_command(),
        launcher=args.launcher,
        address=args.address,
        gpus_per_run=args.gpus_per_run,
    )


def cmd_bench_run(args) -> int:
    from harness.bench import bench_run

    bench_run(args.run_dir)
    return 0


def cmd_landscape(args) -> int:
    from pathlib import Path

    from harness.landscape import compute_landscape, plot_landscape, write_landscape
    from harness.train import read_config

    read_config(Path(args.run))
    result = compute_landscape(
        args.run, grid=args.grid, span=args.span, num_envs=args.num_envs, seed=args.seed, warmup_steps=args.warmup_steps
    )
    print(f"wrote {write_landscape(args.run, result)}")
    print(f"wrote {plot_landscape(result, Path(args.run) / 'landscape.png')}")
    r = result["roughness"]
    print(f"roughness: h-step {r['h_step']:.3f}, TD-lambda {r['td_lambda']:.3f}")
    return 0


def cmd_grad_growth(args) -> int:
    from pathlib import Path

    from harness.grad_growth import grad_growth, parse_variant
    from harness.results import provenance, write_json
    from harness.train import read_config

    read_config(Path(args.run))
    if not (Path(args.run) / "checkpoint.pt").exists():
        raise BadInput(f"{args.run} has no checkpoint.pt")
    if args.out:
        _check_output_file(args.out)
    variants = args.variant or [""]
    try:
        for v in variants:
            parse_variant(v)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    result = grad_growth(args.run, variants, windows=args.windows)
    if args.out:
        print(f"wrote {write_json(args.out, {**result, 'provenance': provenance()})}")
    return 0


def cmd_grad_paths(args) -> int:
    from harness.grad_paths import grad_paths, table

    _validate_names(args.backend, args.task)
    _check_device(args.device)
    _check_preset(args.task, args.preset)
    if args.algo not in ALGORITHMS:
        raise BadInput(f"unknown algorithm {args.algo!r}; choose from: {', '.join(ALGORITHMS)}")
    if args.out:
        _check_output_file(args.out)
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
        _write_result_and_table(args.out, result, text)
    return 0


def sim_physics(sim) -> dict:
    """What a check's result file says about the physics it ran: preset, constants, integrator, mapping."""
    return {**sim.task.physics_record(), "integrator": sim.integrator, "physics_mapping": sim.physics_mapping()}


def cmd_parity(args) -> int:
    from harness.parity import parity, plot, table

    _validate_names(task=args.task)
    for name in args.backends:
        _validate_names(backend=name)
    if len(set(args.backends)) < 2:
        raise BadInput(f"parity compares two different backends, got {' '.join(args.backends)}")
    if args.out:
        _check_output_file(args.out)
    _check_preset(args.task, args.preset)
    try:
        result = parity(
            args.task,
            args.backends,
            preset=args.preset,
            num_envs=args.num_envs,
            seeds=args.episode_seeds,
            steps=args.steps,
            max_steps=args.max_steps,
            seed=args.seed,
            progress=lambda line: print(line, flush=True),
        )
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    text = table(result)
    print(text)
    print(f"targets {'all hold' if result['passed'] else 'not all hold'}: {result['holds']}")
    if args.out:
        stem = _write_result_and_table(args.out, result, text)
        print(f"wrote {plot(result, stem.with_suffix('.png'))}")
    return 0


def _write_result_and_table(out: str, result: dict, text: str):
    """``STEM.json`` (the result and its provenance) and ``STEM.md`` (``text``), STEM being ``out``
    without a ``.json`` suffix; returns STEM."""
    from pathlib import Path

    from harness.results import atomic_write_text, provenance, write_json

    out = Path(out)
    stem = out.with_suffix("") if out.suffix == ".json" else out
    print(f"wrote {write_json(stem.with_suffix('.json'), {'result': result, 'provenance': provenance(_command())})}")
    print(f"wrote {atomic_write_text(stem.with_suffix('.md'), text)}")
    return stem


def cmd_contact_jacobians(args) -> int:
    from harness.contact_jacobians import contact_jacobians, table

    _validate_names(args.backend, args.task)
    _check_device(args.device)
    if args.out:
        _check_output_file(args.out)
    _check_preset(args.task, args.preset)
    try:
        result = contact_jacobians(
            args.task,
            args.backend,
            device=args.device,
            states=args.states,
            num_envs=args.num_envs,
            stride=args.stride,
            policy_epochs=args.policy_epochs,
            seed=args.seed,
            preset=args.preset,
            options=dict(args.backend_option or []),
            progress=lambda line: print(line, flush=True),
        )
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    text = table(result)
    print(text)
    if args.out:
        _write_result_and_table(args.out, result, text)
    return 0


def cmd_crosscheck(args) -> int:
    import json

    from harness.crosscheck import crosscheck, forward_crosscheck
    from harness.results import provenance, write_json

    _validate_names(task=args.task)
    for name in args.backends:
        _validate_names(backend=name)
    if args.out:
        _check_output_file(args.out)
    from tasks import task_class

    if task_class(args.task).layout.num_particles:  # soft bodies: forward rollouts (module docstring)
        report = forward_crosscheck(args.task, args.backends, num_envs=args.num_envs, steps=args.steps, seed=args.seed)
        print(json.dumps(report["pairs"], indent=2))
    else:
        report = crosscheck(args.task, args.backends, num_envs=args.num_envs, steps=args.steps, seed=args.seed)
        print(json.dumps(report["segments"], indent=2))
    if args.out:
        print(f"wrote {write_json(args.out, {**report, 'provenance': provenance()})}")
    return 0


def cmd_solver_probe(args) -> int:
    from harness.solver_probe import run_probe

    _validate_names(args.backend, args.task)
    if args.task not in ("ant", "go2", "soft_jumper"):
        raise BadInput(f"solver-probe has candidates for the tasks ant, go2 and soft_jumper, not {args.task!r}")
    run_probe(
        num_envs=args.num_envs,
        out=args.out,
        command=_command(),
        task=args.task,
        steps=args.max_steps,
        backend=args.backend,
    )
    return 0


def cmd_peer(args) -> int:
    from harness.peers import PEER_TASKS, PEERS, PeerUnavailable, run_peer
    from harness.results import provenance, write_json

    if args.peer not in PEERS:
        raise BadInput(f"unknown peer {args.peer!r}; choose from: {', '.join(PEERS)}")
    if args.task not in PEER_TASKS[args.peer]:
        raise BadInput(f"{args.peer} has the tasks {', '.join(PEER_TASKS[args.peer])}, not {args.task!r}")
    _check_output_file(args.out)
    words = ["--num-envs", str(args.num_envs), "--horizon", str(args.horizon), "--windows", str(args.windows)]
    try:
        result = run_peer(args.peer, args.task, words + list(args.peer_arg), python=args.python)
    except PeerUnavailable as exc:
        raise BadInput(str(exc)) from None
    print(f"wrote {write_json(args.out, {**result, 'provenance': provenance()})}")
    return 0


def cmd_fd_schemes(args) -> int:
    from harness.results import atomic_write_text, provenance, write_json

    _validate_names("mujoco_warp", args.task)
    from tasks import task_class

    if task_class(args.task).layout.num_particles:
        raise BadInput("fd-schemes compares schemes on articulated tasks (ant, go2); soft bodies have no C reference")
    prefix = args.out.removesuffix(".json") if args.out else None  # PREFIX or PREFIX.json: both files
    if prefix:
        _check_output_file(prefix + ".json")
    from harness.fd_schemes import fd_schemes, markdown

    print(f"fd-schemes mujoco_warp/{args.task}: accuracy on {args.num_envs} envs, cost at {args.timing_envs} envs")
    report = fd_schemes(
        args.task,
        num_envs=args.num_envs,
        timing_envs=args.timing_envs,
        windows=args.windows,
        seed=args.seed,
        settle=args.settle,
        contact_states=args.contact_states,
    )
    if prefix:  # the JSON last: a suite counts the check done when it exists
        print(f"wrote {atomic_write_text(prefix + '.md', markdown(report, _command()))}")
        print(f"wrote {write_json(prefix + '.json', {**report, 'provenance': provenance()})}")
    return 0


def cmd_scaling(args) -> int:
    from harness.results import provenance, write_json
    from harness.scaling import scaling, write

    _validate_names(args.backend, args.task)
    _check_device(args.device)
    if sorted(args.envs) != list(args.envs) or len(set(args.envs)) != len(args.envs):
        raise BadInput(f"--envs must be distinct and increasing, got {args.envs}")
    suffix = ("" if args.device == "cpu" else "_cuda") + ("_forward" if args.forward_only else "")
    out = args.out.removesuffix(".json") if args.out else f"results/scaling_{args.backend}_{args.task}{suffix}"
    _check_output_file(out + ".csv")
    print(f"scaling {args.backend}/{args.task}: envs {args.envs}, {args.horizon}-step windows, best of {args.windows}")
    rows = scaling(
        args.backend,
        args.task,
        env_counts=args.envs,
        horizon=args.horizon,
        windows=args.windows,
        device=args.device,
        seed=args.seed,
        max_seconds=args.max_seconds,
        options=dict(args.backend_option or []),
        forward_only=args.forward_only,
    )
    prov = provenance()
    for path in write(rows, out, _command(), prov):
        print(f"wrote {path}")
    print(f"wrote {write_json(out + '.json', {'rows': rows, 'provenance': prov})}")
    return 0


def cmd_scaling_plot(args) -> int:
    from pathlib import Path

    from harness.scaling import plot

    missing = [c for c in args.csv if not Path(c).is_file()]
    if missing:
        raise BadInput(f"no such scaling CSV: {missing[0]}")
    if not args.out.endswith(".png"):
        raise BadInput(f"--out must name a .png file, got {args.out!r}")
    _check_output_file(args.out)
    try:
        print(f"wrote {plot(args.csv, args.out)}")
    except (KeyError, ValueError) as exc:
        raise BadInput(f"not a scaling CSV ({exc}): {' '.join(args.csv)}") from None
    return 0


VERBS = {
    "scaling-plot": cmd_scaling_plot,
    "scaling": cmd_scaling,
    "fd-schemes": cmd_fd_schemes,
    "list": cmd_list,
    "gradcheck": cmd_gradcheck,
    "throughput": cmd_throughput,
    "train": cmd_train,
    "eval": cmd_eval,
    "report": cmd_report,
    "sweep": cmd_sweep,
    "grad-growth": cmd_grad_growth,
    "grad-paths": cmd_grad_paths,
    "crosscheck": cmd_crosscheck,
    "parity": cmd_parity,
    "contact-jacobians": cmd_contact_jacobians,
    "solver-probe": cmd_solver_probe,
    "peer": cmd_peer,
    "bench": cmd_bench,
    "bench-run": cmd_bench_run,
    "landscape": cmd_landscape,
}


def main(argv: list[str] | None = None) -> int:
    from harness.results import RunError, RunStopped

    try:
        args = build_parser().parse_args(argv)
        return VERBS[args.verb](args)
    except (BadInput, RunError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except RunStopped as exc:
        print(f"stopped: {exc}", file=sys.stderr)
        return 128 + exc.signum
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
