"""Where a bare Newton window spends its time, kernel by kernel (eager launches, no graph capture).

    OMP_NUM_THREADS=1 python benchmarks/profile/newton_kernels.py --task ant [--preset bench] \
        [--num-envs 64] [--horizon 32] [--out results/.../profile.json]

Runs the adapter's bare rollout (``backends.newton.bare.bare_tape_rollout``: the same model,
solver, contacts and substeps, one tape over the window, its backward) once to warm up and once
timed, with every ``wp.launch`` (forward and adjoint) timed on its own. A CPU kernel runs to
completion inside its launch, so a launch's wall time is the kernel's plus Warp's Python launch
path; the per-kernel table says both how long and how many times.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="ant")
    parser.add_argument("--preset", default=None)
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--horizon", type=int, default=32)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()

    import warp as wp
    import warp._src.context as context

    from backends.newton.bare import bare_tape_rollout
    from harness.envs import make_sim
    from harness.results import provenance, write_json
    from tasks import make_task

    task = make_task(args.task, preset=args.preset)
    sim = make_sim("newton", task, args.num_envs, horizon=args.horizon, graph_capture=0)
    bare_tape_rollout(sim, args.horizon, repeats=0)  # compile and warm up

    seconds, calls = defaultdict(float), defaultdict(int)
    original = context.launch

    def timed(kernel, *a, **kw):
        start = time.perf_counter()
        out = original(kernel, *a, **kw)
        name = getattr(kernel, "key", str(kernel)) + (" (adjoint)" if kw.get("adjoint") else "")
        seconds[name] += time.perf_counter() - start
        calls[name] += 1
        return out

    context.launch = timed
    wp.launch = timed
    start = time.perf_counter()
    bare_tape_rollout(sim, args.horizon, repeats=0)
    total = time.perf_counter() - start
    context.launch = wp.launch = original

    rows = sorted(
        ({"kernel": k, "seconds": s, "launches": calls[k]} for k, s in seconds.items()), key=lambda r: -r["seconds"]
    )
    print(
        f"{task.name} ({task.preset_label}, {sim.integrator}), {args.num_envs} envs x {args.horizon} steps: "
        f"{total:.3f} s per eager window, {sum(calls.values())} launches"
    )
    for row in rows[:15]:
        print(f"  {row['seconds']:8.3f} s {100 * row['seconds'] / total:5.1f}%  {row['launches']:6d}x  {row['kernel']}")
    if args.out:
        payload = {
            "task": task.name,
            "preset": task.preset_label,
            "integrator": sim.integrator,
            "num_envs": args.num_envs,
            "horizon": args.horizon,
            "window_s": total,
            "kernels": rows,
        }
        print(f"wrote {write_json(args.out, {'result': payload, 'provenance': provenance(' '.join(sys.argv))})}")


if __name__ == "__main__":
    main()
