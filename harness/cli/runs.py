"""Verbs of training runs and suites: list, train, eval, report, sweep, bench, bench-run, landscape."""

from __future__ import annotations

from harness.cli.parser import FLAGS
from harness.inputs import (
    BadInput,
    algo_config,
    check_device,
    check_memory,
    check_output,
    preflight,
    validate_names,
)
from harness.results import harness_command


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


def cmd_train(args) -> int:
    from harness.run.train import resume, train

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
        resume(args.resume, args.epochs, checkpoint_every=args.checkpoint_every, command=harness_command())
        return 0
    missing = [name for name in ("backend", "task", "algo", "epochs", "out") if getattr(args, name) is None]
    if missing:
        raise BadInput("train needs " + ", ".join("--" + m.replace("_", "-") for m in missing) + " (or --resume DIR)")
    preflight(backends=args.backend, task=args.task, device=args.device, preset=args.preset)
    cfg = algo_config(args, args.algo)
    check_memory(args.backend, args.task, cfg.num_envs, cfg.horizon, args.device)
    train(
        args.out,
        args.task,
        args.backend,
        cfg,
        args.epochs,
        seed=args.seed,
        device=args.device,
        checkpoint_every=args.checkpoint_every,
        command=harness_command(),
        preset=args.preset,
        backend_options=dict(args.backend_option or []),
    )
    return 0


def cmd_eval(args) -> int:
    from pathlib import Path

    from harness.run.folder import read_config
    from harness.run.train import evaluate

    config = read_config(Path(args.run))
    if args.backend:
        validate_names(args.backend, config["task"])
    if args.out:
        check_output(args.out)
    if args.num_envs:
        check_memory(args.backend or config["backend"], config["task"], args.num_envs, 0, config["device"])
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
    return 0


def cmd_report(args) -> int:
    from pathlib import Path

    from harness.report import write_report
    from harness.run.folder import read_config

    runs = [Path(r) for r in args.runs]
    for run in runs:
        read_config(run)
    check_output(args.out)
    for path in write_report(runs, args.out, harness_command(), plot=not args.no_plot):
        print(f"wrote {path}")
    return 0


def cmd_sweep(args) -> int:
    """Algorithms x seeds of one task and backend: a suite spec made in memory, run by the suite's runner
    (runs addressed and reused as the bench's, tables and plots beside them in OUT)."""
    from pathlib import Path

    from harness.suite.runner import run_suite

    preflight(backends=args.backend, task=args.task, device=args.device)
    for name in args.algos:
        algo_config(args, name)  # refuse bad input before any training
    check_output(args.out, "folder")
    out = Path(args.out).resolve()
    evaluation = {"seeds": args.eval_seeds, **({"max_steps": args.max_steps} if args.max_steps else {})}
    spec = {
        "suite": {"name": out.name, "jobs": args.jobs or 1, "device": args.device},
        "eval": evaluation,
        "train": [
            {
                "backends": [args.backend],
                "tasks": [args.task],
                "algos": list(args.algos),
                "seeds": list(args.seeds),
                "horizons": [args.horizon],
                "epochs": args.epochs,
                "num_envs": args.num_envs,
            }
        ],
    }
    return run_suite(
        command_problem=_command_problem(),
        spec=spec,
        store=out.parent,
        jobs=args.jobs,
        command=harness_command(),
        launcher=args.launcher,
        address=args.address,
        gpus_per_run=args.gpus_per_run,
    )


def _command_problem():
    """What the command line says of a job's words (None: it parses), with one parser for every job."""
    from harness.cli.parser import build_parser

    parser = build_parser()

    def problem(words: list[str]) -> str | None:
        try:
            parser.parse_args([str(w) for w in words])
        except BadInput as exc:
            return str(exc)
        return None

    return problem


def cmd_bench(args) -> int:
    from harness.suite.runner import run_suite

    if args.device:
        check_device(args.device)
    return run_suite(
        command_problem=_command_problem(),
        profile=args.profile,
        spec_file=args.spec,
        store=args.store,
        device=args.device,
        jobs=args.jobs,
        dry_run=args.dry_run,
        report_only=args.report_only,
        command=harness_command(),
        launcher=args.launcher,
        address=args.address,
        gpus_per_run=args.gpus_per_run,
    )


