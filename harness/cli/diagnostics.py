"""Verbs that check gradients and physics: gradcheck, grad-growth, grad-paths, parity, contact-jacobians, crosscheck."""

from __future__ import annotations

from algorithms.config import ALGORITHMS
from harness.cli.inputs import (
    BadInput,
    check_output,
    make_verb_sim,
    out_stem,
    preflight,
    sim_physics,
)
from harness.results import harness_command


def cmd_gradcheck(args) -> int:
    from harness.checks.gradcheck import DEFAULT_TOLERANCE, gradcheck

    preflight(
        backends=args.backend, task=args.task, device=args.device, out=args.out, memory=(args.num_envs, args.steps)
    )
    sim = make_verb_sim(args, horizon=args.steps)
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
        from harness.results import write_check

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
        print(f"wrote {write_check(args.out, 'gradcheck', summary, harness_command())}")
    return 0 if ok else 1


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


def cmd_grad_paths(args) -> int:
    from harness.checks.grad_paths import grad_paths, table

    if args.algo not in ALGORITHMS:
        raise BadInput(f"unknown algorithm {args.algo!r}; choose from: {', '.join(ALGORITHMS)}")
    memory = (args.num_envs, args.horizon)
    preflight(
        backends=args.backend, task=args.task, device=args.device, preset=args.preset, out=args.out, memory=memory
    )
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
        _write_result_and_table(args.out, "grad-paths", result, text)
    return 0


def cmd_parity(args) -> int:
    from harness.checks.parity import parity, plot, table

    if args.backends is None:  # the two first installed engines that drive the task
        from harness.envs import engines_for

        preflight(task=args.task)
        args.backends = engines_for(args.task)[:2]
    if len(set(args.backends)) < 2:
        raise BadInput(f"parity compares two different backends, got {' '.join(args.backends)}")
    preflight(backends=args.backends, task=args.task, preset=args.preset, out=args.out, memory=(args.num_envs, 0))
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
        from pathlib import Path

        print(f"wrote {plot(result, Path(out_stem(args.out)).with_suffix('.png'))}")
        _write_result_and_table(args.out, "parity", result, text)

    return 0


def _write_result_and_table(out: str, kind: str, result: dict, text: str):
    """``STEM.md`` (``text``), then ``STEM.json`` (the check file; last, since a suite counts the check
    done when it exists), STEM being ``out`` without a ``.json`` suffix (:func:`out_stem`)."""
    from pathlib import Path

    from harness.results import atomic_write_text, write_check

    stem = Path(out_stem(out))
    print(f"wrote {atomic_write_text(stem.with_suffix('.md'), text)}")
    print(f"wrote {write_check(stem.with_suffix('.json'), kind, result, harness_command())}")


def cmd_contact_jacobians(args) -> int:
    from backends.contract import BackendError
    from harness.checks.contact_jacobians import contact_jacobians, table

    preflight(
        backends=args.backend,
        task=args.task,
        device=args.device,
        preset=args.preset,
        out=args.out,
        memory=(args.num_envs, 1),
    )
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
    except (ValueError, BackendError) as exc:  # a task or an option the adapter cannot take
        raise BadInput(str(exc)) from None
    text = table(result)
    print(text)
    if args.out:
        _write_result_and_table(args.out, "contact-jacobians", result, text)
    return 0


def cmd_crosscheck(args) -> int:
    import json

    from harness.checks.crosscheck import crosscheck, forward_crosscheck
    from harness.results import write_check

    if len(set(args.backends)) < 2 or len(set(args.backends)) != len(args.backends):
        raise BadInput(f"--backends needs two or more different backends to compare, got {' '.join(args.backends)}")
    preflight(backends=args.backends, task=args.task, out=args.out, memory=(args.num_envs, args.steps))
    from tasks import task_class

    if task_class(args.task).layout.num_particles:  # soft bodies: forward rollouts (module docstring)
        kind = "forward-crosscheck"
        report = forward_crosscheck(args.task, args.backends, num_envs=args.num_envs, steps=args.steps, seed=args.seed)
        print(json.dumps(report["pairs"], indent=2))
    else:
        kind = "crosscheck"
        report = crosscheck(args.task, args.backends, num_envs=args.num_envs, steps=args.steps, seed=args.seed)
        print(json.dumps(report["segments"], indent=2))
    if args.out:
        print(f"wrote {write_check(args.out, kind, report)}")
    return 0
