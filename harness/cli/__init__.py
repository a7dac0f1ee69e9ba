"""``python -m harness VERB ...``: the benchmark's command line.

Verbs, by module: :mod:`harness.cli.runs` (``list``, ``train`` and ``train --resume DIR``, ``eval``,
``report``, ``sweep``, ``bench`` the suite, ``bench-run`` one of its runs, ``landscape``, ``step-gain``,
``render``, ``readme``), every check kind the suite runs (``gradcheck``, ``throughput``, ``crosscheck``,
``parity``, ``contact-jacobians``, ``grad-paths``, ``scaling``, ``fd-schemes``, ``solver-probe``,
``peer``: flags and verb declared in :mod:`harness.checks.kinds`, the verb beside the check's code) and
:mod:`harness.cli.other_checks` (``grad-growth``, ``scaling-plot``). Every flag is declared once
in :data:`harness.cli.parser.FLAGS` (type, default, help) and every hyperparameter flag is generated
from :class:`algorithms.config.AlgoConfig`, whose field docs are the ``--help`` text. Bad input (an
unknown backend or task, an invalid number or configuration) prints one ``error:`` line and exits 2
(:mod:`harness.inputs`).

Why argparse and not tyro (the CLI library CleanRL uses): tyro reports a bad value in a
nine-line framed panel (measured with tyro 1.0.17 on ``--critic-iterations 2.5``), which breaks the
one-line ``error:`` + exit 2 contract; generating the flags from the dataclass gives the same
single source of truth.
"""

from __future__ import annotations

import sys

from harness.checks.kinds import KINDS
from harness.cli.other_checks import cmd_grad_growth, cmd_scaling_plot
from harness.cli.parser import FLAGS, build_parser
from harness.cli.runs import (
    cmd_bench,
    cmd_bench_run,
    cmd_eval,
    cmd_landscape,
    cmd_list,
    cmd_readme,
    cmd_render,
    cmd_report,
    cmd_step_gain,
    cmd_sweep,
    cmd_train,
)
from harness.inputs import EXIT_BAD_INPUT, BadInput

__all__ = ["FLAGS", "BadInput", "build_parser", "main"]

VERBS = {
    "list": cmd_list,
    "train": cmd_train,
    "eval": cmd_eval,
    "report": cmd_report,
    "sweep": cmd_sweep,
    "bench": cmd_bench,
    "bench-run": cmd_bench_run,
    "readme": cmd_readme,
    "landscape": cmd_landscape,
    "step-gain": cmd_step_gain,
    "render": cmd_render,
    "grad-growth": cmd_grad_growth,
    "scaling-plot": cmd_scaling_plot,
    **{name: kind.run for name, kind in KINDS.items()},  # each check kind's verb, from its registry entry
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
