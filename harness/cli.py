"""``python -m harness VERB ...``: the benchmark's command line.

Verbs: ``list`` (backends and tasks), ``gradcheck`` (autograd vs finite differences),
``throughput`` (env-steps/s forward-only and forward+backward).
Bad input (unknown backend/task, invalid numbers) prints one ``error:`` line and exits 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

EXIT_BAD_INPUT = 2


class BadInput(Exception):
    """User input we refuse: reported as one line, exit code 2."""


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not value > 0.0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return value


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors as a single line with exit code 2."""

    def error(self, message: str):
        raise BadInput(f"{self.prog}: {message}")


def _add_sim_args(p: argparse.ArgumentParser, num_envs: int) -> None:
    p.add_argument("--backend", required=True, help="adapter name (see `list`)")
    p.add_argument("--task", required=True, help="task name (see `list`)")
    p.add_argument("--num-envs", type=_positive_int, default=num_envs)
    p.add_argument("--device", default="cpu", help="torch/warp device, e.g. cpu or cuda:0")
    p.add_argument("--seed", type=int, default=0)


def _add_algo_overrides(p: argparse.ArgumentParser) -> None:
    """One flag per hyperparameter of AlgoConfig (``--actor-lr``, ``--lambda-batches`` = b_lambda, ...)."""
    from algorithms.config import AlgoConfig

    group = p.add_argument_group("hyperparameter overrides (default: the algorithm's preset)")
    for f in dataclasses.fields(AlgoConfig):
        if f.name in ("algo", "extra"):
            continue
        flag = "--" + f.name.replace("_", "-")
        default = f.default
        if isinstance(default, bool):
            group.add_argument(flag, type=_bool, default=None, metavar="{true,false}")
        elif isinstance(default, tuple):
            kind = type(default[0])
            group.add_argument(flag, type=kind, nargs=len(default) if kind is float else "+", default=None)
        elif f.name in ("num_envs", "horizon"):
            group.add_argument(flag, type=_positive_int, default=None)
        elif isinstance(default, int | float) or default is None:
            group.add_argument(flag, type=_number, default=None)
        else:
            group.add_argument(flag, type=str, default=None)


def _bool(text: str) -> bool:
    if text.lower() in ("1", "true", "yes"):
        return True
    if text.lower() in ("0", "false", "no"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return int(value) if value.is_integer() and "." not in text and "e" not in text.lower() else value


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="python -m harness", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="verb", required=True, parser_class=_Parser)

    sub.add_parser("list", help="registered backends and tasks")

    p = sub.add_parser("gradcheck", help="compare autograd gradients with central finite differences")
    _add_sim_args(p, num_envs=2)
    p.add_argument("--steps", type=_positive_int, default=8, help="control steps in the rollout")
    p.add_argument("--tolerance", type=_positive_float, default=None, help="max relative error allowed")
    p.add_argument(
        "--with-contact",
        action="store_true",
        help="start from the task's own initial height (contact) instead of a contact-free segment in the air",
    )

    p = sub.add_parser("train", help="train an algorithm; writes config.json, metrics.jsonl, checkpoints")
    p.add_argument("--backend", help="adapter name (see `list`)")
    p.add_argument("--task", help="task name (see `list`)")
    p.add_argument("--algo", help="one of: shac, shac-tdfixed, shac-tdadpt, sapo, sapo-tdfixed, sapo-tdadpt")
    p.add_argument("--device", default="cpu")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--epochs", type=_positive_int, default=None, help="total epochs (with --resume: a new total)")
    p.add_argument("--out", help="run directory to create")
    p.add_argument("--resume", metavar="DIR", help="continue the interrupted run in DIR")
    p.add_argument("--checkpoint-every", type=_positive_int, default=5)
    _add_algo_overrides(p)

    p = sub.add_parser("eval", help="evaluate a run's final (and initial) policy; writes DIR/eval.json")
    p.add_argument("--run", required=True, help="run directory written by `train`")
    p.add_argument("--seeds", type=_positive_int, default=10)
    p.add_argument("--num-envs", type=_positive_int, default=None, help="default: twice the training env count")
    p.add_argument("--max-steps", type=_positive_int, default=None, help="cap on steps per episode")

    p = sub.add_parser("report", help="table (md, csv) and curves (png) from run directories")
    p.add_argument("--runs", nargs="+", required=True, help="run directories written by `train`")
    p.add_argument("--out", required=True, help="output prefix, e.g. results/ant_newton_shac_vs_tdadpt")
    p.add_argument("--no-plot", action="store_true")

    p = sub.add_parser("sweep", help="train (or resume) and evaluate several algorithms, then report")
    p.add_argument("--backend", required=True)
    p.add_argument("--task", required=True)
    p.add_argument("--algos", nargs="+", required=True)
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--epochs", type=_positive_int, required=True)
    p.add_argument("--num-envs", type=_positive_int, default=64)
    p.add_argument("--horizon", type=_positive_int, default=32)
    p.add_argument("--device", default="cpu")
    p.add_argument("--eval-seeds", type=_positive_int, default=10)
    p.add_argument("--eval-max-steps", type=_positive_int, default=None)
    p.add_argument("--out", required=True, help="directory for the runs and the report")

    p = sub.add_parser("grad-growth", help="open-loop action-gradient norms along a run's policy trajectories")
    p.add_argument("--run", required=True)
    p.add_argument("--variant", action="append", default=None, help="physics changes, e.g. contact_kf=300")
    p.add_argument("--windows", type=_positive_int, default=3)
    p.add_argument("--out", default=None)

    p = sub.add_parser("crosscheck", help="compare backends' gradients of the same loss, start and actions")
    p.add_argument("--task", required=True)
    p.add_argument("--backends", nargs="+", required=True)
    p.add_argument("--num-envs", type=_positive_int, default=4)
    p.add_argument("--steps", type=_positive_int, default=8)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None)

    p = sub.add_parser("throughput", help="env-steps/s forward-only and forward+backward")
    _add_sim_args(p, num_envs=64)
    p.add_argument("--horizon", type=_positive_int, default=32, help="steps per window (graph cut after each)")
    p.add_argument("--windows", type=_positive_int, default=5, help="timed windows per variant (best is kept)")
    p.add_argument("--out", default=None, help="write the result as JSON here (with the command that made it)")
    return parser


