"""The Go2 task on both adapters: asset, PD control, standing, gradients, bad input.

The contract suite (tests/test_contract.py) also runs on Go2 for both adapters; what is here is
specific to this robot and to ``JOINT_POSITION_TARGET``.
"""

from __future__ import annotations

import dataclasses
import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest
import torch

pytest.importorskip("newton")
pytest.importorskip("mujoco_warp")

import mujoco  # noqa: E402

from backends import BackendError, InvalidActionError, make  # noqa: E402
from backends.mujoco_warp.reference import float64_step_jacobians  # noqa: E402
from simcore import PhysicsSpec, SimState, StateLayout  # noqa: E402
from tasks.go2 import DEFAULT_DOF_Q, JOINT_NAMES, TORQUE_LIMITS, Go2  # noqa: E402

BACKENDS = ("newton", "mujoco_warp")


@pytest.fixture(scope="module")
def go2():
    return Go2()


def _variant(base_task: Go2, **attributes) -> Go2:
    """A Go2 whose class attributes (asset, layout, ...) differ; physics as given or the Go2's."""
    physics = attributes.pop("physics", base_task.physics)
    cls = type("Go2Variant", (Go2,), attributes)
    return cls(physics)


class FixedBaseGo2(Go2):
    """The Go2 bolted to the world in its default pose, no ground: joints only."""

    name = "go2_fixed_base"
    layout = StateLayout(num_dofs=12, floating_base=False)

    def default_state(self):
        return torch.tensor(DEFAULT_DOF_Q), torch.zeros(12)

    def sample_initial_state(self, num_envs, generator):
        q, qd = self.default_state()
        return q.repeat(num_envs, 1), qd.repeat(num_envs, 1)


# -- 1. the asset --------------------------------------------------------------------------------
def test_the_project_urdf_has_primitive_collisions_only_and_the_robots_mass(go2):
    root = ElementTree.parse(go2.asset_path).getroot()
    assert not root.findall(".//visual") and not root.findall(".//material") and not root.findall(".//mesh")
    joints = [j for j in root.findall("joint") if j.get("type") == "revolute"]
    assert tuple(j.get("name") for j in joints) == JOINT_NAMES
    assert not [j for j in root.findall("joint") if j.get("type") != "revolute"]
    assert [float(j.find("limit").get("effort")) for j in joints] == list(TORQUE_LIMITS)
    total = sum(float(m.get("value")) for m in root.findall("link/inertial/mass"))
    assert abs(total - 16.087) < 1e-6  # Unitree's description: every link, rotors and feet folded in
    spheres = root.findall(".//collision/geometry/sphere")
    assert len(spheres) == 4 and all(float(s.get("radius")) == 0.022 for s in spheres)


def test_both_adapters_load_the_same_file_with_the_same_mass_and_joint_order(go2):
    newton_sim = make("newton", go2, num_envs=1)
    mujoco_sim = make("mujoco_warp", go2, num_envs=1)
    newton_mass = float(newton_sim.model.body_mass.numpy().sum())
    assert abs(newton_mass - mujoco_sim.mjm.body_subtreemass[0]) < 1e-4
    labels = [label.split("/")[-1] for label in newton_sim.model.joint_label]
    assert tuple(labels[1:]) == JOINT_NAMES
    hinges = [mujoco_sim.mjm.joint(i).name for i in range(1, mujoco_sim.mjm.njnt)]
    assert tuple(hinges) == JOINT_NAMES
    assert mujoco_sim.mjm.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE  # the adapter's own free joint


@pytest.mark.parametrize("backend", BACKENDS)
def test_unitrees_official_urdf_loads_and_steps(backend, shared_dir, go2):
    """Meshes, materials, rotor and foot links as Unitree ships them (../shared)."""
    official = _variant(go2, asset_path=shared_dir / "assets" / "go2_description" / "go2_description.urdf")
    sim = make(backend, official, num_envs=2, seed=0)
    assert sim.state.joint_q.shape == (2, 19)
    with torch.no_grad():
        for _ in range(3):
            state = sim.step(torch.zeros(2, 12))
    assert torch.isfinite(state.engine).all()


# -- 2. control ----------------------------------------------------------------------------------
def test_actions_map_to_targets_around_the_default_pose(go2):
    actions = torch.tensor([[1.0] * 12, [-1.0] * 12, [0.0] * 12])
    targets = go2.actions_to_control(actions)
    default = torch.tensor(DEFAULT_DOF_Q)
    assert torch.allclose(targets[2], default)
    assert torch.allclose(targets[0] - default, torch.full((12,), go2.action_scale))


def test_the_pd_law_clips_to_each_joints_torque_limit(go2):
    q = torch.zeros(1, 12)
    tau = go2.physics.pd_torque(torch.full((1, 12), 10.0), q, q)
    assert torch.equal(tau[0], torch.tensor(TORQUE_LIMITS))


