"""The command line's parser: every flag declared once (:data:`FLAGS`: type, default, help), the few
verb-specific defaults (:data:`VERB_DEFAULTS`), hyperparameter flags generated from
:class:`algorithms.config.AlgoConfig` (its field docs are the help), and one sub-parser per verb."""

from __future__ import annotations

import argparse
import dataclasses
import math
import types
import typing

from algorithms.config import ALGORITHMS
from harness.bounds import (
    INT_MAX,
    MAX_CONTACT_STATES,
    MAX_ENVS,
    MAX_EPOCHS,
    MAX_EVAL_SEEDS,
    MAX_GRID,
    MAX_HORIZON,
    MAX_SEGMENT_STEPS,
    MAX_SPAN,
    MAX_STEP_GAIN_STATES,
    MAX_STEPS,
    MAX_STRIDE,
)
from harness.cli.inputs import BadInput
from harness.words import parse_option


class _Once:
    """A flag that takes one value, refused when given twice (argparse alone keeps the last, so a
    pasted-over command line would run with a value the user may not have meant)."""

    def __call__(self, parser, namespace, values, option_string=None):
        if option_string is not None:
            if self.dest in parser.given:
                parser.error(f"{option_string} given twice; give it once")
            parser.given.add(self.dest)
        super().__call__(parser, namespace, values, option_string)


class _StoreOnce(_Once, argparse._StoreAction):
    pass


class _StoreTrueOnce(_Once, argparse._StoreTrueAction):
    pass


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors as a single line with exit code 2 and refuses a single-value flag
    given twice."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.given: set[str] = set()
        self.register("action", None, _StoreOnce)
        self.register("action", "store", _StoreOnce)
        self.register("action", "store_true", _StoreTrueOnce)

    def parse_known_args(self, args=None, namespace=None):
        self.given = set()  # the flags of this command line
        return super().parse_known_args(args, namespace)

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


def _int_in(low: int, high: int):
    """An integer flag in [low, high]: the limits a suite spec has (:mod:`harness.suite.schema`), so that
    a value the types or the machine cannot hold is refused before any work."""

    def parse(text: str) -> int:
        value = _int(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected an integer in [{low}, {high}], got {value}")
        return value

    parse.__name__ = "integer"  # argparse names the type in its messages
    return parse


def _nonnegative_int(text: str) -> int:
    value = _int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {value}")
    return value


def _text(text: str) -> str:
    """A name or path given on the command line: not empty (an empty value would read as "not given"),
    one line, no control characters."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a non-empty value, got ''")
    if any(ord(ch) < 32 for ch in text):
        raise argparse.ArgumentTypeError(f"expected one line without control characters, got {text!r}")
    return text


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _positive_float(text: str) -> float:
    value = _finite(text) if text.lower() not in ("nan", "inf", "-inf") else float("nan")
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return value


def _span(text: str) -> float:
    """A landscape's half-width: positive, at most :data:`MAX_SPAN` (beyond it every point is NaN)."""
    value = _positive_float(text)
    if value > MAX_SPAN:
        raise argparse.ArgumentTypeError(f"expected a number in (0, {MAX_SPAN:g}], got {text!r}")
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
    "backend": {"type": _text, "help": "adapter name (see `list`)"},
    "backends": {"type": _text, "nargs": "+", "help": "two or more adapter names (see `list`)"},
    "preset": {"type": _text, "help": "the task's physics preset (see `list`; default: the task's own default)"},
    "episode_seeds": {"type": _int_in(1, MAX_EVAL_SEEDS), "default": 5, "help": "seeds of the random-policy episodes"},
    "task": {"type": _text, "help": "task name (see `list`)"},
    "algo": {"type": _text, "help": "one of: " + ", ".join(ALGORITHMS)},
    "algos": {"type": _text, "nargs": "+", "help": "algorithm presets to train, e.g. shac shac-tdadpt"},
    "num_envs": {"type": _int_in(1, MAX_ENVS), "help": "parallel environments N"},
    "horizon": {"type": _int_in(1, MAX_HORIZON), "help": "control steps per window h (the graph is cut after each)"},
    "device": {"type": _text, "default": "cpu", "help": "torch/warp device, e.g. cpu or cuda:0"},
    "seed": {
        "type": _int_in(0, INT_MAX),
        "default": 0,
        "help": "random seed of the run (initial states, noise, weights)",
    },
    "seeds": {"type": _int_in(0, INT_MAX), "nargs": "+", "default": [0], "help": "training seeds"},
    "steps": {
        "type": _int_in(1, MAX_SEGMENT_STEPS),
        "default": 8,
        "help": "control steps in the differentiated rollout",
    },
    "epochs": {"type": _int_in(1, MAX_EPOCHS), "help": "training epochs"},
    "out": {"type": _text, "help": "the result file to write (JSON)"},
    "run": {"type": _text, "help": "run directory written by `train`"},
    "runs": {"type": _text, "nargs": "+", "help": "run directories written by `train`"},
    "windows": {"type": _positive_int, "help": "timed windows of h steps of each kind (the best is kept)"},
    "eval_seeds": {"type": _int_in(1, MAX_EVAL_SEEDS), "default": 10, "help": "evaluation seeds (10000, 10001, ...)"},
    "max_steps": {"type": _int_in(1, MAX_STEPS), "help": "cap on steps per evaluation episode (default: the task's)"},
    "checkpoint_every": {"type": _positive_int, "default": 1, "help": "epochs between checkpoints"},
    "tolerance": {"type": _positive_float, "help": "max relative gradient error allowed (default 2e-2)"},
    "jobs": {
        "type": _positive_int,
        "help": "jobs at once (bench: the spec's [suite] jobs; sweep: 1; ray: the cluster's CPUs)",
    },
    "launcher": {
        "choices": ("local", "ray"),
        "default": "local",
        "help": "where runs execute: local processes, one per core, or Ray tasks (pip install 'diffsim-bench[ray]')",
    },
    "address": {
        "type": _text,
        "help": "Ray head HOST:PORT to join (default: RAY_ADDRESS if set, else a new local Ray instance)",
    },
    "gpus_per_run": {
        "type": _positive_float,
        "default": 0.25,
        "help": "GPU fraction each run asks Ray for when the device is CUDA",
    },
    "backend_option": {
        "type": parse_option,
        "action": "append",
        "metavar": "KEY=VALUE",
        "help": "adapter option, repeatable, e.g. fd_scheme=central (see the adapter's docstring)",
    },
}