def _make_sim(args, **options):
    # Imports here, not at module level: `list` and argument errors must not load an engine.
    import backends
    from tasks import make_task

    task = make_task(args.task)
    cls = backends.get(args.backend)
    try:
        return cls(task, num_envs=args.num_envs, device=args.device, seed=args.seed, **options)
    except (RuntimeError, ValueError) as exc:
        raise BadInput(f"cannot build {args.backend}/{args.task} on {args.device}: {exc}") from exc


def _validate_names(args) -> None:
    import backends
    import tasks

    if args.backend not in backends.available():
        raise BadInput(f"unknown backend {args.backend!r}; choose from: {', '.join(backends.available())}")
    if args.task not in tasks.available():
        raise BadInput(f"unknown task {args.task!r}; choose from: {', '.join(tasks.available())}")


def cmd_list(args) -> int:
    import backends
    import tasks

    print("backends: " + ", ".join(backends.available()))
    print("tasks:    " + ", ".join(tasks.available()))
    return 0


def cmd_gradcheck(args) -> int:
    from harness.gradcheck import DEFAULT_TOLERANCE, gradcheck

    _validate_names(args)
    sim = _make_sim(args)
    tolerance = args.tolerance or DEFAULT_TOLERANCE
    start_height = None
    if not args.with_contact and sim.layout.floating_base:
        start_height = 2.0  # high enough that `steps` of free fall never reach the ground
    segment = "with contact" if start_height is None else f"contact-free (root lifted to {start_height} m)"
    print(f"gradcheck {args.backend}/{args.task}: {args.num_envs} envs, {args.steps} steps, {segment}", flush=True)
    result = gradcheck(sim, steps=args.steps, seed=args.seed, start_height=start_height)
    print(f"  d loss / d actions:        max relative error {result.action_rel_error:.3e}")
    print(f"  d loss / d initial state:  max relative error {result.state_rel_error:.3e}")
    ok = result.max_rel_error <= tolerance
    print(f"max relative error {result.max_rel_error:.3e} (tolerance {tolerance:.1e}): {'PASS' if ok else 'FAIL'}")
    return 0 if ok else 1


def cmd_throughput(args) -> int:
    from harness.results import provenance, write_json
    from harness.throughput import measure

    _validate_names(args)
    sim = _make_sim(args, max_graph_steps=max(64, args.horizon))
    bare = getattr(sys.modules[type(sim).__module__], "bare_tape_rollout", None)
    print(f"throughput {args.backend}/{args.task}: {args.num_envs} envs, windows of {args.horizon} steps", flush=True)
    result = measure(sim, horizon=args.horizon, windows=args.windows, seed=args.seed, bare=bare)
    print(f"  forward only:        {result.forward_steps_per_s:10.0f} env-steps/s")
    print(f"  forward + backward:  {result.forward_backward_steps_per_s:10.0f} env-steps/s")
    print(f"  gradient cost:       {result.gradient_cost_factor:10.2f} x a forward-only step")
    if result.bare_engine_steps_per_s is not None:
        print(f"  bare engine tape:    {result.bare_engine_steps_per_s:10.0f} env-steps/s (forward + backward)")
        print(f"  adapter / bare time: {result.overhead_ratio:10.3f}")
    if args.out:
        path = write_json(args.out, {"result": result.as_dict(), "provenance": provenance()})
        print(f"wrote {path}")
    return 0


def _algo_config(args):
    from algorithms.config import AlgoConfig, preset

    try:
        cfg = preset(args.algo)
    except KeyError as exc:
        raise BadInput(exc.args[0]) from None
    changes = {}
    for f in dataclasses.fields(AlgoConfig):
        value = getattr(args, f.name, None)
        if value is not None and f.name not in ("algo", "extra"):
            changes[f.name] = tuple(value) if isinstance(value, list) else value
    try:
        return cfg.replace(**changes)
    except ValueError as exc:
        raise BadInput(f"bad configuration: {exc}") from None


