"""Accuracy versus cost of the MuJoCo-Warp adapter's gradients, with and without contact.

Each row of ``GRID`` is a set of the adapter's options: the analytic adjoint (``gradients=adjoint``),
or a finite-difference scheme (``fd_scheme``: central, forward, one_sided or adaptive differences),
the steps (``fd_eps_state``, ``fd_eps_control``) and the perturbed worlds' solver
settings (``fd_warmstart``: each world's own warm start from zero, or the nominal world's carried
into its perturbed worlds at every substep; ``fd_tolerance``: the perturbed worlds' solver tolerance,
0 running the full iteration count). Every row is compared on the same states with the float64 MuJoCo
C reference (:mod:`backends.mujoco_warp.reference`: central differences with a 1e-6 step, solver
tolerance 0), by the relative Frobenius error of one control step's Jacobian (state and control
columns together):

* contact-free: the task's initial states lifted to 2 m (the segment ``gradcheck`` uses), where the
  step is smooth and the reference is exact: the maximum over ``num_envs`` envs;
* in contact: ``contact_states`` states sampled from random rollouts and kept where MuJoCo C finds a
  contact (:func:`harness.checks.contact_jacobians.sample_contact_states`, as the in-contact check samples
  them): the median, the share within 5%, and the median over the states whose friction sticks
  (where the step is smooth at the reference's scale; where it slides or a contact is made or
  broken, no finite step is exact).

Each error is also split by the kind of column (positions, velocities, controls: the relative error
of that block), since each kind has its own step. The grid varies the position and velocity steps;
the control step is varied after it, at the adapter's default scheme, by the factors of
``CONTROL_FACTORS`` around the task's default control step (N m for torques, rad for position
targets).

Cost: the seconds of one control step with gradients and its backward pass (what a training step pays;
best of ``windows`` after a warm-up) for ``timing_envs`` envs on the ground, and the worlds it steps (for
``adaptive``, its nominal and +eps worlds plus the mean share of -eps worlds it added in contact).
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch

from backends import make
from backends.mujoco_warp.adapter import fd_settings
from backends.mujoco_warp.reference import accurate_model, classify_step, float64_step_jacobians
from harness.formatting import markdown_table
from tasks import make_task

#: the adapter options of each measured row (the control step stays at the adapter's default)
GRID = (
    {"fd_scheme": "central", "fd_eps_state": 1e-2, "fd_eps_velocity": 1e-2},
    {"fd_scheme": "central", "fd_eps_state": 2e-3, "fd_eps_velocity": 2e-3},
    {"fd_scheme": "central", "fd_eps_state": 5e-4, "fd_eps_velocity": 5e-4},
    {"fd_scheme": "central", "fd_eps_state": 5e-4, "fd_eps_velocity": 1e-2},
    {"fd_scheme": "forward", "fd_eps_state": 2e-3, "fd_eps_velocity": 2e-3},
    {
        "fd_scheme": "forward",
        "fd_eps_state": 2e-3,
        "fd_eps_velocity": 2e-3,
        "fd_warmstart": "nominal",
        "fd_tolerance": 0.0,
    },
    {"fd_scheme": "forward", "fd_eps_state": 1e-3, "fd_eps_velocity": 1e-3},
    {"fd_scheme": "forward", "fd_eps_state": 5e-4, "fd_eps_velocity": 5e-4},
    {"fd_scheme": "forward", "fd_eps_state": 5e-4, "fd_eps_velocity": 2e-3},
    {"fd_scheme": "forward", "fd_eps_state": 2e-3, "fd_eps_velocity": 5e-4},
    {"fd_scheme": "forward", "fd_eps_state": 2.5e-4, "fd_eps_velocity": 2.5e-4},
    {"fd_scheme": "forward", "fd_eps_state": 2.5e-4, "fd_eps_velocity": 2e-3},
    {"fd_scheme": "forward", "fd_eps_state": 2.5e-4, "fd_eps_velocity": 1e-2},
    {
        "fd_scheme": "forward",
        "fd_eps_state": 2.5e-4,
        "fd_eps_velocity": 1e-2,
        "fd_warmstart": "nominal",
        "fd_tolerance": 0.0,
    },
    {"fd_scheme": "forward", "fd_eps_state": 2.5e-4, "fd_eps_velocity": 3e-2},
    {"fd_scheme": "one_sided", "fd_eps_state": 5e-4, "fd_eps_velocity": 5e-4},  # the adapter's default
    {"fd_scheme": "one_sided", "fd_eps_state": 5e-4, "fd_eps_velocity": 1e-2},
    {"fd_scheme": "one_sided", "fd_eps_state": 2.5e-4, "fd_eps_velocity": 1e-2},
    {"fd_scheme": "adaptive", "fd_eps_state": 2.5e-4, "fd_eps_velocity": 2.5e-4},
    {"fd_scheme": "adaptive", "fd_eps_state": 2.5e-4, "fd_eps_velocity": 1e-2},
    {"fd_scheme": "adaptive", "fd_eps_state": 5e-4, "fd_eps_velocity": 5e-4},
    {"gradients": "adjoint"},  # the analytic gradients, on the same states (no steps to set)
)
#: the control step's rows: the adapter's default settings with the control step times each factor
CONTROL_FACTORS = (0.01, 0.1, 10.0)
#: the column blocks of a step's Jacobian, in the adapter's order
KINDS = ("position", "velocity", "control")


def control_rows(task, factors=CONTROL_FACTORS) -> tuple[dict, ...]:
    """The adapter's default settings for ``task`` with the control step scaled by each factor."""
    default = fd_settings(task, {})
    return tuple({"fd_scheme": default["fd_scheme"], "fd_eps_control": default["fd_eps_control"] * f} for f in factors)


