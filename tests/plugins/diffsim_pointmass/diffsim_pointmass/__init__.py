"""An analytic point-mass engine and task, plugged into diffsim-bench through entry points.

The "engine" is a planar double integrator with linear drag, integrated with semi-implicit
Euler in plain torch, so autograd gives exact gradients:

    v' = v + dt * (u / m - c * v),    x' = x + dt * v'

with the drag ``c`` the task's ``PhysicsSpec.joint_damping`` per unit mass. A spec with a ground
plane or an armature is refused: this engine has neither.

State layout: no floating base, two slide dofs (x, y): joint_q = position, joint_qd = velocity.
"""

from __future__ import annotations

import torch

from backends.contract import BackendError, BatchedSim, inert_by_definition
from simcore import ControlKind, PhysicsSpec, SimState, StateLayout
from tasks.base import Task


class PointMassTask(Task):
    """Drive a 1 kg point to the origin: reward -|x|^2 - 0.01 |u|^2."""

    name = "pointmass"
    asset_format = "analytic"
    layout = StateLayout(num_dofs=2, floating_base=False)
    control_kind = ControlKind.JOINT_TORQUE
    action_dim = 2
    obs_dim = 6
    episode_length = 200
    max_force = 10.0

    def __init__(self, physics: PhysicsSpec | None = None):
        super().__init__(physics or PhysicsSpec(frame_dt=0.05, substeps=4, ground_plane=False, joint_damping=0.5))

    def sample_initial_state(self, num_envs, generator):
        q = 2.0 * torch.rand(num_envs, 2, generator=generator) - 1.0
        qd = 0.5 * (2.0 * torch.rand(num_envs, 2, generator=generator) - 1.0)
        return q, qd

    def actions_to_control(self, actions):
        return self.max_force * torch.clamp(actions, -1.0, 1.0)

    def observe(self, state: SimState, prev_actions):
        return torch.cat((state.joint_q, state.joint_qd, prev_actions), dim=-1)

    def reward(self, state, obs, actions, prev_actions):
        return -state.joint_q.pow(2).sum(-1) - 0.01 * actions.pow(2).sum(-1)

    def terminated(self, state, obs):
        return state.joint_q.abs().amax(-1) > 10.0


class PointMassSim(BatchedSim):
    """The contract implemented in ~30 lines of torch: no tape, no buffers, autograd does the rest."""

    name = "pointmass"
    contract_tasks = ("pointmass",)
    known_options = ()  # it reads none: any option is refused, never ignored
    mass = 1.0

    def _build(self) -> None:
        if not isinstance(self.task, PointMassTask):
            raise BackendError(f"the pointmass backend simulates only the pointmass task, not {self.task.name!r}")
        phys = self.task.physics
        if phys.ground_plane:
            raise BackendError("PhysicsSpec.ground_plane: the pointmass backend has no ground to contact")
        if phys.armature:
            raise BackendError("PhysicsSpec.armature: the pointmass backend has no rotor inertia")

    def physics_mapping(self) -> dict[str, str]:
        mapping = {
            "frame_dt": "substeps Euler steps of frame_dt / substeps",
            "substeps": "Euler steps per control step",
            "gravity": "inert: gravity acts along z, the point moves in the x-y plane",
            "ground_plane": "False only (refused otherwise)",
            "joint_limit_ke": "inert: the point has no joint limits",
            "joint_limit_kd": "inert: the point has no joint limits",
            "joint_damping": "the linear drag c = joint_damping / mass",
            "armature": "None or 0 only (refused otherwise)",
        }
        mapping.update(inert_by_definition(self.task))
        return mapping

    def state_from_generalized(self, joint_q, joint_qd, particle_q=None, particle_qd=None) -> SimState:
        joint_q = joint_q.to(self.device, torch.float32)
        joint_qd = joint_qd.to(self.device, torch.float32)
        return SimState(joint_q=joint_q, joint_qd=joint_qd, engine=torch.cat((joint_q, joint_qd), dim=-1))

    def _control_joint_torque(self, control: torch.Tensor) -> torch.Tensor:
        """JOINT_TORQUE: the force on the point, as given."""
        return control

    def simulate(self, state: SimState, control: torch.Tensor) -> SimState:
        control = self.engine_control(control)
        x, v = state.engine[:, :2], state.engine[:, 2:]
        dt = self.task.physics.sim_dt
        drag = self.task.physics.joint_damping / self.mass
        for _ in range(self.task.physics.substeps):
            v = v + dt * (control / self.mass - drag * v)
            x = x + dt * v
        return SimState(joint_q=x, joint_qd=v, engine=torch.cat((x, v), dim=-1))
