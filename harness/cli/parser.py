"""The command line's parser: every flag declared once (:data:`FLAGS`: type, default, help), the few
verb-specific defaults (:data:`VERB_DEFAULTS`), hyperparameter flags generated from
:class:`algorithms.config.AlgoConfig` (its field docs are the help), and one sub-parser per verb; the
check kinds' verbs are built from their registry entries (:data:`harness.checks.kinds.KINDS`)."""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing

from algorithms.config import ALGORITHMS
from harness.bounds import (
    INT_MAX,
    MAX_ENVS,
    MAX_EPOCHS,
    MAX_EVAL_SEEDS,
    MAX_FRAMES,
    MAX_GPUS_PER_RUN,
    MAX_GRID,
    MAX_HORIZON,
    MAX_JOBS,
    MAX_SEGMENT_STEPS,
    MAX_STEP_GAIN_STATES,
    MAX_STEPS,
    MAX_STRIDE,
    MAX_TOLERANCE,
    MAX_WINDOWS,
)
from harness.checks.kinds import KINDS
from harness.inputs import BadInput
from harness.words import (
    boolean,
    finite,
    int_in,
    integer,
    one_line,
    optional_float,
    parse_option,
    positive_float_up_to,
    span,
)


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


# -- every flag, declared once --------------------------------------------------------------------