def _references(sim, engine: torch.Tensor, control: torch.Tensor, model) -> list[tuple[np.ndarray, float]]:
    """Per env: the float64 reference Jacobian (state and control columns) of its control step, and its
    state gain (:func:`harness.checks.contact_jacobians.gains`)."""
    from harness.checks.contact_jacobians import gains, tangent_gain_columns

    position_cols, velocity_cols = tangent_gain_columns(sim.layout)
    refs = []
    for i in range(engine.shape[0]):
        _, ref_state, ref_control = float64_step_jacobians(sim, engine[i], control[i], model=model)
        gain = gains(ref_state, sim.layout.nq, position_cols, velocity_cols)["state_gain"]
        refs.append((np.concatenate((ref_state, ref_control), axis=1), gain))
    return refs


def _errors(sim, engine: torch.Tensor, control: torch.Tensor, refs: list[tuple[np.ndarray, float]]) -> list[dict]:
    """Per env: the relative error of the step's whole Jacobian and of each kind's column block, and
    the ratio of its state gain to the reference's."""
    from harness.checks.contact_jacobians import gains, tangent_gain_columns

    _, jac_state, jac_control = sim.step_jacobians(engine, control)
    layout = sim.layout
    nv = layout.nv
    blocks = {"position": slice(0, nv), "velocity": slice(nv, 2 * nv), "control": slice(2 * nv, None)}
    position_cols, velocity_cols = tangent_gain_columns(layout)
    errors = []
    for i, (ref, ref_gain) in enumerate(refs):
        jac = np.concatenate((jac_state[i].numpy(), jac_control[i].numpy()), axis=1)
        row = {"all": float(np.linalg.norm(jac - ref) / np.linalg.norm(ref))}
        for kind, cols in blocks.items():
            row[kind] = float(np.linalg.norm(jac[:, cols] - ref[:, cols]) / np.linalg.norm(ref[:, cols]))
        own = gains(jac_state[i].numpy(), layout.nq, position_cols, velocity_cols)["state_gain"]
        row["gain_ratio"] = own / ref_gain
        errors.append(row)
    return errors