# the few flags whose default differs by verb, in one place
VERB_DEFAULTS: dict[str, dict] = {
    "gradcheck": {"num_envs": 2},  # finite differences perturb every env at once: 2 envs say as much as 64
    "crosscheck": {"num_envs": 4},
    "parity": {"num_envs": 64, "steps": 100, "max_steps": 300},
    "contact-jacobians": {"num_envs": 8},
    "step-gain": {"num_envs": 64},
    "throughput": {"num_envs": 64, "horizon": 32, "windows": 5},
    "sweep": {"num_envs": 64, "horizon": 32},
    "grad-growth": {"windows": 3},
    "grad-paths": {"algo": "shac", "num_envs": 16, "horizon": 16, "epochs": 10},
    "solver-probe": {"num_envs": 64, "task": "ant", "max_steps": 1000, "backend": "newton"},
    "fd-schemes": {"num_envs": 8, "windows": 3},
    "peer": {"windows": 5},
    "scaling": {"horizon": 8, "windows": 3},
    "bench": {"device": None},  # the spec's [suite] device unless given
}

# what a shared flag means in the verbs where FLAGS' words would not be true, in one place
VERB_HELP: dict[str, dict[str, str]] = {
    "gradcheck": {
        "num_envs": "envs differenced at once",
        "out": "the check's result file (JSON)",
    },
    "train": {
        "backend_option": "adapter option, repeatable, e.g. fd_scheme=one_sided: recorded in config.json, kept on "
        "--resume and in evaluations on the same backend",
        "epochs": "total epochs (with --resume: a new, larger total)",
        "out": "the run directory to write",
    },
    "eval": {
        "num_envs": "envs per evaluation seed (default: twice the run's)",
        "out": "the evaluation file to write (default: RUN/eval.json)",
    },
    "report": {"out": "prefix of the tables (.md, .csv, _by_algo.csv) and the curves (.png)"},
    "bench": {
        "device": "run the suite's jobs on this device (cpu, cuda[:N]) instead of its [suite] device; a run "
        "finished on one device is reused by a suite on another",
    },
    "sweep": {"epochs": "epochs of every run", "out": "the sweep's directory: its runs, logs, tables and plots"},
    "grad-growth": {"windows": "windows of the policy's trajectory replayed open-loop"},
    "grad-paths": {
        "epochs": "SHAC epochs whose windows are rolled out four ways",
        "out": "the result file (JSON; its table beside it as .md)",
    },
    "crosscheck": {
        "num_envs": "envs compared on every engine",
        "steps": "control steps of each compared segment",
    },
    "parity": {
        "num_envs": "envs per seed of the settle, probe and episode measurements",
        "steps": "open-loop steps of the trajectory comparison",
        "max_steps": "cap on steps of each random-policy episode",
        "out": "the result file (JSON; its table .md and plot .png beside it)",
    },
    "contact-jacobians": {
        "num_envs": "envs per batch of sampled states",
        "out": "the result file (JSON; its table beside it as .md)",
    },
    "throughput": {"num_envs": "envs stepped at once in the timed windows", "horizon": "env steps per timed window"},
    "fd-schemes": {
        "num_envs": "envs per batch of compared states",
        "windows": "timed steps with gradients (the best is kept)",
        "out": "the result file (PREFIX.json; its table beside it as PREFIX.md)",
    },
    "scaling": {
        "horizon": "env steps per timed window",
        "windows": "timed windows per env count (the best is kept)",
        "out": "prefix of the .csv, .png and .json written (without it: the table is printed, nothing written)",
    },
    "scaling-plot": {"out": "the plot to write (.png)"},
    "landscape": {"num_envs": "envs of the window whose losses are mapped"},
    "step-gain": {"num_envs": "envs of the policy's rollout (one batch of Jacobians)"},
    "render": {
        "run": "run directory written by `train` (its checkpoint.pt is the policy shown)",
        "backend": "the engine to show it on (default: the one it trained on)",
        "max_steps": "control steps shown at most, fewer when the episode ends (default 300)",
    },
    "solver-probe": {
        "num_envs": "envs of the random-action rollout",
        "max_steps": "control steps of each probe rollout",
    },
    "peer": {"num_envs": "envs of the peer's timed windows", "horizon": "env steps per timed window"},
}