def cmd_train(args) -> int:
    from harness.train import RunError, train

    command = "python -m harness " + " ".join(sys.argv[1:])
    try:
        if args.resume:
            from algorithms.config import AlgoConfig

            train(
                args.resume,
                "",
                "",
                AlgoConfig(),
                args.epochs or 0,
                resume=True,
                checkpoint_every=args.checkpoint_every,
                command=command,
            )
            return 0
        missing = [name for name in ("backend", "task", "algo", "epochs", "out") if getattr(args, name) is None]
        if missing:
            raise BadInput("train needs " + ", ".join("--" + m for m in missing) + " (or --resume DIR)")
        _validate_names(args)
        cfg = _algo_config(args)
        train(
            args.out,
            args.task,
            args.backend,
            cfg,
            args.epochs,
            seed=args.seed,
            device=args.device,
            checkpoint_every=args.checkpoint_every,
            command=command,
        )
    except RunError as exc:
        raise BadInput(str(exc)) from None
    return 0


def cmd_eval(args) -> int:
    from pathlib import Path

    from harness.train import evaluate

    if not (Path(args.run) / "config.json").exists():
        raise BadInput(f"{args.run} is not a run directory (no config.json)")
    result = evaluate(args.run, seeds=args.seeds, num_envs=args.num_envs, max_steps=args.max_steps)
    print(f"initial policy: mean return {result['initial']['mean_return']:.1f}")
    print(
        f"final policy:   mean return {result['final']['mean_return']:.1f} "
        f"(std over {args.seeds} seeds {result['final']['std_over_seeds']:.1f})"
    )
    print(f"wrote {Path(args.run) / 'eval.json'}")
    return 0


def cmd_report(args) -> int:
    from pathlib import Path

    from harness.report import plot_curves, summarize, write_table

    runs = [Path(r) for r in args.runs]
    missing = [str(r) for r in runs if not (r / "config.json").exists()]
    if missing:
        raise BadInput(f"not run directories (no config.json): {', '.join(missing)}")
    command = "python -m harness " + " ".join(sys.argv[1:])
    md, csv = write_table([summarize(r) for r in runs], args.out, command)
    print(f"wrote {md} and {csv}")
    if not args.no_plot:
        print(f"wrote {plot_curves(runs, Path(args.out).with_suffix('.png'))}")
    return 0


def cmd_sweep(args) -> int:
    from pathlib import Path

    from harness.report import plot_curves, summarize, write_table
    from harness.train import evaluate, train

    _validate_names(args)
    for name in args.algos:
        args.algo = name
        _algo_config(args)  # refuse a bad name before any training starts
    command = "python -m harness " + " ".join(sys.argv[1:])
    runs = []
    for name in args.algos:
        for seed in args.seeds:
            args.algo = name
            cfg = _algo_config(args).replace(num_envs=args.num_envs, horizon=args.horizon)
            run = Path(args.out) / f"{args.task}_{args.backend}_{name}_s{seed}"
            resume = (run / "config.json").exists()
            print(f"== {run.name}{' (resume)' if resume else ''}", flush=True)
            train(
                run,
                args.task,
                args.backend,
                cfg,
                args.epochs,
                seed=seed,
                device=args.device,
                resume=resume,
                command=command,
            )
            evaluate(run, seeds=args.eval_seeds, max_steps=args.eval_max_steps)
            runs.append(run)
    prefix = Path(args.out) / "summary"
    md, _ = write_table([summarize(r) for r in runs], prefix, command)
    plot_curves(runs, prefix.with_suffix(".png"))
    print(Path(md).read_text())
    return 0


def cmd_grad_growth(args) -> int:
    from pathlib import Path

    from harness.grad_growth import grad_growth, parse_variant
    from harness.results import provenance, write_json

    if not (Path(args.run) / "checkpoint.pt").exists():
        raise BadInput(f"{args.run} has no checkpoint.pt")
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


def cmd_crosscheck(args) -> int:
    import json

    from harness.crosscheck import crosscheck
    from harness.results import provenance, write_json

    for name in args.backends:
        args.backend = name
        _validate_names(args)
    report = crosscheck(args.task, args.backends, num_envs=args.num_envs, steps=args.steps, seed=args.seed)
    print(json.dumps(report["segments"], indent=2))
    if args.out:
        print(f"wrote {write_json(args.out, {**report, 'provenance': provenance()})}")
    return 0


VERBS = {
    "crosscheck": cmd_crosscheck,
    "grad-growth": cmd_grad_growth,
    "report": cmd_report,
    "sweep": cmd_sweep,
    "list": cmd_list,
    "gradcheck": cmd_gradcheck,
    "throughput": cmd_throughput,
    "train": cmd_train,
    "eval": cmd_eval,
}


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        return VERBS[args.verb](args)
    except BadInput as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
