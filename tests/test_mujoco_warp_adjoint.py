"""The analytic adjoint of MuJoCo-Warp's step (``gradients=adjoint``): each part against MuJoCo C,
the whole control step's Jacobians against float64 central differences in and out of contact, the
contract suite in that mode, and the refusals of what it does not cover."""

from __future__ import annotations

import numpy as np
import pytest
import torch

mujoco = pytest.importorskip("mujoco")
pytest.importorskip("mujoco_warp")

from backends import BackendError, make  # noqa: E402
from backends.mujoco_warp import build_spec  # noqa: E402
from backends.mujoco_warp.adjoint import dynamics  # noqa: E402
from backends.mujoco_warp.adjoint.integrate import quat_mul_wxyz, rotation_quat  # noqa: E402
from backends.mujoco_warp.adjoint.step import substep  # noqa: E402
from backends.mujoco_warp.adjoint.tree import rigid_tree  # noqa: E402
from backends.mujoco_warp.reference import accurate_model, float64_step_jacobians  # noqa: E402
from harness.contract_suite import ContractSuite  # noqa: E402
from tasks import make_task  # noqa: E402


@pytest.fixture(scope="module")
def ant():
    return make_task("ant")


@pytest.fixture(scope="module")
def model(ant):
    return build_spec(ant).compile()


def _random_states(m, count, seed):
    rng = np.random.default_rng(seed)
    d = mujoco.MjData(m)
    for _ in range(count):
        d.qpos[:] = m.qpos0 + 0.3 * rng.standard_normal(m.nq)
        d.qpos[3:7] /= np.linalg.norm(d.qpos[3:7])
        d.qpos[2] += 1.0
        d.qvel[:] = rng.standard_normal(m.nv)
        mujoco.mj_forward(m, d)
        yield d


def test_kinematics_mass_matrix_and_bias_forces_equal_mujocos(model):
    tree = rigid_tree(model)
    for d in _random_states(model, 4, seed=0):
        kin = dynamics.kinematics(tree, torch.tensor(d.qpos[None]))
        mass = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, d, mass)
        assert np.allclose(kin.origin[0].numpy(), d.xpos, atol=1e-12)
        assert np.allclose(kin.rot[0].numpy().reshape(-1, 9), d.xmat, atol=1e-12)
        assert np.allclose(dynamics.mass_matrix(tree, kin)[0].numpy(), mass, rtol=1e-10, atol=1e-12)
        bias = dynamics.bias_force(tree, kin, torch.tensor(d.qvel[None]))[0].numpy()
        assert np.allclose(bias, d.qfrc_bias, rtol=1e-10, atol=1e-10)


def _settled_in_contact(m, steps=300, seed=1):
    """A MuJoCo C Ant walked by random torques until it stands on the ground."""
    rng = np.random.default_rng(seed)
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    d.qpos[2] = 0.5
    for _ in range(steps):
        d.qfrc_applied[6:] = 8.0 * rng.uniform(-1, 1, m.nv - 6)
        mujoco.mj_step(m, d)
    assert d.ncon >= 2
    return d


def test_the_replayed_step_equals_mujocos_in_contact(model):
    """Given MuJoCo's converged acceleration, the replay's next state is MuJoCo's own (constraint rows,
    cone zones, implicit damping and integration included), to float64 round-off."""
    m = accurate_model(model)
    tree = rigid_tree(m)
    d = _settled_in_contact(m)
    for _ in range(5):
        q0, v0, f0 = d.qpos.copy(), d.qvel.copy(), d.qfrc_applied.copy()
        mujoco.mj_step(m, d)
        q1, v1 = substep(tree, *(torch.tensor(x[None]) for x in (q0, v0, f0, d.qacc)))
        assert np.abs(q1[0].numpy() - d.qpos).max() < 1e-12
        assert np.abs(v1[0].numpy() - d.qvel).max() < 1e-10 * max(1.0, np.abs(d.qvel).max())


def test_one_step_jacobian_equals_mujocos_transition_derivatives_in_contact(model):
    """``mjd_transitionFD`` (float64 central differences, solver converged) against the replay's
    autograd Jacobian in MuJoCo's tangent coordinates, in contact."""
    m = accurate_model(model)
    tree, nv = rigid_tree(m), m.nv
    d = _settled_in_contact(m)
    mujoco.mj_forward(m, d)
    reference = np.zeros((2 * nv, 2 * nv))
    mujoco.mjd_transitionFD(m, d, 1e-6, 1, reference, None, None, None)
    jac = _replay_jacobian(m, tree, d)
    assert np.linalg.norm(jac - reference) / np.linalg.norm(reference) < 1e-5


