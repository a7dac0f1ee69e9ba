"""Compare the gradients of two (or more) backends on the same task, start state and actions.

For each segment (contact-free: root lifted to the task's ``airborne_height``; with contact: the task's own start) every
backend's gradient of the same loss (the summed task reward over ``steps`` control steps) w.r.t.
the actions and the initial generalized state is computed, and so is each backend's own
autograd-vs-finite-difference error (:func:`harness.checks.gradcheck.gradcheck`). Reported per pair:
``||g_a - g_b|| / ||g_b||`` and the cosine between the gradients. The engines differ (contact
models, coordinates, armature), so agreement is reported, not required.

Actions are 0.1 * U(-1, 1) (20 N m on the Ant): with larger torques the hinges reach their limits
within the rollout, and MuJoCo's joint limits, like its contacts, are constraints that make a step
non-smooth, so the "contact-free" segment would not be smooth for it.

Quaternion gradients are compared after removing their radial part: an engine that normalises
the root quaternion has none, one that does not may, and neither changes the dynamics.

Soft bodies (tasks with particles) are compared forward instead (:func:`forward_crosscheck`): the
same actions from the same start on every backend, the centre-of-mass paths side by side.
"""

from __future__ import annotations

import itertools

import torch

from harness.checks.gradcheck import gradcheck, rollout_loss
from harness.envs import make_sim


def _gradients(sim, q0, qd0, actions) -> dict[str, torch.Tensor]:
    q, qd, a = (x.clone().requires_grad_(True) for x in (q0, qd0, actions))
    rollout_loss(sim, q, qd, a).sum().backward()
    g_q = q.grad.clone()
    if sim.layout.floating_base:
        quat = q0[:, 3:7] / q0[:, 3:7].norm(dim=1, keepdim=True)
        g_quat = g_q[:, 3:7]
        g_q[:, 3:7] = g_quat - (g_quat * quat).sum(1, keepdim=True) * quat
    return {"actions": a.grad.double(), "initial_state": torch.cat((g_q, qd.grad), dim=1).double()}


def _compare(a: torch.Tensor, b: torch.Tensor) -> dict:
    a, b = a.flatten(), b.flatten()
    return {
        "rel_diff": float((a - b).norm() / b.norm().clamp_min(1e-12)),
        "cosine": float(torch.dot(a, b) / (a.norm() * b.norm()).clamp_min(1e-12)),
    }


def crosscheck(
    task_name: str,
    backend_names: list[str],
    num_envs: int = 4,
    steps: int = 8,
    seed: int = 0,
    action_scale: float = 0.1,
) -> dict:
    from tasks import make_task

    task = make_task(task_name)
    sims = {name: make_sim(name, task, num_envs, seed=seed, horizon=steps) for name in backend_names}
    report = {
        "task": task_name,
        "num_envs": num_envs,
        "steps": steps,
        "seed": seed,
        "action_scale": action_scale,
        "segments": {},
    }
    for segment, height in (("contact_free", task.airborne_height), ("with_contact", None)):
        gen = torch.Generator().manual_seed(seed)
        q0, qd0 = task.sample_initial_state(num_envs, gen)
        if height is not None and task.layout.floating_base:
            q0[:, 2] = height
        actions = action_scale * (2.0 * torch.rand(steps, num_envs, task.action_dim, generator=gen) - 1.0)
        grads = {name: _gradients(sim, q0, qd0, actions) for name, sim in sims.items()}
        entry = {"own_finite_difference_check": {}, "pairs": {}}
        for name, sim in sims.items():
            r = gradcheck(sim, steps=steps, seed=seed, start_height=height, action_scale=action_scale)
            entry["own_finite_difference_check"][name] = {
                "actions_rel_error": r.action_rel_error,
                "initial_state_rel_error": r.state_rel_error,
            }
        for a, b in itertools.combinations(backend_names, 2):
            entry["pairs"][f"{a} vs {b}"] = {
                kind: _compare(grads[a][kind], grads[b][kind]) for kind in ("actions", "initial_state")
            }
        report["segments"][segment] = entry
    return report