FLAGS: dict[str, dict] = {
    "backend": {"type": one_line, "help": "adapter name (see `list`)"},
    "backends": {"type": one_line, "nargs": "+", "help": "two or more adapter names (see `list`)"},
    "preset": {"type": one_line, "help": "the task's physics preset (see `list`; default: the task's own default)"},
    "episode_seeds": {"type": int_in(1, MAX_EVAL_SEEDS), "default": 5, "help": "seeds of the random-policy episodes"},
    "task": {"type": one_line, "help": "task name (see `list`)"},
    "algo": {"type": one_line, "help": "one of: " + ", ".join(ALGORITHMS)},
    "algos": {"type": one_line, "nargs": "+", "help": "algorithm presets to train, e.g. shac shac-tdadpt"},
    "num_envs": {"type": int_in(1, MAX_ENVS), "help": "parallel environments N"},
    "horizon": {"type": int_in(1, MAX_HORIZON), "help": "control steps per window h (the graph is cut after each)"},
    "device": {"type": one_line, "default": "cpu", "help": "torch/warp device, e.g. cpu or cuda:0"},
    "seed": {
        "type": int_in(0, INT_MAX),
        "default": 0,
        "help": "random seed of the run (initial states, noise, weights)",
    },
    "seeds": {"type": int_in(0, INT_MAX), "nargs": "+", "default": [0], "help": "training seeds"},
    "steps": {
        "type": int_in(1, MAX_SEGMENT_STEPS),
        "default": 8,
        "help": "control steps in the differentiated rollout",
    },
    "epochs": {"type": int_in(1, MAX_EPOCHS), "help": "training epochs"},
    "out": {"type": one_line, "help": "the result file to write (JSON)"},
    "run": {"type": one_line, "help": "run directory written by `train`"},
    "runs": {"type": one_line, "nargs": "+", "help": "run directories written by `train`"},
    "windows": {"type": int_in(1, MAX_WINDOWS), "help": "timed windows of h steps of each kind (the best is kept)"},
    "eval_seeds": {"type": int_in(1, MAX_EVAL_SEEDS), "default": 10, "help": "evaluation seeds (10000, 10001, ...)"},
    "max_steps": {"type": int_in(1, MAX_STEPS), "help": "cap on steps per evaluation episode (default: the task's)"},
    "checkpoint_every": {"type": int_in(1, MAX_EPOCHS), "default": 1, "help": "epochs between checkpoints"},
    "tolerance": {
        "type": positive_float_up_to(MAX_TOLERANCE),
        "help": "max relative gradient error allowed (default 2e-2)",
    },
    "jobs": {
        "type": int_in(1, MAX_JOBS),
        "help": "jobs at once (bench: the spec's [suite] jobs; sweep: 1; ray: the cluster's CPUs)",
    },
    "launcher": {
        "choices": ("local", "ray"),
        "default": "local",
        "help": "where runs execute: local processes, one per core, or Ray tasks (pip install 'diffsim-bench[ray]')",
    },
    "address": {
        "type": one_line,
        "help": "Ray head HOST:PORT to join (default: RAY_ADDRESS if set, else a new local Ray instance)",
    },
    "gpus_per_run": {
        "type": positive_float_up_to(MAX_GPUS_PER_RUN),
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

# the few flags whose default differs by verb (a check kind declares its own in harness.checks.kinds)
VERB_DEFAULTS: dict[str, dict] = {
    "step-gain": {"num_envs": 64},
    "sweep": {"num_envs": 64, "horizon": 32},
    "grad-growth": {"windows": 3},
    "bench": {"device": None},  # the spec's [suite] device unless given
}

# what a shared flag means in the verbs where FLAGS' words would not be true (check kinds: their registry entry)
VERB_HELP: dict[str, dict[str, str]] = {
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
    "scaling-plot": {"out": "the plot to write (.png)"},
    "landscape": {"num_envs": "envs of the window whose losses are mapped"},
    "step-gain": {"num_envs": "envs of the policy's rollout (one batch of Jacobians)"},
    "render": {
        "run": "run directory written by `train` (its checkpoint.pt is the policy shown)",
        "backend": "the engine to show it on (default: the one it trained on)",
        "max_steps": "control steps shown at most, fewer when the episode ends (default 300)",
    },
}


def flag_help(verb: str) -> dict[str, str]:
    """What the shared flags mean in ``verb`` where FLAGS' words would not be true: a check kind's own
    declaration (:data:`harness.checks.kinds.KINDS`), else :data:`VERB_HELP`."""
    return KINDS[verb].flag_help if verb in KINDS else VERB_HELP.get(verb, {})


def _add(p: argparse.ArgumentParser, verb: str, *names: str, required: tuple[str, ...] = ()) -> None:
    defaults = KINDS[verb].defaults if verb in KINDS else VERB_DEFAULTS.get(verb, {})
    for name in names:
        spec = dict(FLAGS[name])
        if name in flag_help(verb):
            spec["help"] = flag_help(verb)[name]
        if name in defaults:
            spec["default"] = defaults[name]
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
            spec.update(type=boolean, metavar="{true,false}")
        elif origin is tuple:
            args = typing.get_args(hint)
            spec["type"] = integer if args[0] is int else finite
            spec["nargs"] = "+" if args[-1] is Ellipsis else len(args)
        elif origin in (typing.Union, types.UnionType):  # float | None
            spec.update(type=optional_float, metavar="{NUMBER,none}")
        elif hint is int:
            spec["type"] = integer
        else:
            spec["type"] = finite
        group.add_argument("--" + f.name.replace("_", "-"), dest=f.name, **spec)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="python -m harness", description="the benchmark's command line (python -m harness VERB --help)"
    )
    sub = parser.add_subparsers(dest="verb", required=True, parser_class=_Parser)
    for add_verbs in (_run_verbs, _check_verbs, _other_check_verbs, _analysis_verbs):
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
    p.add_argument("--readme", type=one_line, default="README.md", help="the README to update (default: %(default)s)")
    p.add_argument("--root", type=one_line, default=".", help="the repository the results are under (default: .)")

    p = sub.add_parser("bench-run", help="(used by bench) train or resume one planned run, then evaluate it")
    p.add_argument("run_dir", help="a run directory planned by bench (holds job.json)")


def _check_verbs(sub) -> None:
    """One verb per check kind, as its registry entry declares it (:data:`harness.checks.kinds.KINDS`)."""
    for kind in KINDS.values():
        p = sub.add_parser(kind.name, help=kind.help)
        _add(p, kind.name, *kind.flags, required=kind.required)
        for flag, keywords in kind.own_flags:
            p.add_argument(flag, **keywords)


def _other_check_verbs(sub) -> None:
    """Checks the suite does not run: a run's open-loop gradients, scaling CSVs in one plot."""
    p = sub.add_parser("grad-growth", help="open-loop action-gradient norms along a run's policy trajectories")
    _add(p, "grad-growth", "run", required=("run",))
    p.add_argument("--variant", action="append", default=None, help="physics changes, e.g. contact_kf=300")
    _add(p, "grad-growth", "windows", "out")

    p = sub.add_parser("scaling-plot", help="several `scaling` CSVs in one log-log plot")
    p.add_argument("--csv", nargs="+", required=True, help="CSV files written by `scaling`")
    _add(p, "scaling-plot", "out", required=("out",))


def _analysis_verbs(sub) -> None:
    """Analyses of a run's final policy: the loss landscape, the step gain, a video."""
    p = sub.add_parser("landscape", help="h-step and TD-lambda actor losses over a plane of policy parameters")
    _add(p, "landscape", "run", "num_envs", "seed", required=("run",))
    p.add_argument("--grid", type=int_in(2, MAX_GRID), default=40, help="points per axis (default: %(default)s)")
    p.add_argument("--span", type=span, default=1.0, help="each axis spans [-span, span] (default: 1)")
    p.add_argument("--warmup-steps", type=int_in(0, MAX_STEPS), default=0, help="policy steps before the window")

    p = sub.add_parser(
        "step-gain",
        help="Proposition 1's B_f: the one-step Jacobian's gain at states a run's final policy visits",
    )
    _add(p, "step-gain", "run", "num_envs", "seed", required=("run",))
    p.add_argument("--states", type=int_in(1, MAX_STEP_GAIN_STATES), default=256, help="states measured (default 256)")
    p.add_argument("--stride", type=int_in(1, MAX_STRIDE), default=8, help="control steps between an env's states")

    p = sub.add_parser("render", help="a video and a filmstrip of a run's final policy (headless)")
    _add(p, "render", "run", "backend", "max_steps", required=("run",))
    p.add_argument("--compare", action="store_true", help="both engines side by side, the same policy and seed")
    p.add_argument("--frames", type=int_in(1, MAX_FRAMES), default=60, help="frames drawn, evenly spaced (default: 60)")
