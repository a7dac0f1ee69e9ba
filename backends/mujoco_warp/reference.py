"""A float64 reference for the adapter's finite-difference Jacobians: MuJoCo C on the same model.

One control step of an articulated task (``substeps`` ``mj_step`` calls, the joint torque or the
task's PD law as ``qfrc_applied`` before each substep, warm start zeroed at the start, exactly as
:meth:`MujocoWarpSim._run_worlds` does on Warp) is differenced centrally in float64 with a tiny
step, in the adapter's own tangent coordinates (:meth:`MujocoWarpSim._retract`). The result has the
adapter's layout: rows are the ambient next engine state, columns the tangent state and controls.
Float64 with a step of 1e-6 leaves a truncation error of ~1e-12 and a round-off error of ~1e-10
relative, so on smooth (contact-free) states the reference is exact for the purpose of comparing
float32 schemes whose errors are 1e-5 and above. ``mjd_transitionFD`` (MuJoCo's own float64 finite
differences, chained over the substeps) agrees with it; ``tests/test_mujoco_warp_ant.py`` checks
the adapter against both.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch


def c_control_step(sim, qpos: np.ndarray, qvel: np.ndarray, control: torch.Tensor, data=None, model=None) -> np.ndarray:
    """Next ``[qpos, qvel]`` of one control step on MuJoCo C in float64 (one world), on the adapter's
    model or on ``model`` (the same model with other solver settings)."""
    model = model if model is not None else sim.mjm
    data = data if data is not None else mujoco.MjData(model)
    mujoco.mj_resetData(model, data)
    data.qpos[:], data.qvel[:] = qpos, qvel
    control = control.to(torch.float64)
    for _ in range(sim.task.physics.substeps):
        _apply_control(sim, data, control)
        mujoco.mj_step(model, data)
    return np.concatenate((data.qpos, data.qvel))


def _apply_control(sim, data, control: torch.Tensor) -> None:
    """The joint forces of one substep, as the adapter applies them: the torques, or the task's PD law
    on the current hinge state."""
    layout, phys = sim.layout, sim.task.physics
    root_q, root_v = layout.nq - layout.num_dofs, layout.nv - layout.num_dofs
    if sim.position_control:
        hinge_q = torch.from_numpy(data.qpos[root_q:].copy())
        hinge_qd = torch.from_numpy(data.qvel[root_v:].copy())
        data.qfrc_applied[root_v:] = phys.pd_torque(control, hinge_q, hinge_qd).numpy()
    else:
        data.qfrc_applied[root_v:] = control.numpy()


def float64_step_jacobians(sim, engine: torch.Tensor, control: torch.Tensor, eps: float = 1e-6, model=None):
    """(next engine (D,), d next / d tangent state (D, 2 nv), d next / d control (D, J)) of one env's
    control step, by float64 central differences of :func:`c_control_step` with step ``eps`` (on
    ``model`` when given)."""
    if sim.soft:
        raise ValueError("the float64 reference covers articulated tasks (soft bodies have their own check)")
    engine = engine.detach().to(torch.float64).reshape(1, -1)
    control = control.detach().to(torch.float64).reshape(1, -1)
    coords = sim._fd_steps.numel()
    eye = torch.eye(coords, dtype=torch.float64)
    deltas = torch.cat((torch.zeros(1, coords, dtype=torch.float64), eps * eye, -eps * eye))
    qpos, qvel, controls = sim._retract(engine, control, deltas)
    model = model if model is not None else sim.mjm
    data = mujoco.MjData(model)
    outputs = np.stack(
        [
            c_control_step(sim, qpos[k].numpy(), qvel[k].numpy(), controls[k], data, model)
            for k in range(deltas.shape[0])
        ]
    )
    jac = (outputs[1 : 1 + coords] - outputs[1 + coords :]).T / (2.0 * eps)
    state_cols = 2 * sim.layout.nv
    return outputs[0], jac[:, :state_cols], jac[:, state_cols:]


def accurate_model(mjm):
    """A copy of ``mjm`` whose solver runs its full iteration count (tolerances 0): nominal and
    perturbed solves of a finite difference then stop at the same point."""
    import copy

    model = copy.copy(mjm)
    model.opt.tolerance = 0.0
    model.opt.ls_tolerance = 0.0
    return model


#: a contact sticks when its friction force stays inside the cone by this margin (else it slides)
STICK_MARGIN = 0.98


def classify_step(sim, model, engine: torch.Tensor, control: torch.Tensor) -> dict:
    """What MuJoCo C sees during one control step of one env from ``engine`` on ``model``: the
    contacts at the start, whether a contact is made or broken during the step (onset), whether a
    joint limit is active, and whether friction slides: ``sliding`` when some pushing contact's
    friction force reaches the Coulomb cone (|f_t| >= STICK_MARGIN mu f_n) in some substep, the
    regime switch where the penalty friction law turns from viscous to capped; ``sticking`` when
    every pushing contact stays inside the cone throughout."""
    qpos, qvel = (x.double().numpy() for x in sim._split(engine.reshape(1, -1).double()))
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = qpos[0], qvel[0]
    control = control.double()
    counts, limits, pushing, sliding = [], False, 0, False
    force = np.zeros(6)
    for _ in range(sim.task.physics.substeps):
        _apply_control(sim, data, control)
        mujoco.mj_step(model, data)
        counts.append(int(data.ncon))
        limits |= bool(np.any(data.efc_type[: data.nefc] == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT))
        for i in range(data.ncon):  # the constraint forces of this substep's solve, in the contact frame
            mujoco.mj_contactForce(model, data, i, force)
            if force[0] > 0.0:
                pushing += 1
                sliding |= bool(np.hypot(force[1], force[2]) >= STICK_MARGIN * data.contact[i].friction[0] * force[0])
    return {
        "contacts": counts[0],
        "onset": len(set(counts)) > 1,
        "limit": limits,
        "sliding": sliding,
        "sticking": pushing > 0 and not sliding,
    }


__all__ = ["accurate_model", "c_control_step", "classify_step", "float64_step_jacobians"]