def _add(p: argparse.ArgumentParser, verb: str, *names: str, required: tuple[str, ...] = ()) -> None:
    for name in names:
        spec = dict(FLAGS[name])
        if name in VERB_HELP.get(verb, {}):
            spec["help"] = VERB_HELP[verb][name]
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
    parser = _Parser(
        prog="python -m harness", description="the benchmark's command line (python -m harness VERB --help)"
    )
    sub = parser.add_subparsers(dest="verb", required=True, parser_class=_Parser)
    for add_verbs in (_run_verbs, _gradient_verbs, _contact_verbs, _engine_verbs, _analysis_verbs):
        add_verbs(sub)
    return parser


def _run_verbs(sub) -> None:
    """Training runs and suites: train, evaluate, report, sweep, bench."""
    sub.add_parser("list", help="registered backends and tasks")

    p = sub.add_parser("train", help="train an algorithm; writes config.json, metrics.jsonl, checkpoints")
    _add(p, "train", "backend", "task", "algo", "num_envs", "horizon", "device", "seed", "epochs", "out")
    _add(p, "train", "checkpoint_every", "preset", "backend_option")
    p.add_argument("--resume", metavar="DIR", help="continue the interrupted run in DIR (only --epochs may change)")
    _hyperparameter_flags(p)

    p = sub.add_parser("eval", help="evaluate a run's final (and initial) policy; writes DIR/eval.json")
    _add(p, "eval", "run", "eval_seeds", "num_envs", "max_steps", "out", required=("run",))
    p.add_argument(
        "--backend",
        help="adapter name (see `list`): evaluate on this backend instead of the one the run "
        "trained on (sim-to-sim; default file DIR/sim2sim_on_BACKEND.json)",
    )

    p = sub.add_parser("report", help="tables (md, csv: per run and mean over seeds) and curves (png)")
    _add(p, "report", "runs", "out", required=("runs", "out"))
    p.add_argument("--no-plot", action="store_true")

    p = sub.add_parser("sweep", help="algorithms x seeds of one task and backend: a suite made in memory")
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

    p = sub.add_parser(
        "bench",
        help="the benchmark suite: checks, training grid, sim-to-sim, loss landscapes, then tables and plots",
    )
    p.add_argument(
        "--profile",
        help="smoke (tox -e bench), standard (results/), perf (speed), protocol (the paper's Ant protocol) "
        "or paper (a cluster's worth)",
    )
    p.add_argument("--spec", help="a TOML spec of your own (format: docs/suite.md)")
    p.add_argument(
        "--store",
        default="results/bench",
        help="runs, checks, logs and tables go to STORE/NAME, NAME the spec's suite name (default: %(default)s)",
    )
    _add(p, "bench", "jobs", "launcher", "address", "gpus_per_run", "device")
    p.add_argument("--dry-run", action="store_true", help="list the jobs, their state and estimated cost; run none")
    p.add_argument("--report-only", action="store_true", help="write the tables and plots from what is finished")

    p = sub.add_parser("readme", help="make README's headline tables from the result files they cite")
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 naming the blocks that differ")
    p.add_argument("--readme", type=_text, default="README.md", help="the README to update (default: %(default)s)")
    p.add_argument("--root", type=_text, default=".", help="the repository the results are under (default: .)")

    p = sub.add_parser("bench-run", help="(used by bench) train or resume one planned run, then evaluate it")
    p.add_argument("run_dir", help="a run directory planned by bench (holds job.json)")