def forward_crosscheck(
    task_name: str,
    backend_names: list[str],
    num_envs: int = 2,
    steps: int = 60,
    seed: int = 0,
    action_scale: float = 1.0,
) -> dict:
    """The same start and actions forward on every backend, compared by the body's centre of mass.

    For soft bodies, whose finite-difference gradients on MuJoCo-Warp cost thousands of worlds per
    env: every backend rolls out ``steps`` control steps of the same uniform random actions
    (``action_scale * U(-1, 1)``) from the same initial states, without gradients, and the report
    gives the COM of each (the task's ``com`` if it has one, else the particle centroid or the root)
    every step, and per pair the largest distance between them so far (max over envs).
    """
    from harness.checks.solver_probe import body_position
    from tasks import make_task

    task = make_task(task_name)
    gen = torch.Generator().manual_seed(seed)
    initial = task.sample_initial_state(num_envs, gen)
    actions = action_scale * (2.0 * torch.rand(steps, num_envs, task.action_dim, generator=gen) - 1.0)

    def where(state) -> torch.Tensor:
        return task.com(state)[0] if hasattr(task, "com") else body_position(state)

    trajectories = {}
    for name in backend_names:
        sim = make_sim(name, task, num_envs, seed=seed, horizon=1)
        state = sim.state_from_generalized(*initial)
        path = [where(state)]
        with torch.no_grad():
            for t in range(steps):
                state = sim.advance(state, actions[t])
                path.append(where(state))
        trajectories[name] = torch.stack(path).double()  # (steps + 1, N, 3)
    report = {
        "task": task_name,
        "num_envs": num_envs,
        "steps": steps,
        "seed": seed,
        "action_scale": action_scale,
        "com": {name: path.tolist() for name, path in trajectories.items()},
        "pairs": {},
    }
    for a, b in itertools.combinations(backend_names, 2):
        gap = (trajectories[a] - trajectories[b]).norm(dim=-1).amax(dim=1)  # (steps + 1,), max over envs
        axes = (trajectories[a] - trajectories[b]).abs().amax(dim=(0, 1))
        report["pairs"][f"{a} vs {b}"] = {
            "com_distance_by_step": gap.tolist(),
            "com_distance_max": float(gap.max()),
            "com_distance_final": float(gap[-1]),
            "com_abs_difference_max_xyz": axes.tolist(),
        }
    return report


# -- the verb and its line in the suite's checks table ---------------------------------------------


def verb(args) -> int:
    """``python -m harness crosscheck``: gradients (soft bodies: forward paths) of two or more engines."""
    import json

    from harness.inputs import BadInput, preflight
    from harness.results import write_check
    from tasks import task_class

    if len(set(args.backends)) < 2 or len(set(args.backends)) != len(args.backends):
        raise BadInput(f"--backends needs two or more different backends to compare, got {' '.join(args.backends)}")
    preflight(backends=args.backends, task=args.task, out=args.out, memory=(args.num_envs, args.steps))
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


def _extremes(pairs: dict, low: str, high: str) -> tuple[float | None, float | None]:
    """(min of ``low``, max of ``high``) over every comparison nested in ``pairs``."""
    lows, highs = [], []

    def walk(node):
        if isinstance(node, dict):
            if low in node and isinstance(node[low], int | float):
                lows.append(node[low])
            if high in node and isinstance(node[high], int | float):
                highs.append(node[high])
            for value in node.values():
                walk(value)

    walk(pairs)
    return (min(lows) if lows else None), (max(highs) if highs else None)


def summary(result: dict, kind: str) -> str:
    """Gradient agreement (cosine, relative difference); a soft body's file: the forward paths' gap."""
    from harness.formatting import fmt

    if kind == "forward-crosscheck":
        _, gap = _extremes(result["pairs"], "", "com_distance_max")
        steps = result.get("steps")
        return f"forward rollouts across backends: max centre-of-mass distance {fmt(gap)} m, {steps} steps"
    cosine, rel_diff = _extremes(result.get("segments", {}), "cosine", "rel_diff")
    return f"gradients across backends: min cosine {fmt(cosine)}, max rel. difference {fmt(rel_diff)}"