def test_a_step_target_on_one_joint_gives_the_same_response_in_both_engines(go2):
    """Fixed base, no ground, FL calf target stepped by +0.25 rad for 30 control steps.

    Measured: the driven joint's trajectories differ by at most 1.8e-5 rad, every joint by 5.9e-5 rad
    (float32 engines, same PD law per substep, same armature; the limits are not reached).
    """
    task = FixedBaseGo2(dataclasses.replace(go2.physics, ground_plane=False))
    actions = torch.zeros(1, 12)
    actions[0, 2] = 1.0
    trajectories = {}
    for backend in BACKENDS:
        sim = make(backend, task, num_envs=1, seed=0)
        with torch.no_grad():
            trajectories[backend] = torch.stack([sim.step(actions).joint_q[0].clone() for _ in range(30)])
    newton_traj, mujoco_traj = trajectories["newton"], trajectories["mujoco_warp"]
    calf = newton_traj[:, 2]
    assert calf.max() > DEFAULT_DOF_Q[2] + 0.3  # it moved: overshoot past the +0.25 rad target
    difference = (newton_traj - mujoco_traj).abs().max()
    print(f"fixed-base step response, max |newton - mujoco| over 30 steps: {difference:.2e} rad")
    assert difference < 1e-3


# -- 3. the task ---------------------------------------------------------------------------------
def _state(q: torch.Tensor, qd: torch.Tensor) -> SimState:
    return SimState(joint_q=q, joint_qd=qd, engine=torch.cat((q, qd), dim=1))


def test_observation_and_reward_of_a_standing_go2(go2):
    q, qd = go2.default_state()
    q, qd = q[None].clone(), qd[None].clone()
    q[0, 2] = go2.height_target
    qd[0, 0] = 1.5  # forward
    zeros = torch.zeros(1, 12)
    obs = go2.observe(_state(q, qd), zeros)
    assert obs.shape == (1, go2.obs_dim)
    assert torch.allclose(obs[0, 1:4], torch.tensor([0.0, 0.0, -1.0]))  # gravity in the trunk frame
    assert torch.allclose(obs[0, 4:7], torch.tensor([1.5, 0.0, 0.0]))
    assert torch.allclose(obs[0, 10:22], torch.zeros(12))  # at the default pose
    reward = go2.reward(_state(q, qd), obs, zeros, zeros)
    # upright at the target height: forward speed + upright bonus - torque penalty (gravity-free PD: 0 torque)
    assert torch.allclose(reward, torch.tensor([1.5 + go2.up_weight]))
    jerk = go2.reward(_state(q, qd), obs, zeros, torch.ones(1, 12))
    assert torch.allclose(reward - jerk, torch.tensor([go2.action_rate_weight * 12]))
    assert not bool(go2.terminated(_state(q, qd), obs))


def test_the_episode_ends_when_the_trunk_falls_or_tips(go2):
    q, qd = go2.default_state()
    q = q.repeat(3, 1)
    q[1, 2] = 0.1  # down
    q[2, 3:7] = torch.tensor([0.7071068, 0.0, 0.0, 0.7071068])  # rolled onto its side
    done = go2.terminated(_state(q, qd.repeat(3, 1)), None)
    assert done.tolist() == [False, True, True]


def test_initial_states_are_randomised_around_the_default_pose(go2):
    q, qd = go2.sample_initial_state(64, torch.Generator().manual_seed(0))
    deviation = (q[:, 7:] - torch.tensor(DEFAULT_DOF_Q)).abs()
    assert 0.05 < deviation.max() <= 0.1 and q[:, 2].min() >= 0.36
    assert torch.allclose(q[:, 3:7].norm(dim=1), torch.ones(64))


# -- 4. standing ---------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", BACKENDS)
def test_a_go2_under_zero_actions_stands(backend, go2):
    """120 steps (2 s) here; the 1000-step record is in results/go2_standing.json."""
    sim = make(backend, go2, num_envs=2, seed=3)
    with torch.no_grad():
        for _ in range(120):
            state = sim.step(torch.zeros(2, 12))
    height = state.root_pos[:, 2]
    assert bool((height > 0.24).all() and (height < 0.32).all()), height
    assert bool((go2.up_z(state) > 0.95).all())


# -- 5. gradients (the contract suite runs gradcheck on 4 contact-free steps on both adapters) ----
# -- 5. gradients (the contract suite runs gradcheck on 4 contact-free steps on both adapters) ----
def test_newton_action_gradients_in_stance_match_finite_differences(go2):
    """Four feet on the ground, contact forces acting (90 settling steps, then 8 steps of small actions;
    rewards only; 16 random directions). Featherstone rewrites its external wrenches in place, and
    without the adapter's restore for the tape's replay d reward / d actions is off by 9.7% here
    (2.0e-3 with it; per coordinate 9.8% and 1.3e-3). Only the action gradient is asserted: the
    state gradient in stance crosses the contact-damping kink (damping acts only while a foot moves
    into the ground), where central differences measure no derivative (docs/tasks.md, "Go2
    gradients")."""
    from harness.checks.gradcheck import DEFAULT_TOLERANCE, gradcheck

    sim = make("newton", go2, num_envs=2, seed=1, max_graph_steps=8)
    result = gradcheck(sim, steps=8, seed=0, action_scale=0.1, settle_steps=90, value_probe=False, max_coordinates=0)
    assert result.action_rel_error < DEFAULT_TOLERANCE, result