def cmd_readme(args) -> int:
    """README's result blocks made anew from the results (harness/report/readme.py)."""
    from pathlib import Path

    from harness.report.readme import update_readme

    readme = Path(args.readme)
    if not readme.is_file():
        raise BadInput(f"--readme {args.readme}: no such file")
    if not args.check:
        check_output(args.readme)
    changed = update_readme(readme, Path(args.root), check=args.check)
    if args.check and changed:
        print(f"{readme}: block(s) {', '.join(changed)} differ from the results; run python -m harness readme")
        return 1
    print(f"{readme}: {'rewrote ' + ', '.join(changed) if changed else 'every block matches the results'}")
    return 0


def cmd_bench_run(args) -> int:
    from harness.suite.runner import bench_run

    bench_run(args.run_dir)
    return 0


#: the MUJOCO_GL values MuJoCo's renderer takes on Linux (its gl_context); headless: egl or osmesa
RENDER_GL = ("egl", "osmesa", "glfw", "glx", "enable", "enabled", "on", "true", "1", "")


def cmd_render(args) -> int:
    import os
    from pathlib import Path

    os.environ.setdefault("MUJOCO_GL", "egl")  # before anything imports MuJoCo: headless rendering
    if os.environ["MUJOCO_GL"].lower().strip() not in RENDER_GL:
        shown = ", ".join(g for g in RENDER_GL if g)
        raise BadInput(f"MUJOCO_GL={os.environ['MUJOCO_GL']!r}: render draws with one of {shown}")
    from harness.run.folder import read_config
    from harness.run.render import compared_backends, render

    config = read_config(Path(args.run))
    trained_on = config["backend"]
    if args.compare and args.backend:
        raise BadInput("--compare shows both engines; drop --backend")
    if args.backend:
        validate_names(args.backend, None)
    shown = compared_backends(trained_on, config["task"]) if args.compare else [args.backend or trained_on]
    render(args.run, shown, args.max_steps or 300, args.frames)
    return 0


def cmd_landscape(args) -> int:
    from pathlib import Path

    from harness.checks.landscape import compute_landscape, write_landscape
    from harness.report.plots import plot_landscape
    from harness.run.folder import read_config

    config = read_config(Path(args.run))
    if args.num_envs:  # one window of the run's h steps per point, no backward pass
        check_memory(config["backend"], config["task"], args.num_envs, 0, config["device"])
    result = compute_landscape(
        args.run, grid=args.grid, span=args.span, num_envs=args.num_envs, seed=args.seed, warmup_steps=args.warmup_steps
    )
    print(f"wrote {write_landscape(args.run, result)}")
    print(f"wrote {plot_landscape(result, Path(args.run) / 'landscape.png')}")
    r = result["roughness"]
    shown = {k: "n/a (non-finite points)" if r.get(k) is None else f"{r[k]:.3f}" for k in ("h_step", "td_lambda")}
    print(f"roughness: h-step {shown['h_step']}, TD-lambda {shown['td_lambda']}")
    return 0


def cmd_step_gain(args) -> int:
    from pathlib import Path

    from harness.checks.step_gain import compute_step_gain, write_step_gain
    from harness.run.folder import read_config

    config = read_config(Path(args.run))
    # one window of the run's h steps with its graph kept, every env
    check_memory(config["backend"], config["task"], args.num_envs, config["algo_config"].horizon, config["device"])
    result = compute_step_gain(args.run, states=args.states, num_envs=args.num_envs, stride=args.stride, seed=args.seed)
    print(f"wrote {write_step_gain(args.run, result)}")
    gain, growth = result["summary"]["state_gain"], result["window"]["per_step_growth"]
    print(
        f"one-step state gain: median {gain['median']:.3g}, p95 {gain['p95']:.3g} "
        f"(bound 1/(gamma lambda) = {result['paper_bound']:.4f}); "
        f"growth per step over a window of {result['window']['steps']}: median {growth['median']:.3g}"
    )
    return 0