def _gradient_verbs(sub) -> None:
    """Gradient checks: against finite differences, between engines, along a run's policy."""
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


def _contact_verbs(sub) -> None:
    """Gradients in contact: per-step Jacobians against a reference, MuJoCo-Warp's schemes."""
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
    p.add_argument(
        "--states", type=_int_in(1, MAX_CONTACT_STATES), default=200, help="states in contact compared (default 200)"
    )
    p.add_argument("--stride", type=_positive_int, default=5, help="steps between sampled states of an env")
    p.add_argument(
        "--policy-epochs",
        type=_nonnegative_int,
        default=30,
        help="half the states come from a SHAC policy trained this many epochs on newton, half from random "
        "actions (0: all random; default %(default)s)",
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
        type=_int_in(1, MAX_CONTACT_STATES),
        default=48,
        help="states in contact each setting is compared on (a multiple of --num-envs) (default: %(default)s)",
    )
    p.add_argument(
        "--settle",
        type=_nonnegative_int,
        default=30,
        help="zero-action steps before the states in contact are sampled (default: %(default)s)",
    )
    p.add_argument(
        "--schemes",
        nargs="+",
        metavar="SCHEME",
        help="compare only the grid's rows of these schemes (central, forward, one_sided, adaptive, or adjoint: "
        "the analytic gradients; the control-step rows come with the default scheme, one_sided) (default: every row)",
    )


def _engine_verbs(sub) -> None:
    """Engine measurements: parity of the physics, speed, solver settings, a peer simulator."""
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


def _analysis_verbs(sub) -> None:
    """Analyses of a run's final policy: the loss landscape, the step gain, a video."""
    p = sub.add_parser("landscape", help="h-step and TD-lambda actor losses over a plane of policy parameters")
    _add(p, "landscape", "run", "num_envs", "seed", required=("run",))
    p.add_argument("--grid", type=_int_in(2, MAX_GRID), default=40, help="points per axis (default: %(default)s)")
    p.add_argument("--span", type=_span, default=1.0, help="each axis spans [-span, span] (default: 1)")
    p.add_argument("--warmup-steps", type=_nonnegative_int, default=0, help="policy steps before the window")

    p = sub.add_parser(
        "step-gain",
        help="Proposition 1's B_f: the one-step Jacobian's gain at states a run's final policy visits",
    )
    _add(p, "step-gain", "run", "num_envs", "seed", required=("run",))
    p.add_argument("--states", type=_int_in(1, MAX_STEP_GAIN_STATES), default=256, help="states measured (default 256)")
    p.add_argument("--stride", type=_int_in(1, MAX_STRIDE), default=8, help="control steps between an env's states")

    p = sub.add_parser("render", help="a video and a filmstrip of a run's final policy (headless)")
    _add(p, "render", "run", "backend", "max_steps", required=("run",))
    p.add_argument("--compare", action="store_true", help="both engines side by side, the same policy and seed")
    p.add_argument("--frames", type=_positive_int, default=60, help="frames drawn, evenly spaced (default: 60)")