def _contact_free(task, sim, num_envs: int, seed: int):
    gen = torch.Generator().manual_seed(seed)
    q, qd = task.sample_initial_state(num_envs, gen)
    if task.layout.floating_base:
        q[:, 2] = 2.0
    actions = 0.5 * (2.0 * torch.rand(num_envs, task.action_dim, generator=gen) - 1.0)
    return sim.state_from_generalized(q, qd).engine.detach(), task.actions_to_control(actions)


def _contact(task, sim, model, count: int, seed: int, settle: int):
    """(engine states, controls, classes) of ``count`` states in contact, in batches of the sim's envs."""
    from harness.checks.contact_jacobians import contact_predicate, sample_contact_states

    q, qd, actions = sample_contact_states(sim, count, settle, 5, seed, 0.5, contact_predicate(sim, model))
    n = sim.num_envs
    batches = []
    for start in range(0, count - count % n, n):
        engine = sim.state_from_generalized(q[start : start + n], qd[start : start + n]).engine.detach()
        control = task.actions_to_control(actions[start : start + n])
        classes = [classify_step(sim, model, engine[i], control[i]) for i in range(n)]
        batches.append((engine, control, classes, _references(sim, engine, control, model)))
    return batches


def _step_seconds(sim, windows: int) -> float:
    """Best-of-``windows`` seconds of one control step with gradients and its backward pass (a vector-
    Jacobian product), what a training step pays: the finite differences' Jacobians are made in the
    step, the adjoint's work is in the backward pass."""
    engine = sim.state.engine.detach()
    control = sim.task.actions_to_control(torch.zeros(sim.num_envs, sim.task.action_dim))

    def step_and_backward() -> float:
        start = time.perf_counter()
        x, u = engine.clone().requires_grad_(True), control.clone().requires_grad_(True)
        sim.simulate(sim._state_from_engine(x), u).engine.sum().backward()
        return time.perf_counter() - start

    step_and_backward()  # warm-up: kernels, buffers of this many worlds
    return min(step_and_backward() for _ in range(windows))


def _fd_fields(sim) -> dict:
    """A row's gradient settings: the finite differences' scheme and steps, or the adjoint's (none)."""
    names = ("fd_eps_state", "fd_eps_velocity", "fd_eps_control", "fd_warmstart", "fd_tolerance")
    if sim.gradients == "adjoint":
        return {"fd_scheme": "adjoint", **dict.fromkeys(names)}
    return {"fd_scheme": sim.fd_scheme, **{name: getattr(sim, name) for name in names}}


def _worlds_per_env(sim, second_sides: list[float]) -> float:
    """The worlds one env stepped per control step: the scheme's fixed batch, and for ``adaptive`` the
    mean share of -eps worlds it added on the in-contact states (one per coordinate with a switch)."""
    worlds = sim.worlds_per_env_with_grad
    if sim.gradients == "adjoint" or sim.fd_scheme != "adaptive" or not second_sides:
        return float(worlds)
    return worlds + float(np.mean(second_sides)) * (worlds - 1)


def _scheme(options: dict) -> str:
    """A grid row's scheme: its ``fd_scheme``, or ``adjoint`` for the analytic gradients."""
    return "adjoint" if options.get("gradients") == "adjoint" else options.get("fd_scheme")


def _label(options: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in options.items())


