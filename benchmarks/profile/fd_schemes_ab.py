"""Two MuJoCo-Warp finite-difference schemes timed against each other in one process, call by call.

    OMP_NUM_THREADS=1 python benchmarks/profile/fd_schemes_ab.py --task ant [--num-envs 64] \
        [--rounds 12] [--schemes one_sided adaptive] [--out results/fd_schemes/ab_ant.json]

On a machine whose load moves (other jobs beside it), two processes timed one after the other see
different machines; here both schemes' adapters are built in one process on the same states in contact
(the envs after 30 random steps), and each round times one step with gradients
(``MujocoWarpSim.fd_jacobians``) of each scheme, the order alternating between rounds. The ratio of the
two medians is the speed-up; the per-round ratios show its spread. Also recorded: the worlds each step
ran (``adaptive``: its -eps worlds added).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="ant")
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--rounds", type=int, default=12)
    parser.add_argument("--schemes", nargs=2, default=["one_sided", "adaptive"])
    parser.add_argument("--out", default=None)
    args = parser.parse_args()

    import torch

    from backends import make
    from harness.results import provenance, write_json
    from tasks import make_task

    task = make_task(args.task)
    walker = make("mujoco_warp", task, num_envs=args.num_envs, seed=0)
    walker.reset()
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for _ in range(30):
            walker.step(0.5 * (2.0 * torch.rand(args.num_envs, task.action_dim, generator=gen) - 1.0))
    engine = walker.state.engine.detach()
    control = task.actions_to_control(0.5 * (2.0 * torch.rand(args.num_envs, task.action_dim, generator=gen) - 1.0))
    sims = {s: make("mujoco_warp", task, num_envs=args.num_envs, seed=0, fd_scheme=s) for s in args.schemes}
    seconds = {s: [] for s in args.schemes}
    worlds = {s: [] for s in args.schemes}
    for sim in sims.values():  # warm-up: kernels, buffers, captured graphs
        sim.fd_jacobians(engine, control)
        sim.fd_jacobians(engine, control)
    for round_ in range(args.rounds):
        order = args.schemes if round_ % 2 == 0 else args.schemes[::-1]
        for scheme in order:
            sim = sims[scheme]
            start = time.perf_counter()
            sim.fd_jacobians(engine, control)
            seconds[scheme].append(time.perf_counter() - start)
            extra = sim.second_side_share * (sim.worlds_per_env_with_grad - 1) if scheme == "adaptive" else 0.0
            worlds[scheme].append(sim.worlds_per_env_with_grad + extra)
    base, other = args.schemes
    ratios = [b / o for b, o in zip(seconds[base], seconds[other], strict=True)]
    payload = {
        "task": args.task,
        "num_envs": args.num_envs,
        "rounds": args.rounds,
        "schemes": args.schemes,
        "seconds_per_step": seconds,
        "median_seconds_per_step": {s: statistics.median(v) for s, v in seconds.items()},
        "env_steps_per_s_with_grad": {s: args.num_envs / statistics.median(v) for s, v in seconds.items()},
        "worlds_per_env": {s: statistics.mean(v) for s, v in worlds.items()},
        "speed_up": statistics.median(seconds[base]) / statistics.median(seconds[other]),
        "per_round_speed_up": ratios,
    }
    print(
        f"{args.task}, {args.num_envs} envs: {base} {payload['env_steps_per_s_with_grad'][base]:.1f}, "
        f"{other} {payload['env_steps_per_s_with_grad'][other]:.1f} env-steps/s with gradients; "
        f"{other} {payload['speed_up']:.2f}x (rounds {min(ratios):.2f}-{max(ratios):.2f})"
    )
    if args.out:
        print(f"wrote {write_json(args.out, {'result': payload, 'provenance': provenance(' '.join(sys.argv))})}")


if __name__ == "__main__":
    main()
