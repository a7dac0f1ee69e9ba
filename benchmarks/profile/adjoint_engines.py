"""MuJoCo-Warp with the analytic adjoint against Newton, timed in one process, window by window, and
the adjoint's cost split by part.

    OMP_NUM_THREADS=1 python benchmarks/profile/adjoint_engines.py [--task ant] [--num-envs 64] \
        [--horizon 32] [--rounds 6] [--out results/adjoint/ant_engines.json]

Each round times one window of ``horizon`` steps with gradients and its backward pass
(:func:`harness.checks.throughput._window`, the perf profile's window) on each engine, the order alternating,
so both see the same machine even while its load moves; the ratio of the two medians is MuJoCo-Warp's
speed as a fraction of Newton's. Then one more MuJoCo-Warp window runs under torch's profiler: the
forward (MuJoCo-Warp's own step, recording each substep) and the backward by the adjoint's parts
(:mod:`backends.mujoco_warp.adjoint.step`'s labels: kinematics, mass matrix, bias forces, constraint
rows, constraint solve, integrator). Last, each part timed alone (forward and backward, its inputs
as leaves, at a recorded substep's state of envs standing on the ground) times the substeps of a
control step: what each part costs a control step's backward pass.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

PARTS = ("kinematics", "mass matrix", "bias forces", "constraint rows", "constraint solve", "integrator")


def _profiled_window(sim, horizon: int, seed: int) -> dict:
    """Seconds of one window's forward, backward and each adjoint part (CPU time of the labelled ranges
    and of the autograd nodes they created)."""
    import torch
    from torch.profiler import ProfilerActivity, profile, record_function

    gen = torch.Generator().manual_seed(seed)
    actions = [(2.0 * torch.rand(sim.num_envs, sim.task.action_dim, generator=gen) - 1.0) for _ in range(horizon)]
    sim.cut_graph()
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        start = time.perf_counter()
        with record_function("window: forward"):
            loss = 0.0
            for a in actions:
                state = sim.step(a.requires_grad_(True))
                loss = loss + state.joint_q.sum() + state.joint_qd.sum()
        middle = time.perf_counter()
        with record_function("window: backward"):
            loss.backward()
        end = time.perf_counter()
    sim.reset()
    totals = {e.key: e.cpu_time_total / 1e6 for e in prof.key_averages()}
    return {
        "forward_s": middle - start,
        "backward_s": end - middle,
        "parts_s": {part: totals.get(f"adjoint: {part}", 0.0) for part in PARTS},
        "note": "parts: the labelled ranges' CPU time in the backward pass's replays (forward replay under "
        "autograd); their gradients run in autograd's nodes, counted in backward_s",
    }


def _leaf(t):
    return t.detach().clone().requires_grad_(True)


def _timed(forward, repeats: int) -> float:
    """Median seconds of ``forward()`` and the backward pass of a weighted sum of its outputs."""
    import torch

    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        outputs = [o for o in forward() if o.requires_grad]
        torch.autograd.backward([o for o in outputs], [torch.ones_like(o) for o in outputs])
        seconds.append(time.perf_counter() - start)
    return statistics.median(seconds)


def _parts_in_isolation(sim, engine, control, repeats: int = 5) -> dict:
    """Per part of one substep's replay (at the first substep's recorded state), the seconds of its
    forward and backward with its inputs as leaves, times the substeps of a control step: what each
    part costs a control step's backward pass."""
    import dataclasses

    import torch

    from backends.mujoco_warp.adjoint import constraints as cons
    from backends.mujoco_warp.adjoint import dynamics
    from backends.mujoco_warp.adjoint.integrate import integrate_positions
    from backends.mujoco_warp.adjoint.step import _constraint_force, _hessian, substep

    tree = sim.tree
    _, records = sim.adjoint_step(engine, control)
    q, v, a0 = (t.double() for t in records[len(records) // 2])
    u = control.double()
    kin = dynamics.kinematics(tree, q)
    kin_leaf = dataclasses.replace(kin, **{f.name: _leaf(getattr(kin, f.name)) for f in dataclasses.fields(kin)})
    mass = dynamics.mass_matrix(tree, kin)
    rows = cons.constraint_rows(tree, kin, q, v)
    rows_leaf = dataclasses.replace(rows, **{f.name: _leaf(getattr(rows, f.name)) for f in dataclasses.fields(rows)})
    smooth = _leaf(sim.applied_force(u, q, v) - tree.damping * v)
    with torch.no_grad():
        limit_zone, contact_zone, blocks = cons.zones_and_hessian_blocks(rows, a0)
        mass, zones = mass.detach(), (limit_zone, contact_zone)
        hessian = _hessian(mass, rows, limit_zone, blocks)

    def solve():
        m = _leaf(mass)
        residual = (m @ a0[..., None]).squeeze(-1) - smooth - _constraint_force(rows_leaf, a0, zones)
        return (a0 - torch.linalg.solve(hessian, residual),)

    def integrate():
        m, qacc, qv, qq = _leaf(mass), _leaf(a0), _leaf(v), _leaf(q)
        damped = m + tree.timestep * torch.diag(tree.damping)
        qvel = qv + tree.timestep * torch.linalg.solve(damped, (m @ qacc[..., None]).squeeze(-1))
        return integrate_positions(tree, qq, qvel, tree.timestep), qvel

    substeps = len(records)
    parts = {
        "kinematics": lambda: tuple(vars(dynamics.kinematics(tree, _leaf(q))).values()),
        "mass matrix": lambda: (dynamics.mass_matrix(tree, kin_leaf),),
        "bias forces": lambda: (dynamics.bias_force(tree, kin_leaf, _leaf(v)),),
        "constraint rows": lambda: tuple(vars(cons.constraint_rows(tree, kin_leaf, _leaf(q), _leaf(v))).values()),
        "zones and solver Hessian (no gradient)": lambda: (
            _hessian(mass, rows, *cons.zones_and_hessian_blocks(rows, a0)[::2]).requires_grad_(True),
        ),
        "constraint solve": solve,
        "integrator": integrate,
        "whole substep": lambda: substep(tree, _leaf(q), _leaf(v), sim.applied_force(u, q, v), a0),
    }
    return {name: substeps * _timed(fn, repeats) for name, fn in parts.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="ant")
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--horizon", type=int, default=32)
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()

    import torch

    from backends import make
    from harness.checks.throughput import WARMUP_WINDOWS, _window
    from harness.results import provenance, write_json
    from tasks import make_task

    task = make_task(args.task)
    sims = {
        "newton": make("newton", task, num_envs=args.num_envs, seed=0, max_graph_steps=args.horizon),
        "mujoco_warp adjoint": make("mujoco_warp", task, num_envs=args.num_envs, seed=0, gradients="adjoint"),
    }
    gen = torch.Generator().manual_seed(0)
    for sim in sims.values():
        sim.reset()
        for _ in range(WARMUP_WINDOWS):
            _window(sim, args.horizon, True, gen)
    seconds = {name: [] for name in sims}
    for r in range(args.rounds):
        order = list(sims) if r % 2 == 0 else list(reversed(sims))
        for name in order:
            seconds[name].append(_window(sims[name], args.horizon, True, gen))
        print(f"round {r + 1}: " + ", ".join(f"{n} {seconds[n][-1]:.2f} s" for n in sims), flush=True)
    steps = args.num_envs * args.horizon
    rates = {name: steps / statistics.median(s) for name, s in seconds.items()}
    ratios = [n / m for n, m in zip(seconds["newton"], seconds["mujoco_warp adjoint"], strict=True)]
    report = {
        "task": args.task,
        "num_envs": args.num_envs,
        "horizon": args.horizon,
        "rounds": args.rounds,
        "seconds_per_window": seconds,
        "env_steps_per_s_with_grad": rates,
        "mujoco_warp_over_newton": rates["mujoco_warp adjoint"] / rates["newton"],
        "per_round_ratio": ratios,
        "adjoint_window_profile": _profiled_window(sims["mujoco_warp adjoint"], args.horizon, 1),
        "adjoint_parts_per_control_step_s": _parts_in_isolation(
            sims["mujoco_warp adjoint"],
            sims["mujoco_warp adjoint"].state.engine.detach(),
            task.actions_to_control(torch.zeros(args.num_envs, task.action_dim)),
        ),
        "load_average": os.getloadavg(),
    }
    print(
        "env-steps/s with gradients: "
        + ", ".join(f"{n} {v:.1f}" for n, v in rates.items())
        + f"; MuJoCo-Warp / Newton {report['mujoco_warp_over_newton']:.3f} (rounds {min(ratios):.3f}-{max(ratios):.3f})"
    )
    print(report["adjoint_window_profile"])
    if args.out:
        command = "python benchmarks/profile/adjoint_engines.py " + " ".join(sys.argv[1:])
        write_json(Path(args.out), {**report, "command": command, "provenance": provenance(command)})
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