def fd_schemes(
    task_name: str,
    num_envs: int = 8,
    contact_states: int = 48,
    timing_envs: int = 16,
    windows: int = 3,
    seed: int = 0,
    settle: int = 30,
    grid=GRID,
    control_factors=CONTROL_FACTORS,
    progress=print,
    schemes: tuple[str, ...] | None = None,
) -> dict:
    """One row per option set of ``grid``, then one per control-step factor; see the module
    docstring. ``contact_states`` is rounded down to a multiple of ``num_envs``. ``schemes``: only the
    rows of these schemes (the control-step rows, the default scheme's, when it is among them)."""
    task = make_task(task_name)
    if schemes is not None:
        grid = [options for options in grid if _scheme(options) in schemes]
        if fd_settings(task, {})["fd_scheme"] not in schemes:
            control_factors = ()
    sampler = make("mujoco_warp", task, num_envs=num_envs, seed=seed)
    model = accurate_model(sampler.mjm)
    free, free_control = _contact_free(task, sampler, num_envs, seed)
    free_refs = _references(sampler, free, free_control, model)
    batches = _contact(task, sampler, model, contact_states, seed, settle) if contact_states else []
    rows = []
    for options in tuple(grid) + control_rows(task, control_factors):
        sim = make("mujoco_warp", task, num_envs=num_envs, seed=seed, **options)
        free_errors = [e["all"] for e in _errors(sim, free, free_control, free_refs)]
        contact_errors, sticking, second_sides = [], [], []
        for engine, control, classes, refs in batches:
            errors = _errors(sim, engine, control, refs)
            if sim.gradients == "fd" and sim.fd_scheme == "adaptive":
                second_sides.append(sim.second_side_share)
            contact_errors += errors
            sticking += [e["all"] for e, c in zip(errors, classes, strict=True) if c["sticking"] and not c["onset"]]
        seconds = float("nan")
        if timing_envs:
            timed = make("mujoco_warp", task, num_envs=timing_envs, seed=seed, **options)
            timed.reset()
            with torch.no_grad():
                for _ in range(settle):
                    timed.step(torch.zeros(timing_envs, task.action_dim))
            seconds = _step_seconds(timed, windows)
        contact = np.asarray([e["all"] for e in contact_errors])
        row = {
            "options": dict(options),
            **_fd_fields(sim),
            "worlds_per_env": _worlds_per_env(sim, second_sides),
            "contact_free_error_max": float(max(free_errors)),
            "contact_states": int(contact.size),
            "contact_error_median": float(np.median(contact)) if contact.size else float("nan"),
            "contact_within_5pct": float(np.mean(contact <= 0.05)) if contact.size else float("nan"),
            # a quotient across a contact switch is a jump over the step: a gain far above the reference's
            "contact_spurious_gain_share": float(np.mean([e["gain_ratio"] > 2.0 for e in contact_errors]))
            if contact.size
            else float("nan"),
            "contact_gain_ratio_max": max((e["gain_ratio"] for e in contact_errors), default=float("nan")),
            "contact_error_median_by_kind": {
                kind: float(np.median([e[kind] for e in contact_errors])) if contact.size else float("nan")
                for kind in KINDS
            },
            "sticking_states": len(sticking),
            "sticking_error_median": float(np.median(sticking)) if sticking else float("nan"),
            "timing_envs": timing_envs,
            "seconds_per_step_with_grad": seconds,
            "env_steps_per_s_with_grad": timing_envs / seconds if timing_envs else float("nan"),
        }
        progress(
            f"  {_label(options)}: {row['worlds_per_env']:.4g} worlds/env, "
            f"contact-free max {row['contact_free_error_max']:.1e}, "
            f"in contact median {row['contact_error_median']:.2g} ({row['contact_within_5pct']:.0%} within 5%; "
            + "/".join(f"{v:.2g}" for v in row["contact_error_median_by_kind"].values())
            + " by position/velocity/control columns; "
            + f"{row['contact_spurious_gain_share']:.0%} of states with a gain over 2x the reference's), "
            f"sticking median {row['sticking_error_median']:.2g}, {seconds:.2f} s per step of {timing_envs} envs"
        )
        rows.append(row)
    return {
        "task": task_name,
        "num_envs": num_envs,
        "settle": settle,
        "seed": seed,
        "windows": windows,
        "schemes": list(schemes) if schemes is not None else None,
        "reference": "float64 MuJoCo C central differences (step 1e-6, solver tolerance 0) of the same control step",
        "rows": rows,
    }


