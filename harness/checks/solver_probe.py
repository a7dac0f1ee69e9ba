"""``python -m harness solver-probe``: evidence for a task's Newton solver settings, written with provenance.

Each task has candidate settings (:data:`CANDIDATES`), each a physics preset of the task, changes to
its physics and adapter options, probed through the adapter itself:

* forward stability: ``num_envs`` envs x ``steps`` control steps of uniform random actions in
  (-1, 1) (no gradient): the first non-finite step if any, the height range of the body (trunk, or a
  soft body's particle centroid), the largest horizontal excursion;
* standing: 8 envs x ``steps`` steps of zero actions, the lowest body height and smallest up_z (or
  lowest particle);
* gradient: along the first ``windows`` windows of 32 random-action steps, the per-env norm of
  d(window reward)/d(first actions) (what ``grad-growth`` measures along a trained policy's
  trajectories), max and median; an exploding adjoint shows up as norms of 1e3 and far above.

On another backend (one solver there) only the standing check of the task's own settings runs.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time

import torch

from harness.results import write_check

#: (label, physics preset (None: the task's default), physics changes, adapter options) for the Ant on Newton
ANT_CANDIDATES = [
    ("featherstone, the bench constants (chosen)", None, {}, {}),
    ("semi_implicit, the bench constants without armature", "bench_semi_implicit", {}, {}),
    ("featherstone, contact kd 1e4 (the top of SHAC's range)", None, {"contact_kd": 1.0e4}, {}),
    ("featherstone, friction slope kf 3e3 (DiffRL's)", "bench_kf3000", {}, {}),
    ("featherstone, Rewarped's AntDflex", "rewarped", {}, {}),
]
#: the same for the Go2
GO2_CANDIDATES = [
    # the semi-implicit solver has no rotor inertia: it refuses an armature, so these run without one
    ("semi_implicit 16 substeps, no armature", None, {"armature": 0.0}, {"solver": "semi_implicit"}),
    ("semi_implicit 64 substeps, no armature", None, {"substeps": 64, "armature": 0.0}, {"solver": "semi_implicit"}),
    ("featherstone armature 0.01 16 substeps", None, {"armature": 0.01}, {"solver": "featherstone"}),
    ("featherstone armature 0.01 32 substeps", None, {"armature": 0.01, "substeps": 32}, {"solver": "featherstone"}),
    ("featherstone armature 0.1 16 substeps (chosen)", None, {}, {"solver": "featherstone"}),
]
#: the SoftJumper on Newton: the task's settings (semi-implicit, 80 substeps, kf 10)
SOFT_JUMPER_CANDIDATES = [
    ("semi_implicit 80 substeps kf 10 (chosen)", None, {}, {}),
]
CANDIDATES = {"ant": ANT_CANDIDATES, "go2": GO2_CANDIDATES, "soft_jumper": SOFT_JUMPER_CANDIDATES}


def run_probe(
    num_envs: int = 64,
    out: str | None = None,
    command: str | None = None,
    task: str = "ant",
    steps: int = 1000,
    backend: str = "newton",
) -> list[dict]:
    if backend != "newton":  # one solver there: only the standing check of the task's own settings
        results = [standing(backend, task, steps=steps, num_envs=num_envs)]
        print(json.dumps(results[0]), flush=True)
    else:
        results = []
        for label, preset, changes, options in CANDIDATES[task]:
            result = probe_candidate(task, label, changes, options, preset=preset, num_envs=num_envs, steps=steps)
            print(json.dumps(result), flush=True)
            results.append(result)
    if out:
        print(f"wrote {write_check(out, 'solver-probe', {'task': task, 'backend': backend, 'runs': results}, command)}")
    return results


def standing(backend: str, task_name: str, steps: int = 1000, num_envs: int = 8, seed: int = 1) -> dict:
    """Zero actions for ``steps`` control steps on ``backend`` with the task's own settings."""
    from backends import make
    from tasks import make_task

    task = make_task(task_name)
    start = time.perf_counter()
    stand = zero_action_stand(make(backend, task, num_envs=num_envs, seed=seed), steps)
    return {"backend": backend, "zero_actions": stand, "seconds": round(time.perf_counter() - start, 1)}


def body_position(state) -> torch.Tensor:
    """(N, 3) where each env's body is: the root of a floating base, else the centroid of the particles."""
    if state.particle_q is not None:
        return state.particle_q.mean(dim=1)
    return state.root_pos


