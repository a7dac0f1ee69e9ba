"""Accuracy versus cost of the MuJoCo-Warp adapter's finite-difference schemes.

For each scheme (``fd_scheme``: central or forward differences) and state step (``fd_eps_state``),
the per-step Jacobians of ``num_envs`` envs are compared with the float64 MuJoCo C reference
(:mod:`backends.mujoco_warp.reference`): relative Frobenius error of the state Jacobian and of the
control Jacobian, the max over envs. Two sets of states:

* contact-free: the task's initial states lifted to 2 m (the segment ``gradcheck`` uses), where
  the step is smooth and the reference is exact; the default scheme must be < 1e-3 here;
* contact: the task's initial states after ``settle`` zero-action steps (feet or legs on the
  ground). A control step with contacts is non-smooth (adapter module docstring), so there is no
  exact reference; the column is reported to show how far the schemes spread, not to rank them.

Cost: the seconds of one control step with gradients (:meth:`MujocoWarpSim.fd_jacobians`, best of
``windows`` after a warm-up) for ``timing_envs`` envs on the ground, and the worlds it steps.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from backends import make
from backends.mujoco_warp.reference import float64_step_jacobians
from tasks import make_task

#: (scheme, state step) pairs measured; the control step stays at the adapter's default
GRID = (
    ("central", 1e-2),
    ("forward", 1e-2),
    ("forward", 3e-3),
    ("forward", 2e-3),
    ("forward", 1e-3),
    ("forward", 3e-4),
)


def _errors(sim, engine: torch.Tensor, control: torch.Tensor) -> tuple[float, float]:
    _, jac_state, jac_control = sim.fd_jacobians(engine, control)
    worst_state = worst_control = 0.0
    for i in range(engine.shape[0]):
        _, ref_state, ref_control = float64_step_jacobians(sim, engine[i], control[i])
        err_state = np.linalg.norm(jac_state[i].numpy() - ref_state) / np.linalg.norm(ref_state)
        err_control = np.linalg.norm(jac_control[i].numpy() - ref_control) / np.linalg.norm(ref_control)
        worst_state, worst_control = max(worst_state, err_state), max(worst_control, err_control)
    return float(worst_state), float(worst_control)


def _states(task, sim, num_envs: int, seed: int, settle: int):
    """(contact-free engine states, on-ground engine states, controls), all (num_envs, .)."""
    gen = torch.Generator().manual_seed(seed)
    q, qd = task.sample_initial_state(num_envs, gen)
    lifted_q = q.clone()
    if task.layout.floating_base:
        lifted_q[:, 2] = 2.0
    free = sim.state_from_generalized(lifted_q, qd).engine.detach()
    sim.reset()
    with torch.no_grad():
        for _ in range(settle):
            sim.step(torch.zeros(num_envs, task.action_dim))
    ground = sim.state.engine.detach().clone()
    actions = 0.5 * (2.0 * torch.rand(num_envs, task.action_dim, generator=gen) - 1.0)
    return free, ground, task.actions_to_control(actions)


def _step_seconds(sim, windows: int) -> float:
    engine = sim.state.engine.detach()
    control = sim.task.actions_to_control(torch.zeros(sim.num_envs, sim.task.action_dim))
    sim.fd_jacobians(engine, control)  # warm-up: kernels, buffers of this many worlds
    best = float("inf")
    for _ in range(windows):
        start = time.perf_counter()
        sim.fd_jacobians(engine, control)
        best = min(best, time.perf_counter() - start)
    return best


def fd_schemes(
    task_name: str,
    num_envs: int = 8,
    timing_envs: int = 64,
    windows: int = 3,
    seed: int = 0,
    settle: int = 10,
    grid=GRID,
    progress=print,
) -> dict:
    """One row per (scheme, state step) of ``grid``; see the module docstring."""
    task = make_task(task_name)
    rows = []
    for scheme, eps_state in grid:
        options = {"fd_scheme": scheme, "fd_eps_state": eps_state}
        sim = make("mujoco_warp", task, num_envs=num_envs, seed=seed, **options)
        free, ground, control = _states(task, sim, num_envs, seed, settle)
        free_state, free_control = _errors(sim, free, control)
        ground_state, ground_control = _errors(sim, ground, control)
        seconds = float("nan")
        if timing_envs:
            seconds = _step_seconds(make("mujoco_warp", task, num_envs=timing_envs, seed=seed, **options), windows)
        row = {
            "fd_scheme": scheme,
            "fd_eps_state": eps_state,
            "fd_eps_control": sim.fd_eps_control,
            "worlds_per_env": sim.worlds_per_env_with_grad,
            "contact_free_state_error": free_state,
            "contact_free_control_error": free_control,
            "contact_state_error": ground_state,
            "contact_control_error": ground_control,
            "timing_envs": timing_envs,
            "seconds_per_step_with_grad": seconds,
            "env_steps_per_s_with_grad": timing_envs / seconds if timing_envs else float("nan"),
        }
        progress(
            f"  {scheme:8s} eps {eps_state:7.0e}: {row['worlds_per_env']:3d} worlds/env, contact-free error "
            f"{free_state:.1e} (state) {free_control:.1e} (control), with contact {ground_state:.1e} / "
            f"{ground_control:.1e}, {seconds:.2f} s per step of {timing_envs} envs"
        )
        rows.append(row)
    return {
        "task": task_name,
        "num_envs": num_envs,
        "settle": settle,
        "seed": seed,
        "windows": windows,
        "reference": "float64 MuJoCo C central differences (step 1e-6) of the same control step",
        "rows": rows,
    }


def markdown(report: dict, command: str) -> str:
    """The report as a Markdown table, with the command that made it."""
    lines = [
        f"# MuJoCo-Warp finite-difference schemes, {report['task']}",
        "",
        f"`{command}`",
        "",
        f"Errors: relative Frobenius error of one control step's Jacobians against {report['reference']}, "
        f"max over {report['num_envs']} envs. Contact-free: initial states lifted to 2 m. With contact: after "
        f"{report['settle']} zero-action steps on the ground (non-smooth: no exact reference; informative). "
        "Cost: one control step with gradients, best of "
        f"{report['windows']}.",
        "",
        "| scheme | state step | control step | worlds/env | contact-free state | contact-free control "
        "| with contact state | with contact control | s per step | env-steps/s with grad |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in report["rows"]:
        lines.append(
            f"| {r['fd_scheme']} | {r['fd_eps_state']:g} | {r['fd_eps_control']:g} | {r['worlds_per_env']} "
            f"| {r['contact_free_state_error']:.1e} | {r['contact_free_control_error']:.1e} "
            f"| {r['contact_state_error']:.1e} | {r['contact_control_error']:.1e} "
            f"| {r['seconds_per_step_with_grad']:.2f} ({r['timing_envs']} envs) "
            f"| {r['env_steps_per_s_with_grad']:.1f} |"
        )
    return "\n".join(lines) + "\n"