@pytest.mark.parametrize("scheme, worlds", [("central", 97), ("forward", 49)])
def test_mujoco_warp_target_jacobians_match_mujoco_c_in_float64(go2, scheme, worlds):
    """One control step in the air: the batched finite differences (97 worlds per env central, 49
    forward) against float64 MuJoCo C central differences (step 1e-6) of the same step, PD law per
    substep. Measured max relative (Frobenius) error: central 1.8e-5 (state) and 1.8e-5 (targets),
    forward ~2e-4 and ~4e-5."""
    sim = make("mujoco_warp", go2, num_envs=2, seed=0, fd_scheme=scheme)
    assert sim.worlds_per_env_with_grad == worlds
    gen = torch.Generator().manual_seed(3)
    q, qd = go2.sample_initial_state(2, gen)
    q[:, 2] = 1.0
    targets = go2.actions_to_control(0.5 * (2 * torch.rand(2, 12, generator=gen) - 1))
    engine = sim.state_from_generalized(q, qd).engine.detach()
    _, jac_state, jac_target = sim.fd_jacobians(engine, targets)
    for i in range(2):
        _, ref_state, ref_target = float64_step_jacobians(sim, engine[i], targets[i])
        err_state = np.linalg.norm(jac_state[i].numpy() - ref_state) / np.linalg.norm(ref_state)
        err_target = np.linalg.norm(jac_target[i].numpy() - ref_target) / np.linalg.norm(ref_target)
        assert err_state < 1e-3 and err_target < 1e-3, (err_state, err_target)


# -- 9. bad input --------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", BACKENDS)
def test_a_missing_urdf_is_one_clear_error(backend, go2, tmp_path):
    task = _variant(go2, asset_path=tmp_path / "nowhere.urdf")
    with pytest.raises(BackendError, match="cannot load urdf asset .*nowhere.urdf") as info:
        make(backend, task, num_envs=1)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_malformed_urdf_is_one_clear_error(backend, go2, tmp_path):
    broken = tmp_path / "broken.urdf"
    broken.write_text(go2.asset_path.read_text()[:5000])  # cut off mid-element
    with pytest.raises(BackendError, match="cannot load urdf asset .*broken.urdf") as info:
        make(backend, _variant(go2, asset_path=broken), num_envs=1)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_urdf_with_the_wrong_joint_count_is_refused(backend, go2, tmp_path):
    """The Go2 file for a task that expects 8 joints (and the reverse: a 12-joint task, a 9-joint file)."""
    eight = dataclasses.replace(go2.physics, torque_limits=(23.7,) * 8)
    task = _variant(go2, layout=StateLayout(num_dofs=8, floating_base=True), action_dim=8, physics=eight)
    with pytest.raises(BackendError, match="task 'go2' expects") as info:
        make(backend, task, num_envs=1)
    assert "\n" not in str(info.value)
    root = ElementTree.parse(go2.asset_path).getroot()
    for name in ("RR_hip", "RR_thigh", "RR_calf"):
        root.remove(next(link for link in root.findall("link") if link.get("name") == name))
        root.remove(next(joint for joint in root.findall("joint") if joint.get("name") == f"{name}_joint"))
    three_legs = tmp_path / "three_legs.urdf"
    three_legs.write_text(ElementTree.tostring(root, encoding="unicode"))
    with pytest.raises(BackendError, match="expects"):
        make(backend, _variant(go2, asset_path=three_legs), num_envs=1)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_nan_target_is_refused_before_the_engine(backend, go2):
    sim = make(backend, go2, num_envs=2)
    actions = torch.zeros(2, 12)
    actions[1, 4] = float("nan")
    before = sim.state.engine.clone()
    with pytest.raises(InvalidActionError, match=r"NaN or inf for env\(s\) \[1\]"):
        sim.step(actions)
    assert torch.equal(sim.state.engine, before)
    direct = torch.full((2, 12), float("nan"))
    with pytest.raises(
        InvalidActionError, match=r"joint_position_target control contains NaN or inf for env\(s\) \[0, 1\]"
    ):
        sim.simulate(sim.state, direct)


def test_a_bad_torque_limit_count_is_refused(go2):
    """By the task when it is built; the adapters refuse it too for a task that reaches them anyway."""
    physics = dataclasses.replace(go2.physics, torque_limits=(23.7,) * 11)
    with pytest.raises(ValueError, match="torque_limits has 11 limits; task 'go2' has 12 joints"):
        Go2(physics)
    task = Go2()
    task.physics = physics
    for backend in BACKENDS:
        with pytest.raises(BackendError, match="11 torque limits for 12 joints of task 'go2'"):
            make(backend, task, num_envs=1)


def test_physics_spec_refuses_a_negative_armature():
    with pytest.raises(ValueError, match="armature"):
        PhysicsSpec(armature=-0.1)
