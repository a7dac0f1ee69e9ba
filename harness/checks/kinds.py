"""The bench suite's check kinds, each declared once: what it checks, the flags of its verb, the module
that runs it and sums up its result, how its jobs are addressed and what a job of it costs.

Everything else reads this table: the spec schema's list of valid kinds and the planner's jobs
(:func:`harness.suite.bench.plan`), the command line (one verb per kind, of the same name, built from
``flags``/``own_flags``: :func:`harness.cli.parser.build_parser`), the verb itself (``module``'s
``verb(args) -> exit code``) and the suite's checks table (``module``'s ``summary(result) -> str``).
Modules are named, not imported, so ``python -m harness --help`` loads no engine.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field

from harness.bounds import (
    MAX_CONTACT_STATES,
    MAX_ENVS,
    MAX_EPOCHS,
    MAX_SECONDS,
    MAX_STEPS,
    MAX_STRIDE,
    MAX_WORLDS,
)
from harness.words import int_in, one_line, positive_float_up_to


@dataclass(frozen=True)
class CheckKind:
    """How the suite runs one kind of check, and how its verb reads its command line."""

    #: the kind's name: a ``[[check]]`` block's ``kind`` and the harness verb that runs it
    name: str
    #: rough seconds of one job on this project's 2-core CPU machine, for the ETA and the schedule
    seconds: float
    #: the verb's one-line help
    help: str
    #: the module (under ``harness.checks``) with the kind's ``verb(args)`` and ``summary(result)``
    module: str
    #: the shared flags it takes (names in :data:`harness.cli.parser.FLAGS`), and those it requires
    flags: tuple[str, ...] = ()
    required: tuple[str, ...] = ()
    #: what a shared flag means here, where FLAGS' words would not be true
    flag_help: dict[str, str] = field(default_factory=dict)
    #: a shared flag's default here, where it differs from FLAGS'
    defaults: dict[str, object] = field(default_factory=dict)
    #: flags of its own: (``--flag``, argparse keywords)
    own_flags: tuple[tuple[str, dict], ...] = ()
    #: "backend": one job per backend (``--backend B --task T``); "backends": one job over all of a
    #: block's backends (``--backends ...``); "simulator": one job per named simulator, which the verb
    #: picks itself (``--task T`` only)
    targets: str = "backend"
    #: its result depends on how an adapter computes gradients, so its address carries their settings
    differentiates: bool = False
    #: its verb takes ``--device`` (the others run on the CPU)
    takes_device: bool = True
    #: the one backend it measures, when it measures one only
    only_backend: str | None = None
    #: the kinds its result files carry (:func:`harness.results.write_check`), when more than its name
    file_kinds: tuple[str, ...] = ()

    def _module(self):
        return importlib.import_module(f"harness.checks.{self.module}")

    def run(self, args) -> int:
        """Run the verb on parsed ``args``; its exit code."""
        return self._module().verb(args)

    def summary(self, result: dict, file_kind: str) -> str:
        """One line of a result file's key numbers, for the suite's checks table."""
        return self._module().summary(result, file_kind)


_OUT_WITH_TABLE = "the result file (JSON; its table beside it as .md)"

KINDS: dict[str, CheckKind] = {
    k.name: k
    for k in (
        CheckKind(
            "gradcheck",
            40.0,
            "compare autograd gradients with central finite differences",
            "gradcheck",
            flags=(
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
            ),
            required=("backend", "task"),
            flag_help={"num_envs": "envs differenced at once", "out": "the check's result file (JSON)"},
            defaults={"num_envs": 2},  # finite differences perturb every env at once: 2 say as much as 64
            own_flags=(
                (
                    "--with-contact",
                    {
                        "action": "store_true",
                        "help": "start from the task's own initial height (contact) instead of a contact-free "
                        "segment in the air",
                    },
                ),
                (
                    "--settle",
                    {
                        "type": int_in(0, MAX_STEPS),
                        "default": 0,
                        "help": "with --with-contact: zero-action steps before the checked segment (a robot in "
                        "stance, a body at rest)",
                    },
                ),
            ),
            differentiates=True,
        ),
        CheckKind(
            "throughput",
            60.0,
            "env-steps/s forward-only and forward+backward, and the bare engine",
            "throughput",
            flags=(
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
            ),
            required=("backend", "task"),
            flag_help={
                "num_envs": "envs stepped at once in the timed windows",
                "horizon": "env steps per timed window",
            },
            defaults={"num_envs": 64, "horizon": 32, "windows": 5},
            own_flags=(
                (
                    "--against",
                    {
                        "type": one_line,
                        "metavar": "BACKEND",
                        "help": "also time BACKEND (its default options; same task, envs and seed) window by window "
                        "in this process, alternating, and report this adapter's speed with gradients as a share "
                        "of BACKEND's",
                    },
                ),
                (
                    "--grad-cost-only",
                    {
                        "type": int_in(1, MAX_WORLDS),
                        "metavar": "WORLDS",
                        "help": "finite-difference adapters whose timed windows are out of reach (MuJoCo-Warp soft "
                        "bodies): time one control step of WORLDS worlds and scale it to a step with gradients "
                        "(forward-only windows still timed)",
                    },
                ),
            ),
            differentiates=True,
        ),
        CheckKind(
            "crosscheck",
            60.0,
            "compare backends' gradients of the same loss, start and actions (soft bodies: forward COM paths)",
            "crosscheck",
            flags=("task", "backends", "num_envs", "steps", "seed", "out"),
            required=("task", "backends"),
            flag_help={"num_envs": "envs compared on every engine", "steps": "control steps of each compared segment"},
            defaults={"num_envs": 4},
            targets="backends",
            differentiates=True,
            takes_device=False,
            file_kinds=("crosscheck", "forward-crosscheck"),  # a soft body's compares forward rollouts
        ),
        CheckKind(
            "parity",
            120.0,
            "do two engines simulate the same task: settle, contact and limit probes, open-loop divergence, "
            "random-policy episode lengths (table, plot, JSON)",
            "parity",
            flags=("task", "backends", "preset", "num_envs", "episode_seeds", "steps", "max_steps", "seed", "out"),
            required=("task",),
            flag_help={
                "num_envs": "envs per seed of the settle, probe and episode measurements",
                "steps": "open-loop steps of the trajectory comparison",
                "max_steps": "cap on steps of each random-policy episode",
                "out": "the result file (JSON; its table .md and plot .png beside it)",
            },
            defaults={"num_envs": 64, "steps": 100, "max_steps": 300},
            targets="backends",
            takes_device=False,
        ),
        CheckKind(
            "contact-jacobians",
            300.0,
            "per-step Jacobians at states in contact against a reference (MuJoCo C float64, or Newton's own "
            "differences swept over step sizes), with the same states lifted clear of the ground as a control",
            "contact_jacobians",
            flags=("backend", "task", "preset", "num_envs", "device", "seed", "out", "backend_option"),
            required=("backend", "task"),
            flag_help={"num_envs": "envs per batch of sampled states", "out": _OUT_WITH_TABLE},
            defaults={"num_envs": 8},
            own_flags=(
                (
                    "--states",
                    {
                        "type": int_in(1, MAX_CONTACT_STATES),
                        "default": 200,
                        "help": "states in contact compared (default 200)",
                    },
                ),
                (
                    "--stride",
                    {"type": int_in(1, MAX_STRIDE), "default": 5, "help": "steps between sampled states of an env"},
                ),
                (
                    "--policy-epochs",
                    {
                        "type": int_in(0, MAX_EPOCHS),
                        "default": 30,
                        "help": "half the states come from a SHAC policy trained this many epochs on newton, half "
                        "from random actions (0: all random; default %(default)s)",
                    },
                ),
            ),
            differentiates=True,
        ),
        CheckKind(
            "grad-paths",
            120.0,
            "actor-gradient norms on training's own windows with the policy's feedback path and the critic's "
            "bootstrap path each switched off",
            "grad_paths",
            flags=(
                "backend",
                "task",
                "preset",
                "algo",
                "num_envs",
                "horizon",
                "epochs",
                "seed",
                "device",
                "out",
                "backend_option",
            ),
            required=("backend", "task"),
            flag_help={"epochs": "SHAC epochs whose windows are rolled out four ways", "out": _OUT_WITH_TABLE},
            defaults={"algo": "shac", "num_envs": 16, "horizon": 16, "epochs": 10},
            differentiates=True,
        ),
        CheckKind(
            "scaling",
            300.0,
            "forward and forward+backward env-steps/s over num_envs: CSV and log-log plot",
            "scaling",
            flags=("backend", "task", "horizon", "device", "seed", "windows", "out", "backend_option"),
            required=("backend", "task"),
            flag_help={
                "horizon": "env steps per timed window",
                "windows": "timed windows per env count (the best is kept)",
                "out": "prefix of the .csv, .png and .json written (without it: the table is printed, nothing written)",
            },
            defaults={"horizon": 8, "windows": 3},
            own_flags=(
                (
                    "--envs",
                    {
                        "type": int_in(1, MAX_ENVS),
                        "nargs": "+",
                        "default": [1, 4, 16, 64, 256],
                        "help": "env counts, in increasing order (default: %(default)s)",
                    },
                ),
                (
                    "--max-seconds",
                    {
                        "type": positive_float_up_to(MAX_SECONDS),
                        "default": 600.0,
                        "help": "skip an env count whose predicted measuring time exceeds this (default: %(default)s)",
                    },
                ),
                (
                    "--forward-only",
                    {
                        "action": "store_true",
                        "help": "time forward windows only (env counts whose steps with gradients are out of reach)",
                    },
                ),
            ),
            differentiates=True,
        ),
        CheckKind(
            "fd-schemes",
            150.0,
            "MuJoCo-Warp finite-difference schemes: Jacobian accuracy (float64 reference) vs cost",
            "fd_schemes",
            flags=("task", "num_envs", "seed", "windows", "out"),
            required=("task",),
            flag_help={
                "num_envs": "envs per batch of compared states",
                "windows": "timed steps with gradients (the best is kept)",
                "out": "the result file (PREFIX.json; its table beside it as PREFIX.md)",
            },
            defaults={"num_envs": 8, "windows": 3},
            own_flags=(
                (
                    "--timing-envs",
                    {
                        "type": int_in(0, MAX_ENVS),
                        "default": 16,
                        "help": "envs of the timed step with gradients (0: accuracy only) (default: %(default)s)",
                    },
                ),
                (
                    "--contact-states",
                    {
                        "type": int_in(1, MAX_CONTACT_STATES),
                        "default": 48,
                        "help": "states in contact each setting is compared on (a multiple of --num-envs) "
                        "(default: %(default)s)",
                    },
                ),
                (
                    "--settle",
                    {
                        "type": int_in(0, MAX_STEPS),
                        "default": 30,
                        "help": "zero-action steps before the states in contact are sampled (default: %(default)s)",
                    },
                ),
                (
                    "--schemes",
                    {
                        "nargs": "+",
                        "metavar": "SCHEME",
                        "help": "compare only the grid's rows of these schemes (central, forward, one_sided, "
                        "adaptive, or adjoint: the analytic gradients; the control-step rows come with the default "
                        "scheme, one_sided) (default: every row)",
                    },
                ),
            ),
            targets="simulator",
            differentiates=True,
            takes_device=False,
            only_backend="mujoco_warp",
        ),
        CheckKind(
            "solver-probe",
            120.0,
            "Newton solver/contact settings: forward stability and gradient size",
            "solver_probe",
            flags=("backend", "task", "num_envs", "max_steps", "out"),
            flag_help={
                "num_envs": "envs of the random-action rollout",
                "max_steps": "control steps of each probe rollout",
            },
            defaults={"num_envs": 64, "task": "ant", "max_steps": 1000, "backend": "newton"},
            takes_device=False,
        ),
        CheckKind(
            "peer",
            120.0,
            "a peer simulator's env-steps/s (Rewarped, in its own environment), written with provenance",
            "peers",
            flags=("task", "num_envs", "horizon", "windows", "out"),
            required=("task", "num_envs", "horizon", "out"),
            flag_help={"num_envs": "envs of the peer's timed windows", "horizon": "env steps per timed window"},
            defaults={"windows": 5},
            own_flags=(
                ("--peer", {"default": "rewarped", "help": "the peer simulator (default: %(default)s)"}),
                ("--python", {"help": "the peer environment's interpreter (default: $DIFFSIM_REWARPED_PYTHON)"}),
                (
                    "--peer-arg",
                    {
                        "action": "append",
                        "default": [],
                        "metavar": "WORD",
                        "help": "a further word for the peer's script, e.g. --peer-arg=--nograd-env (repeatable)",
                    },
                ),
            ),
            targets="simulator",
            takes_device=False,
        ),
    )
}

#: every check kind's name, in the order the docs list them
CHECK_KINDS = tuple(KINDS)

#: the check kind that writes each kind of result file
BY_FILE_KIND: dict[str, CheckKind] = {f: k for k in KINDS.values() for f in k.file_kinds or (k.name,)}