def zero_action_stand(sim, steps: int) -> dict:
    """Step ``sim`` under zero actions: the first non-finite step, or the lowest body height (root, or
    particle centroid of a soft body), its final mean, the smallest up_z (floating bases) or lowest
    particle (soft bodies), and how many envs the task counts as terminated at the end."""
    from backends import NonFiniteStateError
    from simcore import up_z

    task, n = sim.task, sim.num_envs
    low, up_min, particle_min, failed_at = math.inf, math.inf, math.inf, None
    with torch.no_grad():
        for t in range(steps):
            try:
                state = sim.step(torch.zeros(n, task.action_dim))
            except NonFiniteStateError:
                failed_at = t + 1
                break
            low = min(low, float(body_position(state)[:, 2].min()))
            if sim.layout.floating_base:
                up_min = min(up_min, float(up_z(state.root_quat).min()))
            if state.particle_q is not None:
                particle_min = min(particle_min, float(state.particle_q[..., 2].min()))
    finished = failed_at is None
    result = {
        "num_envs": n,
        "steps": steps,
        "first_non_finite_step": failed_at,
        "trunk_height_min": low if finished else None,
        "trunk_height_final_mean": float(body_position(state)[:, 2].mean()) if finished else None,
        "terminated_envs": int(task.terminated(state, None).sum()) if finished else None,
    }
    if sim.layout.floating_base:
        result["up_z_min"] = up_min if finished else None
    if sim.layout.num_particles:
        result["lowest_particle_z"] = particle_min if finished else None
    return result


def probe_candidate(
    task_name: str,
    label: str,
    changes: dict,
    options: dict,
    preset: str | None = None,
    num_envs: int = 64,
    steps: int = 1000,
    windows: int = 3,
    seed: int = 0,
) -> dict:
    """One candidate setting of ``task_name`` on Newton (its physics ``preset`` with ``changes``, the
    adapter's ``options``): forward stability, standing, gradient norms."""
    from backends import NonFiniteStateError, make
    from tasks import make_task
    from tasks.rollout import rollout_reward

    base = make_task(task_name, preset=preset)
    task = make_task(task_name, dataclasses.replace(base.physics, **changes), preset=preset)
    result = {
        "candidate": label,
        "preset": preset or type(base).default_preset,
        "physics_changes": changes,
        "adapter_options": options,
        "steps": steps,
    }
    start = time.perf_counter()

    # forward stability under random actions
    sim = make("newton", task, num_envs=num_envs, seed=seed, max_graph_steps=32, **options)
    gen = torch.Generator().manual_seed(seed)
    low, high, reach, failed_at = math.inf, -math.inf, 0.0, None
    starts, recorded = [], []  # the first `windows` windows of 32 steps, replayed with grad below
    with torch.no_grad():
        for t in range(steps):
            actions = 2.0 * torch.rand(num_envs, task.action_dim, generator=gen) - 1.0
            if t < 32 * windows:
                if t % 32 == 0:
                    starts.append(sim.state.detach())
                    recorded.append([])
                recorded[-1].append(actions)
            try:
                state = sim.step(actions)
            except NonFiniteStateError:
                failed_at = t + 1
                break
            where = body_position(state)
            low, high = min(low, float(where[:, 2].min())), max(high, float(where[:, 2].max()))
            reach = max(reach, float(where[:, :2].norm(dim=1).max()))
    result["random_actions"] = {
        "num_envs": num_envs,
        "first_non_finite_step": failed_at,
        "trunk_height_min_max": [low, high] if low <= high else None,
        "max_horizontal_distance": reach,
    }

    # standing under zero actions
    result["zero_actions"] = zero_action_stand(make("newton", task, num_envs=8, seed=seed + 1, **options), steps)

    # gradients over 32-step windows of the random trajectory
    norms = []
    if failed_at is None:
        for window_start, actions in zip(starts, recorded, strict=True):
            a = torch.stack(actions).clone().requires_grad_(True)
            try:
                rollout_reward(sim, window_start, a).sum().backward()
            except NonFiniteStateError:
                norms = None
                break
            norms.append(a.grad[0].norm(dim=1))
    if norms:
        g = torch.cat(norms)
        finite = torch.isfinite(g)
        result["gradient_32_step_windows"] = {
            "windows": len(starts),
            "max_norm": float(g[finite].max()) if finite.any() else None,
            "median_norm": float(g[finite].median()) if finite.any() else None,
            "non_finite": int((~finite).sum()),
            "above_1e3": int((g > 1e3).sum()),
            "env_windows": int(g.numel()),
        }
    else:
        result["gradient_32_step_windows"] = None
    result["seconds"] = round(time.perf_counter() - start, 1)
    return result


# -- the verb and its line in the suite's checks table ---------------------------------------------


def verb(args) -> int:
    """``python -m harness solver-probe``: every candidate setting of the task, probed and written."""
    from harness.inputs import BadInput, preflight
    from harness.results import harness_command

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


def summary(result: dict, kind: str) -> str:
    runs = result.get("runs", [])
    stable = sum(
        (run.get("random_actions") or run.get("zero_actions") or {}).get("first_non_finite_step") is None
        for run in runs
    )
    return f"{len(runs)} setting(s) probed, {stable} finite throughout"