BOX_ON_A_HINGE = """
<mujoco>
  <option timestep="0.001" cone="elliptic" impratio="0.3"/>
  <worldbody>
    <geom type="plane" size="0 0 1" contype="0" conaffinity="1"/>
    <body pos="0 0 0.12">
      <freejoint/>
      <geom type="box" size="0.2 0.1 0.05" mass="3" priority="1" condim="3" friction="0.75"
            solref="-4000 -100" solimp="0.1 0.1 0.001 0.5 2" contype="1" conaffinity="0"/>
      <body pos="0.2 0 0">
        <joint type="hinge" axis="0 1 0" range="-0.5 0.5" damping="0.5"
               solreflimit="-1000 -10" solimplimit="0.1 0.1 0.001 0.5 2"/>
        <geom type="capsule" fromto="0 0 0 0.15 0 -0.1" size="0.03" mass="0.5" priority="1" condim="3"
              friction="0.75" solref="-4000 -100" solimp="0.1 0.1 0.001 0.5 2" contype="1" conaffinity="0"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_a_tilted_box_on_its_corners_matches_mujocos_transition_derivatives():
    """Box corners (up to eight contacts) and a capsule on a hinge: the one-step Jacobian in contact."""
    m = accurate_model(mujoco.MjModel.from_xml_string(BOX_ON_A_HINGE))
    tree, nv = rigid_tree(m), m.nv
    d = mujoco.MjData(m)
    d.qpos[3:7] = [0.98, 0.12, 0.15, 0.0]
    d.qpos[3:7] /= np.linalg.norm(d.qpos[3:7])
    for _ in range(400):
        mujoco.mj_step(m, d)
    mujoco.mj_forward(m, d)
    box_contacts = sum(int(d.contact.geom[i][1]) == 1 for i in range(d.ncon))
    assert box_contacts >= 2 and d.ncon > box_contacts, (d.ncon, box_contacts)  # corners and the capsule
    reference = np.zeros((2 * nv, 2 * nv))
    mujoco.mjd_transitionFD(m, d, 1e-6, 1, reference, None, None, None)
    jac = _replay_jacobian(m, tree, d)
    assert np.linalg.norm(jac - reference) / np.linalg.norm(reference) < 1e-5


def test_the_go2_on_its_leg_cylinders_matches_mujocos_transition_derivatives():
    """A tilted Go2 dropped onto its thigh and calf cylinders: their four rim points per cylinder move
    with the configuration; the one-step Jacobian in contact."""
    m = accurate_model(build_spec(make_task("go2")).compile())
    tree = rigid_tree(m)
    d = mujoco.MjData(m)
    d.qpos[:] = m.qpos0
    d.qpos[2] = 0.35
    d.qpos[3:7] = np.array([0.9, 0.3, 0.3, 0.0]) / np.linalg.norm([0.9, 0.3, 0.3, 0.0])
    rng = np.random.default_rng(0)
    for _ in range(400):
        d.qfrc_applied[6:] = rng.uniform(-3, 3, m.nv - 6)
        mujoco.mj_step(m, d)
    mujoco.mj_forward(m, d)
    cylinder = int(mujoco.mjtGeom.mjGEOM_CYLINDER)
    assert any(int(m.geom_type[d.contact.geom[i][1]]) == cylinder for i in range(d.ncon))
    reference = np.zeros((2 * m.nv, 2 * m.nv))
    mujoco.mjd_transitionFD(m, d, 1e-6, 1, reference, None, None, None)
    jac = _replay_jacobian(m, tree, d)
    assert np.linalg.norm(jac - reference) / np.linalg.norm(reference) < 1e-5


def _replay_jacobian(m, tree, d) -> np.ndarray:
    """The replay's autograd Jacobian of one step at ``d`` in MuJoCo's tangent coordinates."""
    nv = m.nv
    after = mujoco.MjData(m)
    after.qpos[:], after.qvel[:], after.qfrc_applied[:] = d.qpos, d.qvel, d.qfrc_applied
    after.qacc_warmstart[:] = d.qacc_warmstart
    mujoco.mj_step(m, after)
    q0, v0, f0, qacc = (torch.tensor(x.copy()) for x in (d.qpos, d.qvel, d.qfrc_applied, after.qacc))
    nominal = torch.tensor(after.qpos.copy())

    def step(delta):
        quat = quat_mul_wxyz(q0[3:7], rotation_quat(delta[3:6]))
        q = torch.cat((q0[:3] + delta[:3], quat, q0[7:] + delta[6:nv]))[None]
        q1, v1 = substep(tree, q, (v0 + delta[nv:])[None], f0[None], qacc[None])
        turn = quat_mul_wxyz(torch.cat((nominal[3:4], -nominal[4:7])), q1[0, 3:7])
        return torch.cat((q1[0, :3] - nominal[:3], 2.0 * turn[1:], q1[0, 7:] - nominal[7:], v1[0]))

    return torch.func.jacrev(step)(torch.zeros(2 * nv, dtype=torch.float64)).numpy()


@pytest.fixture(scope="module", params=["ant", "go2"])
def adjoint(request):
    return make("mujoco_warp", make_task(request.param), num_envs=4, seed=0, gradients="adjoint")


def _in_contact(sim, task, steps=40):
    sim.reset()
    gen = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for _ in range(steps):
            sim.step(0.5 * (2.0 * torch.rand(sim.num_envs, task.action_dim, generator=gen) - 1.0))
    control = task.actions_to_control(2.0 * torch.rand(sim.num_envs, task.action_dim, generator=gen) - 1.0)
    return sim.state.engine.detach(), control


@pytest.mark.parametrize("where", ["contact", "air"])
def test_control_step_jacobians_match_float64_central_differences(adjoint, where):
    """The whole control step (16 substeps, the engine's float32 states) against MuJoCo C float64 central
    differences: far inside finite differences' own error (docs/mujoco-warp.md)."""
    engine, control = _in_contact(adjoint, adjoint.task)
    if where == "air":
        engine = engine.clone()
        engine[:, 2] += 1.0
    _, jac_state, jac_control = adjoint.step_jacobians(engine, control)
    reference_model = accurate_model(adjoint.mjm)
    for i in range(engine.shape[0]):
        _, ref_state, ref_control = float64_step_jacobians(adjoint, engine[i], control[i], model=reference_model)
        ref = np.concatenate((ref_state, ref_control), axis=1)
        mine = np.concatenate((jac_state[i].numpy(), jac_control[i].numpy()), axis=1)
        assert np.linalg.norm(mine - ref) / np.linalg.norm(ref) < 1e-4, i


def test_the_backward_pass_is_the_jacobians_vector_product(adjoint):
    engine, control = _in_contact(adjoint, adjoint.task)
    layout = adjoint.layout
    weights = torch.randn(engine.shape, generator=torch.Generator().manual_seed(0))
    x = engine.clone().requires_grad_(True)
    u = control.clone().requires_grad_(True)
    state = adjoint.simulate(adjoint._state_from_engine(x), u)
    grad_engine, grad_control = torch.autograd.grad((state.engine * weights).sum(), (x, u))
    nominal, jac_state, jac_control = adjoint.step_jacobians(engine, control)
    assert torch.equal(state.engine.detach(), nominal)  # the forward is the engine's own step
    w = weights.double()[:, None]
    assert torch.allclose(grad_control.double(), (w @ jac_control).squeeze(1), rtol=1e-4, atol=1e-6)
    tangent = adjoint.ambient_to_tangent_grad(engine, grad_engine[:, : layout.nq].double())
    expected = (w @ jac_state).squeeze(1)
    assert torch.allclose(tangent, expected[:, : layout.nv], rtol=1e-4, atol=1e-6)
    assert torch.allclose(grad_engine[:, layout.nq :].double(), expected[:, layout.nv :], rtol=1e-4, atol=1e-6)


def test_what_the_adjoint_does_not_cover_is_refused_at_build_time(ant):
    spec = build_spec(ant)
    spec.geoms[3].type = mujoco.mjtGeom.mjGEOM_ELLIPSOID
    with pytest.raises(BackendError, match="gradients=adjoint does not cover contacts of a mjGEOM_ELLIPSOID geom"):
        rigid_tree(spec.compile())
    with pytest.raises(ValueError, match="soft bodies take gradients=fd"):
        make("mujoco_warp", make_task("soft_jumper"), num_envs=1, gradients="adjoint")
    with pytest.raises(ValueError, match="fd_scheme set the finite differences; gradients=adjoint takes none"):
        make("mujoco_warp", ant, num_envs=1, gradients="adjoint", fd_scheme="forward")
    with pytest.raises(ValueError, match="gradients must be one of fd, adjoint"):
        make("mujoco_warp", ant, num_envs=1, gradients="exact")
    spec = build_spec(ant)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_RK4
    with pytest.raises(BackendError, match="does not cover integrator mjINT_RK4"):
        rigid_tree(spec.compile())


def test_the_gradient_mode_is_part_of_a_runs_settings(ant):
    from backends.mujoco_warp import MujocoWarpSim

    assert MujocoWarpSim.gradient_settings(ant, {"gradients": "adjoint"}) == {"gradients": "adjoint"}
    assert "gradients" not in MujocoWarpSim.gradient_settings(ant, {})  # the default's address is unchanged


class TestAdjointContract(ContractSuite):
    """The contract suite on the Ant and the Go2 with the adjoint's gradients."""

    backend_names = ("mujoco_warp",)
    backend_options = {"gradients": "adjoint"}
