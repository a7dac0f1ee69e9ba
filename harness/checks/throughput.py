"""Env-steps per second of an adapter, forward-only and forward+backward over SHAC-style windows."""

from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass

import torch

from backends.contract import BatchedSim


@dataclass
class ThroughputResult:
    backend: str
    task: str
    num_envs: int
    horizon: int
    windows: int
    forward_steps_per_s: float
    forward_backward_steps_per_s: float
    #: the engine alone doing the work of a step with gradients (a tape rollout, finite-difference worlds)
    bare_engine_steps_per_s: float | None = None
    #: the engine alone stepping forward (no tape, one world per env)
    bare_forward_steps_per_s: float | None = None

    @property
    def overhead_ratio(self) -> float | None:
        """Adapter time / bare engine time for the same forward+backward window (1.0 = no overhead)."""
        if self.bare_engine_steps_per_s is None:
            return None
        return self.bare_engine_steps_per_s / self.forward_backward_steps_per_s

    @property
    def forward_overhead_ratio(self) -> float | None:
        """Adapter time / bare engine time for the same forward-only window."""
        if self.bare_forward_steps_per_s is None:
            return None
        return self.bare_forward_steps_per_s / self.forward_steps_per_s

    @property
    def gradient_cost_factor(self) -> float:
        """Time of a step with gradients (forward + backward) / time of a forward-only step.

        For a finite-difference adapter this is its finite-difference overhead factor.
        """
        return self.forward_steps_per_s / self.forward_backward_steps_per_s

    def as_dict(self) -> dict:
        return {
            **asdict(self),
            "overhead_ratio": self.overhead_ratio,
            "forward_overhead_ratio": self.forward_overhead_ratio,
            "gradient_cost_factor": self.gradient_cost_factor,
        }


# untimed windows before the timed ones: the first compiles kernels and allocates buffers, the second
# captures graphs (the Newton and MuJoCo-Warp adapters capture a buffer's graph on its second use)
WARMUP_WINDOWS = 2


def _window(sim: BatchedSim, horizon: int, grad: bool, gen: torch.Generator) -> float:
    """Seconds for one window of ``horizon`` adapter steps, plus the backward pass if ``grad``.

    The loss touches every output of every step (all generalized coordinates), so the backward
    pass runs each step's full adjoint (particles included), as a training loss would, but no task code is timed:
    this measures the adapter, comparable with the bare engine rollout.
    """
    task = sim.task
    sim.cut_graph()
    actions = [(2.0 * torch.rand(sim.num_envs, task.action_dim, generator=gen) - 1.0) for _ in range(horizon)]
    start = time.perf_counter()
    if grad:
        params = [a.to(sim.device).requires_grad_(True) for a in actions]
        loss = 0.0
        for a in params:
            state = sim.step(a)
            loss = loss + state.joint_q.sum() + state.joint_qd.sum()
            if state.particle_q is not None:
                loss = loss + state.particle_q.sum() + state.particle_qd.sum()
        loss.backward()
    else:
        with torch.no_grad():
            for a in actions:
                sim.step(a.to(sim.device))
    elapsed = time.perf_counter() - start
    sim.reset()  # keep every window in the same regime (no drift into fallen/flying states)
    return elapsed


def forward_rate(sim: BatchedSim, horizon: int = 32, windows: int = 3, seed: int = 0) -> float:
    """Best-of-``windows`` forward-only env-steps/s after ``WARMUP_WINDOWS`` warm-up windows."""
    gen = torch.Generator().manual_seed(seed)
    for _ in range(WARMUP_WINDOWS):
        _window(sim, horizon, False, gen)
    return sim.num_envs * horizon / min(_window(sim, horizon, False, gen) for _ in range(windows))


def measure(sim: BatchedSim, horizon: int = 32, windows: int = 5, seed: int = 0, bare: bool = True) -> ThroughputResult:
    """Best-of-``windows`` rates after ``WARMUP_WINDOWS`` warm-up windows each (Warp compiles kernels on
    first use; adapters that capture graphs capture a buffer's graph on its second use).

    The bare-engine references are the adapter's optional ``bare_engine_rollout`` with and without
    gradients (None: none), timed in the same rounds; ``bare=False`` skips them.
    """
    gen = torch.Generator().manual_seed(seed)
    steps = sim.num_envs * horizon
    best = {False: float("inf"), True: float("inf"), "bare": float("inf"), "bare_forward": float("inf")}
    for grad in (False, True):
        for _ in range(WARMUP_WINDOWS):  # kernel compilation, buffer allocation, graph capture
            _window(sim, horizon, grad, gen)
    # interleave the variants so a slow patch of machine time hits all of them alike
    for _ in range(windows):
        for grad in (False, True):
            best[grad] = min(best[grad], _window(sim, horizon, grad, gen))
            engine_only = sim.bare_engine_rollout(horizon, grad=grad) if bare else None
            if engine_only is not None:
                key = "bare" if grad else "bare_forward"
                best[key] = min(best[key], engine_only)
    rates = {k: (steps / v if v < float("inf") else None) for k, v in best.items()}
    return ThroughputResult(
        backend=sim.name,
        task=sim.task.name,
        num_envs=sim.num_envs,
        horizon=horizon,
        windows=windows,
        forward_steps_per_s=rates[False],
        forward_backward_steps_per_s=rates[True],
        bare_engine_steps_per_s=rates["bare"],
        bare_forward_steps_per_s=rates["bare_forward"],
    )


