"""Verbs that measure speed and settings: throughput, solver-probe, peer, fd-schemes, scaling, scaling-plot."""

from __future__ import annotations

from harness.cli.inputs import (
    BadInput,
    check_device,
    check_memory,
    check_output,
    make_verb_sim,
    out_stem,
    preflight,
    sim_physics,
    validate_names,
)
from harness.results import harness_command


def cmd_throughput(args) -> int:
    from harness.checks.throughput import measure
    from harness.results import write_check

    memory = (args.num_envs, 0 if args.grad_cost_only else args.horizon)
    preflight(backends=args.backend, task=args.task, device=args.device, out=args.out, memory=memory)
    sim = make_verb_sim(args, horizon=args.horizon)
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
        path = write_check(args.out, "throughput", {**result.as_dict(), **sim_physics(sim)})
        print(f"wrote {path}")
    return 0


def _grad_cost_only(sim, args) -> int:
    """``throughput --grad-cost-only WORLDS``: forward windows as usual, the step with gradients estimated."""
    from harness.checks.throughput import forward_rate
    from harness.results import write_check

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
        print(f"wrote {write_check(args.out, 'throughput', result)}")
    return 0


def cmd_solver_probe(args) -> int:
    from harness.checks.solver_probe import run_probe

    preflight(backends=args.backend, task=args.task, out=args.out, memory=(args.num_envs, 0))
    if args.task not in ("ant", "go2", "soft_jumper"):
        raise BadInput(f"solver-probe has candidates for the tasks ant, go2 and soft_jumper, not {args.task!r}")
    run_probe(
        num_envs=args.num_envs,
        out=args.out,
        command=harness_command(),
        task=args.task,
        steps=args.max_steps,
        backend=args.backend,
    )
    return 0


def cmd_peer(args) -> int:
    from harness.checks.peers import PEER_TASKS, PEERS, PeerUnavailable, run_peer
    from harness.results import write_check

    if args.peer not in PEERS:
        raise BadInput(f"unknown peer {args.peer!r}; choose from: {', '.join(PEERS)}")
    if args.task not in PEER_TASKS[args.peer]:
        raise BadInput(f"{args.peer} has the tasks {', '.join(PEER_TASKS[args.peer])}, not {args.task!r}")
    check_output(args.out)
    words = ["--num-envs", str(args.num_envs), "--horizon", str(args.horizon), "--windows", str(args.windows)]
    try:
        result = run_peer(args.peer, args.task, words + list(args.peer_arg), python=args.python)
    except PeerUnavailable as exc:
        raise BadInput(str(exc)) from None
    print(f"wrote {write_check(args.out, 'peer', result)}")
    return 0


def cmd_fd_schemes(args) -> int:
    from harness.results import atomic_write_text, write_check

    validate_names("mujoco_warp", args.task)
    from tasks import task_class

    if task_class(args.task).layout.num_particles:
        raise BadInput("fd-schemes compares schemes on articulated tasks (ant, go2); soft bodies have no C reference")
    from backends.mujoco_warp.adapter import FD_SCHEMES

    if args.contact_states % args.num_envs:
        raise BadInput(
            f"--contact-states {args.contact_states} is not a multiple of --num-envs {args.num_envs}: "
            "the states are compared in batches of the envs"
        )
    choices = (*FD_SCHEMES, "adjoint")  # "adjoint": the analytic gradients' row
    unknown = sorted(set(args.schemes or ()) - set(choices))
    if unknown:
        raise BadInput(f"--schemes: unknown scheme {unknown[0]!r}; choose from {', '.join(choices)}")
    prefix = out_stem(args.out) if args.out else None  # PREFIX or PREFIX.json: both files
    memory = (max(args.num_envs, args.timing_envs), 1)
    preflight(backends="mujoco_warp", task=args.task, out=prefix and prefix + ".json", memory=memory)
    from harness.checks.fd_schemes import fd_schemes, markdown

    print(f"fd-schemes mujoco_warp/{args.task}: accuracy on {args.num_envs} envs, cost at {args.timing_envs} envs")
    from backends.contract import BackendError

    try:
        report = fd_schemes(
            args.task,
            num_envs=args.num_envs,
            timing_envs=args.timing_envs,
            windows=args.windows,
            seed=args.seed,
            settle=args.settle,
            contact_states=args.contact_states,
            schemes=tuple(args.schemes) if args.schemes else None,
        )
    except BackendError as exc:  # a task MuJoCo-Warp cannot build
        raise BadInput(f"fd-schemes on {args.task}: {exc}") from None
    if prefix:  # the JSON last: a suite counts the check done when it exists
        print(f"wrote {atomic_write_text(prefix + '.md', markdown(report, harness_command()))}")
        print(f"wrote {write_check(prefix + '.json', 'fd-schemes', report)}")
    return 0


def cmd_scaling(args) -> int:
    from harness.checks.scaling import scaling, to_csv, write
    from harness.results import provenance, write_check

    validate_names(args.backend, args.task)
    check_device(args.device)
    if sorted(args.envs) != list(args.envs) or len(set(args.envs)) != len(args.envs):
        raise BadInput(f"--envs must be distinct and increasing, got {args.envs}")
    out = out_stem(args.out) if args.out else None  # without --out, as every measuring verb: print, write nothing
    if out:
        check_output(out + ".csv")
    check_memory(
        args.backend, args.task, args.envs[-1], 0 if args.forward_only else args.horizon, args.device, "--envs"
    )
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
    if not out:
        print(to_csv(rows, harness_command(), prov), end="")
        return 0
    for path in write(rows, out, harness_command(), prov):
        print(f"wrote {path}")
    result = {"backend": args.backend, "task": args.task, "rows": rows}
    print(f"wrote {write_check(out + '.json', 'scaling', result)}")
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