def _steps_cells(r: dict) -> list[str]:
    if r["fd_scheme"] == "adjoint":  # the analytic gradients' row: no step sizes
        return ["-"] * 5
    tolerance = "model's" if r["fd_tolerance"] is None else f"{r['fd_tolerance']:g}"
    return [
        f"{r['fd_eps_state']:g}",
        f"{r['fd_eps_velocity']:g}",
        f"{r['fd_eps_control']:g}",
        str(r["fd_warmstart"]),
        tolerance,
    ]


def markdown(report: dict, command: str) -> str:
    """The report as a Markdown table, with the command that made it."""
    lines = [
        f"# MuJoCo-Warp finite-difference settings, {report['task']}",
        "",
        f"`{command}`",
        "",
        f"Errors: relative Frobenius error of one control step's Jacobian (state and control columns) against "
        f"{report['reference']}. Contact-free: the max over {report['num_envs']} initial states lifted to 2 m. "
        "In contact: states sampled from random rollouts where MuJoCo C finds a contact; the median, the share "
        "within 5%, the median of each column block's own relative error (position, velocity, control columns), "
        "the share of states whose state gain (the spectral norm of the state Jacobian) exceeds twice the "
        "reference's (a quotient across a contact switch: a jump over the step) and the largest ratio, "
        "and the median over the states whose friction sticks with no contact made or broken. "
        f"Cost: one control step with gradients on the ground, best of {report['windows']}.",
        "",
    ]
    header = ["scheme", "position step", "velocity step", "control step", "warm start", "tolerance", "worlds/env"]
    header += ["contact-free max", "in contact: median", "within 5%", "by column: position / velocity / control"]
    header += ["gain over 2x the reference's (max ratio)", "friction sticking: median", "s per step"]
    header += ["env-steps/s with grad"]
    rows = [
        [
            r["fd_scheme"],
            *_steps_cells(r),
            f"{r['worlds_per_env']:.4g}",
            f"{r['contact_free_error_max']:.1e}",
            f"{r['contact_error_median']:.2g} ({r['contact_states']})",
            f"{r['contact_within_5pct']:.0%}",
            " / ".join(f"{v:.2g}" for v in r["contact_error_median_by_kind"].values()),
            f"{r['contact_spurious_gain_share']:.0%} ({r['contact_gain_ratio_max']:.3g})",
            f"{r['sticking_error_median']:.2g} ({r['sticking_states']})",
            f"{r['seconds_per_step_with_grad']:.2f} ({r['timing_envs']} envs)",
            f"{r['env_steps_per_s_with_grad']:.1f}",
        ]
        for r in report["rows"]
    ]
    lines += markdown_table(header, rows)
    return "\n".join(lines) + "\n"


# -- the verb and its line in the suite's checks table ---------------------------------------------


def verb(args) -> int:
    """``python -m harness fd-schemes``: MuJoCo-Warp's gradient settings, accuracy against cost."""
    from backends.contract import BackendError
    from backends.mujoco_warp.adapter import FD_SCHEMES
    from harness.inputs import BadInput, out_stem, preflight, validate_names
    from harness.results import atomic_write_text, harness_command, write_check
    from tasks import task_class

    validate_names("mujoco_warp", args.task)
    if task_class(args.task).layout.num_particles:
        raise BadInput("fd-schemes compares schemes on articulated tasks (ant, go2); soft bodies have no C reference")
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
    print(f"fd-schemes mujoco_warp/{args.task}: accuracy on {args.num_envs} envs, cost at {args.timing_envs} envs")
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


def summary(result: dict, kind: str) -> str:
    from harness.formatting import fmt

    rows = result.get("rows", [])
    best = min(rows, key=lambda row: row.get("contact_error_median", math.inf), default=None)
    if best is None:
        return "no setting measured"
    return (
        f"{len(rows)} settings; most accurate in contact: {best.get('fd_scheme')}, position step "
        f"{best.get('fd_eps_state')}, velocity step {best.get('fd_eps_velocity')}, median error "
        f"{fmt(best.get('contact_error_median'))}"
    )
