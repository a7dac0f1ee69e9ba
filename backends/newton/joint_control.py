"""Joint controls of an articulation (:mod:`backends.newton.articulation`): how the control tensor
reaches every substep of a frame.

* :class:`JointTorques` (``JOINT_TORQUE``): the step's generalized forces, shared by its substeps.
* :class:`PositionTargets` (``JOINT_POSITION_TARGET``): the PD law (``PhysicsSpec.pd_torque``) as a
  kernel on the tape before every substep, reading that substep's joint coordinates and writing that
  substep's own ``joint_f``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import newton
import numpy as np
import warp as wp

from backends.newton.tape import Frame
from simcore import SimState

if TYPE_CHECKING:
    from backends.newton.articulation import Articulation


class JointTorques:
    """``JOINT_TORQUE``: the control tensor is the step's generalized forces (``joint_f``), shared by
    every substep."""

    def __init__(self, articulation: Articulation):
        self.articulation = articulation

    def add_frame_buffers(self, frame: Frame) -> None:
        pass

    def control_array(self, frame: Frame) -> wp.array:
        return frame.control.joint_f

    def substep_control(self, state: newton.State, frame: Frame, s: int) -> newton.Control:
        return frame.control

    def bare_controls(self, horizon: int, rng, grad: bool, current: SimState):
        art = self.articulation
        layout, n = art.layout, art.num_envs
        controls = [art.model.control(requires_grad=grad) for _ in range(horizon)]
        for control in controls:
            f = np.zeros((n, layout.nv), dtype=np.float32)
            f[:, layout.nv - layout.num_dofs :] = rng.uniform(-100.0, 100.0, (n, layout.num_dofs))
            control.joint_f.assign(f.ravel())
        return lambda t, s, state: controls[t]


class PositionTargets:
    """``JOINT_POSITION_TARGET``: the (N, J) targets; :func:`_pd_torque` turns them into each
    substep's own ``joint_f`` from that substep's joint coordinates (a shared buffer would be
    overwritten before the tape replays it)."""

    def __init__(self, articulation: Articulation):
        self.articulation = articulation
        limits = articulation.physics.torque_limits or (float("inf"),) * articulation.layout.num_dofs
        self.limits = wp.array(np.asarray(limits, dtype=np.float32), dtype=float, device=articulation.model.device)

    def add_frame_buffers(self, frame: Frame) -> None:
        art = self.articulation
        subs = art.physics.substeps
        size = art.num_envs * art.layout.num_dofs
        frame.target = wp.zeros(size, dtype=float, device=art.model.device, requires_grad=True)
        frame.pd = [art.model.control(requires_grad=True) for _ in range(subs)]
        frame.pd_coordinates = [art.new_pd_coordinate_buffers() for _ in range(subs)]

    def control_array(self, frame: Frame) -> wp.array:
        return frame.target

    def substep_control(self, state: newton.State, frame: Frame, s: int) -> newton.Control:
        """PhysicsSpec.pd_torque from the substep's joint coordinates into the substep's joint_f."""
        q, qd = self.articulation.pd_coordinates(state, frame.pd_coordinates[s])
        self.launch(frame.target, q, qd, frame.pd[s].joint_f)
        return frame.pd[s]

    def launch(self, target: wp.array, q: wp.array, qd: wp.array, joint_f: wp.array) -> None:
        """One launch of :func:`_pd_torque` with the task's gains and limits."""
        art = self.articulation
        layout, phys = art.layout, art.physics
        wp.launch(
            _pd_torque,
            dim=(art.num_envs, layout.num_dofs),
            inputs=[target, q, qd, self.limits, phys.pd_kp, phys.pd_kd, layout.nq, layout.nv, layout.num_dofs],
            outputs=[joint_f],
            device=art.model.device,
        )

    def bare_controls(self, horizon: int, rng, grad: bool, current: SimState):
        """One control per substep, targets within a quarter radian of the current pose; the PD kernel
        reads the state's own joint coordinates (filled by IK on maximal coordinates)."""
        art = self.articulation
        model, subs = art.model, art.physics.substeps
        controls = [model.control(requires_grad=grad) for _ in range(horizon * subs)]
        targets = []
        for _ in range(horizon):
            q = current.dof_q(art.layout).detach().cpu().numpy()
            values = (q + rng.uniform(-0.25, 0.25, q.shape)).astype(np.float32).ravel()
            targets.append(wp.array(values, dtype=float, device=model.device, requires_grad=grad))

        def control(t: int, s: int, state: newton.State) -> newton.Control:
            q, qd = art.pd_coordinates(state, (state.joint_q, state.joint_qd))
            self.launch(targets[t], q, qd, controls[s].joint_f)
            return controls[s]

        return control


@wp.kernel
def _pd_torque(
    target: wp.array[float],
    joint_q: wp.array[float],
    joint_qd: wp.array[float],
    limit: wp.array[float],
    kp: float,
    kd: float,
    nq: int,
    nv: int,
    num_dofs: int,
    joint_f: wp.array[float],
):
    """tau = clip(kp (q* - q) - kd qd, -limit, limit) on the articulated dofs (PhysicsSpec.pd_torque)."""
    env, j = wp.tid()
    q = joint_q[env * nq + nq - num_dofs + j]
    qd = joint_qd[env * nv + nv - num_dofs + j]
    tau = kp * (target[env * num_dofs + j] - q) - kd * qd
    joint_f[env * nv + nv - num_dofs + j] = wp.clamp(tau, -limit[j], limit[j])