def compare(sim: BatchedSim, other: BatchedSim, horizon: int = 32, rounds: int = 5, seed: int = 0) -> dict:
    """Two adapters' forward+backward windows timed in one process, round by round, the order flipping
    each round, so both see the same machine while its load moves (after ``WARMUP_WINDOWS`` each):
    each one's median rate, and ``sim``'s speed as a share of ``other``'s, the ratio of the two medians,
    with the range of the rounds' own ratios."""
    gen = torch.Generator().manual_seed(seed)
    for _ in range(WARMUP_WINDOWS):
        _window(sim, horizon, True, gen)
        _window(other, horizon, True, gen)
    mine, theirs = [], []
    for k in range(rounds):
        pair = (sim, other) if k % 2 == 0 else (other, sim)
        seconds = {id(s): _window(s, horizon, True, gen) for s in pair}
        mine.append(seconds[id(sim)])
        theirs.append(seconds[id(other)])
    steps = sim.num_envs * horizon
    ratios = [t / m for m, t in zip(mine, theirs, strict=True)]
    return {
        "backend": other.name,
        "integrator": other.integrator,
        "rounds": rounds,
        "own_forward_backward_steps_per_s_median": steps / statistics.median(mine),
        "forward_backward_steps_per_s_median": steps / statistics.median(theirs),
        "speed_ratio": statistics.median(theirs) / statistics.median(mine),
        "speed_ratio_min": min(ratios),
        "speed_ratio_max": max(ratios),
    }


# -- the verb and its line in the suite's checks table ---------------------------------------------


def verb(args) -> int:
    """``python -m harness throughput``: forward-only and forward+backward env-steps/s, and the bare engine;
    with ``--against B``, also this adapter's speed with gradients as a share of backend B's (default
    options), the two timed window by window in this process."""
    from harness.inputs import BadInput, make_verb_sim, preflight, sim_physics
    from harness.results import write_check

    memory = (args.num_envs, 0 if args.grad_cost_only else args.horizon)
    against = getattr(args, "against", None)
    if against and args.grad_cost_only:
        raise BadInput("--against times full windows with gradients: it cannot go with --grad-cost-only")
    names = [args.backend] + ([against] if against else [])
    preflight(backends=names, task=args.task, device=args.device, out=args.out, memory=memory)
    sim = make_verb_sim(args, horizon=args.horizon)
    other = _against_sim(args, against) if against else None
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
    payload = {**result.as_dict(), **sim_physics(sim), "backend_options": dict(args.backend_option or [])}
    if other is not None:
        payload["against"] = compare(sim, other, horizon=args.horizon, rounds=args.windows, seed=args.seed)
        print(
            f"  against {against}:  {payload['against']['speed_ratio']:10.3f} of its speed with gradients "
            f"(rounds {payload['against']['speed_ratio_min']:.3f}-{payload['against']['speed_ratio_max']:.3f})"
        )
    if args.out:
        print(f"wrote {write_check(args.out, 'throughput', payload)}")
    return 0


def _against_sim(args, backend: str) -> BatchedSim:
    """The ``--against`` backend on the same task, preset, envs, device and seed, with its default options."""
    from argparse import Namespace

    from harness.inputs import make_verb_sim

    return make_verb_sim(Namespace(**{**vars(args), "backend": backend, "backend_option": []}), horizon=args.horizon)


def _grad_cost_only(sim, args) -> int:
    """``throughput --grad-cost-only WORLDS``: forward windows as usual, the step with gradients estimated."""
    from harness.inputs import BadInput
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


def summary(result: dict, kind: str) -> str:
    from harness.formatting import fmt

    with_grad = result.get("forward_backward_steps_per_s", result.get("forward_backward_steps_per_s_estimated"))
    line = f"{fmt(result.get('forward_steps_per_s'))} env-steps/s forward, {fmt(with_grad)} with gradients"
    against = result.get("against")
    if against:
        line += f"; {fmt(against['speed_ratio'])} of {against['backend']}'s speed with gradients, same process"
    return line
