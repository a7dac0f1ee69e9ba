"""Check verbs the suite does not run: ``grad-growth`` (open-loop action-gradient norms along a trained
run's policy) and ``scaling-plot`` (several ``scaling`` CSVs in one plot). The suite's check kinds have
their verbs beside their code, declared in :mod:`harness.checks.kinds`."""

from __future__ import annotations

from harness.inputs import BadInput, check_output


def cmd_grad_growth(args) -> int:
    from pathlib import Path

    from harness.checks.grad_growth import grad_growth, parse_variant
    from harness.results import write_check
    from harness.run.folder import CHECKPOINT, read_config

    read_config(Path(args.run))
    if not (Path(args.run) / CHECKPOINT).exists():
        raise BadInput(f"{args.run} has no checkpoint.pt")
    if args.out:
        check_output(args.out)
    variants = args.variant or [""]
    try:
        for v in variants:
            parse_variant(v)
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    result = grad_growth(args.run, variants, windows=args.windows)
    if args.out:
        print(f"wrote {write_check(args.out, 'grad-growth', result)}")
    return 0


def cmd_scaling_plot(args) -> int:
    from pathlib import Path

    from harness.checks.scaling import plot

    missing = [c for c in args.csv if not Path(c).is_file()]
    if missing:
        raise BadInput(f"no such scaling CSV: {missing[0]}")
    if not args.out.endswith(".png"):
        raise BadInput(f"--out must name a .png file, got {args.out!r}")
    check_output(args.out)
    try:
        print(f"wrote {plot(args.csv, args.out)}")
    except (KeyError, ValueError) as exc:
        raise BadInput(f"not a scaling CSV ({exc}): {' '.join(args.csv)}") from None
    return 0
