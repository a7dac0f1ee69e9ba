"""The MuJoCo-Warp adapter on the Ant: state conversions, finite-difference gradients, stability, refusals.

Sims are module-scoped (Warp compiles MuJoCo-Warp's kernels once per process) and small: each
MuJoCo-Warp step costs ~100 kernel launches per substep, whatever the number of worlds.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

mujoco = pytest.importorskip("mujoco")
pytest.importorskip("mujoco_warp")

from backends import BackendError, ControlKind, InvalidActionError, NonFiniteStateError, make  # noqa: E402
from backends.mujoco_warp import MujocoWarpSim, build_spec, engine_to_generalized, generalized_to_engine  # noqa: E402
from backends.mujoco_warp.adapter import FD_SCHEMES  # noqa: E402
from backends.mujoco_warp.reference import float64_step_jacobians  # noqa: E402
from harness.checks.gradcheck import DEFAULT_TOLERANCE, gradcheck  # noqa: E402
from simcore import quat_from_angle_axis, quat_mul  # noqa: E402
from tasks import make_task  # noqa: E402


@pytest.fixture(scope="module")
def ant():
    return make_task("ant")


@pytest.fixture(scope="module")
def sim(ant):
    return make("mujoco_warp", ant, num_envs=2, seed=1, fd_scheme="central")


def _actions(n, gen, grad=False):
    a = 2.0 * torch.rand(n, 8, generator=gen) - 1.0
    return a.requires_grad_(grad)


def _tilted_spinning_state(ant, n, gen):
    """Generalized states in the air, tilted far from upright and spinning (body and world frames differ)."""
    q, qd = ant.sample_initial_state(n, gen)
    q[:, 2] = 2.0
    tilt = quat_from_angle_axis(torch.full((n,), 1.2), torch.nn.functional.normalize(torch.rand(n, 3, generator=gen)))
    q[:, 3:7] = quat_mul(tilt, q[:, 3:7])
    qd[:, 3:6] = 3.0 * (2.0 * torch.rand(n, 3, generator=gen) - 1.0)
    qd[:, 0:3] = 2.0 * torch.rand(n, 3, generator=gen) - 1.0
    return q, qd


# -- (a) state layout ------------------------------------------------------------------------
def test_generalized_state_round_trips(sim, ant):
    q, qd = _tilted_spinning_state(ant, 2, torch.Generator().manual_seed(0))
    state = sim.state_from_generalized(q, qd)
    assert state.engine.shape == (2, sim.mjm.nq + sim.mjm.nv)
    assert torch.allclose(state.joint_q, q, atol=1e-6)
    assert torch.allclose(state.joint_qd, qd, atol=1e-5)
    # a non-unit quaternion is normalised, not passed to the engine as is
    scaled = q.clone()
    scaled[:, 3:7] *= 1.5
    assert torch.allclose(sim.state_from_generalized(scaled, qd).joint_q, q, atol=1e-6)


def test_neutral_velocities_match_mujoco_object_velocity_with_an_off_centre_com(ant):
    """Root COM linear velocity and world angular velocity, checked against MuJoCo's own ``mj_objectVelocity``.

    The Ant's torso COM sits at its origin, so a heavy off-centre ball is added to the torso here to
    exercise the ``w x (R c)`` term.
    """
    spec = build_spec(ant)
    spec.body("torso").add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.2, 0, 0], pos=[0.3, -0.2, 0.1])
    m = spec.compile()
    com = m.body_ipos[1]
    assert np.linalg.norm(com) > 0.05
    d = mujoco.MjData(m)
    q, qd = _tilted_spinning_state(ant, 3, torch.Generator().manual_seed(1))
    engine = generalized_to_engine(q.double(), qd.double(), torch.tensor(com))
    joint_q, joint_qd = engine_to_generalized(engine, torch.tensor(com))
    assert torch.allclose(joint_q, q.double(), atol=1e-6) and torch.allclose(joint_qd, qd.double(), atol=1e-6)
    for i in range(3):
        d.qpos[:], d.qvel[:] = engine[i, : m.nq].numpy(), engine[i, m.nq :].numpy()
        mujoco.mj_forward(m, d)
        vel = np.zeros(6)  # (angular, linear) at the body's COM, world orientation
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, 1, vel, 0)
        np.testing.assert_allclose(qd[i, 3:6].numpy(), vel[:3], atol=1e-6)
        np.testing.assert_allclose(qd[i, 0:3].numpy(), vel[3:], atol=1e-6)


# -- (b) gradients -----------------------------------------------------------------------------
def test_gradients_match_finite_differences_on_contact_free_rollout(sim):
    """4 control steps, w.r.t. every action and the initial state (measured: ~5e-4 and ~4e-4).

    Checks the chaining of the per-step finite-difference Jacobians against finite differences of
    the whole rollout loss.
    """
    result = gradcheck(sim, steps=4, seed=0, start_height=2.0)
    assert result.action_rel_error < DEFAULT_TOLERANCE, result
    assert result.state_rel_error < DEFAULT_TOLERANCE, result


class _DropsStateGradient(MujocoWarpSim):
    """A deliberately broken adapter: forgets d(next state)/d(previous state)."""

    name = "broken"

    def simulate(self, state, control):
        return super().simulate(state.detach(), control)


def test_gradcheck_catches_a_broken_adapter(ant):
    result = gradcheck(_DropsStateGradient(ant, num_envs=2, seed=1), steps=1, seed=0, start_height=2.0)
    assert result.state_rel_error > 10 * DEFAULT_TOLERANCE


def test_one_step_gradient_matches_ambient_finite_differences_of_the_engine_state(sim, ant):
    """The quaternion mapping: d(loss)/d(engine input), all 29 ambient coordinates, tilted and spinning.

    The gradient along the quaternion itself is zero (MuJoCo normalises it).
    """
    gen = torch.Generator().manual_seed(2)
    engine = sim.state_from_generalized(*_tilted_spinning_state(ant, 2, gen)).engine.detach()
    control = 50.0 * (2.0 * torch.rand(2, 8, generator=gen) - 1.0)
    weights = torch.randn(2, engine.shape[1], generator=gen)

    def loss(e):
        return (sim.simulate(sim._state_from_engine(e), control).engine * weights).sum(dim=1).double()

    e_var = engine.clone().requires_grad_(True)
    loss(e_var).sum().backward()
    eps = 1e-3
    fd = torch.zeros_like(engine, dtype=torch.float64)
    with torch.no_grad():
        for i in range(engine.shape[1]):
            plus, minus = engine.clone(), engine.clone()
            plus[:, i] += eps
            minus[:, i] -= eps
            fd[:, i] = (loss(plus) - loss(minus)) / (2 * eps)
    err = (e_var.grad.double() - fd).norm(dim=1) / fd.norm(dim=1)
    assert float(err.max()) < 1e-2, err
    radial = (e_var.grad[:, 3:7] * engine[:, 3:7]).sum(dim=1)
    assert float(radial.abs().max()) < 1e-6 * float(e_var.grad.abs().max()), radial


def test_forward_with_grad_equals_forward_without_and_chunking_changes_nothing(sim, ant):
    gen = torch.Generator().manual_seed(3)
    engine = sim.state_from_generalized(*ant.sample_initial_state(2, gen)).engine.detach()
    control = ant.actions_to_control(_actions(2, gen))
    with torch.no_grad():
        plain = sim.simulate(sim._state_from_engine(engine), control).engine
    nominal, jac_state, jac_control = sim.fd_jacobians(engine, control)
    assert torch.equal(plain, nominal)
    chunked = make("mujoco_warp", ant, num_envs=2, seed=1, fd_chunk_envs=1, fd_scheme="central")
    nominal_c, jac_state_c, jac_control_c = chunked.fd_jacobians(engine, control)
    assert torch.equal(nominal, nominal_c)
    assert torch.allclose(jac_state, jac_state_c, rtol=0, atol=1e-6)
    assert torch.allclose(jac_control, jac_control_c, rtol=0, atol=1e-9)
    assert sim.worlds_per_env_with_grad == 1 + 2 * (2 * 14 + 8)


def test_perturbed_solver_settings_leave_the_nominal_world_and_smooth_jacobians_alone(sim, ant):
    """fd_warmstart=nominal and fd_tolerance=0 change only the perturbed worlds' solves: the forward
    result stays bit-identical to a step without gradients, and where the step is smooth (in the air)
    the Jacobians agree with the default settings' to float32 round-off."""
    gen = torch.Generator().manual_seed(3)
    q, qd = ant.sample_initial_state(2, gen)
    q[:, 2] = 2.0
    engine = sim.state_from_generalized(q, qd).engine.detach()
    control = ant.actions_to_control(_actions(2, gen))
    with torch.no_grad():
        plain = sim.simulate(sim._state_from_engine(engine), control).engine
    _, jac_state, jac_control = sim.fd_jacobians(engine, control)
    tuned = make("mujoco_warp", ant, num_envs=2, seed=1, fd_scheme="central", fd_warmstart="nominal", fd_tolerance=0.0)
    nominal, jac_state_t, jac_control_t = tuned.fd_jacobians(engine, control)
    assert torch.equal(plain, nominal)
    assert (jac_state_t - jac_state).norm() / jac_state.norm() < 1e-3
    assert (jac_control_t - jac_control).norm() / jac_control.norm() < 1e-3
    for bad in ({"fd_warmstart": "previous"}, {"fd_tolerance": -1.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            make("mujoco_warp", ant, num_envs=2, seed=1, **bad)


# -- (c) per-step Jacobians against MuJoCo's float64 C finite differences ---------------------------
def _transition_fd_reference(ant, engine: np.ndarray, torque: np.ndarray):
    """Tangent Jacobians (A: 2nv x 2nv, B: 2nv x nu) of one control step from ``mjd_transitionFD``.

    The same model in C MuJoCo (float64), with gear-1 motors on the hinges so ``ctrl`` is the
    torque that the adapter applies through ``qfrc_applied``; the substeps' Jacobians are chained.
    """
    spec = build_spec(ant)
    for joint in spec.joints:
        if joint.type == mujoco.mjtJoint.mjJNT_HINGE:
            spec.add_actuator(target=joint.name, trntype=mujoco.mjtTrn.mjTRN_JOINT, gear=[1, 0, 0, 0, 0, 0])
    m = spec.compile()
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:], d.ctrl[:] = engine[: m.nq], engine[m.nq :], torque
    a_total, b_total = np.eye(2 * m.nv), np.zeros((2 * m.nv, m.nu))
    for _ in range(ant.physics.substeps):
        a, b = np.zeros((2 * m.nv, 2 * m.nv)), np.zeros((2 * m.nv, m.nu))
        mujoco.mjd_transitionFD(m, d, 1e-6, True, a, b, None, None)
        a_total, b_total = a @ a_total, a @ b_total + b
        mujoco.mj_step(m, d)
    return a_total, b_total


def _tangent_rows(jac: np.ndarray, next_engine: np.ndarray) -> np.ndarray:
    """Ambient output rows -> tangent rows: the quaternion's 4 rows become the body-frame rotation's 3."""
    w, v = next_engine[3], next_engine[4:7]
    skew = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    e_conj = np.concatenate((-v[:, None], w * np.eye(3) - skew), axis=1)  # r -> Im(conj(q) * r)
    return np.concatenate((jac[0:3], 2.0 * e_conj @ jac[3:7], jac[7:]))


#: contact-free accuracy of each scheme at its default steps (relative Frobenius error, per env). The
#: default state steps are small (central 5e-4, forward 2.5e-4) because in contact a larger step straddles
#: the contacts' switches (``harness fd-schemes``: median error in contact ~1e-3 against 0.1-0.5 at 2e-3);
#: off the ground they cost float32 round-off: A measures ~1e-3 (central) and ~3.4e-3 (forward), against
#: ~6e-5 and ~8e-4 with the former steps (1e-2 and 2e-3)
CONTACT_FREE_BOUND = {"central": 2e-3, "forward": 5e-3, "one_sided": 2e-3, "adaptive": 5e-3}
# one_sided: central without switches; adaptive: forward without switches


@pytest.mark.parametrize("scheme", FD_SCHEMES)
def test_step_jacobians_match_mujoco_transition_fd(ant, scheme):
    """Contact-free state, each scheme at its default steps; measured max relative error (Frobenius,
    per env) for A and B: central ~1e-3 and ~3e-5, forward ~3.4e-3 and ~7e-5 (CONTACT_FREE_BOUND)."""
    sim = make("mujoco_warp", ant, num_envs=2, seed=1, fd_scheme=scheme)
    gen = torch.Generator().manual_seed(4)
    q, qd = ant.sample_initial_state(2, gen)
    q[:, 2] = 2.0
    engine = sim.state_from_generalized(q, qd).engine.detach()
    control = ant.actions_to_control(0.5 * _actions(2, gen))
    nominal, jac_state, jac_control = sim.fd_jacobians(engine, control)
    for i in range(2):
        a_ref, b_ref = _transition_fd_reference(ant, engine[i].double().numpy(), control[i].double().numpy())
        y = nominal[i].double().numpy()
        a = _tangent_rows(jac_state[i].numpy(), y)
        b = _tangent_rows(jac_control[i].numpy(), y)
        err_a = np.linalg.norm(a - a_ref) / np.linalg.norm(a_ref)
        err_b = np.linalg.norm(b - b_ref) / np.linalg.norm(b_ref)
        print(f"{scheme} env {i}: Jacobian vs mjd_transitionFD, relative error A {err_a:.2e}, B {err_b:.2e}")
        assert err_a < CONTACT_FREE_BOUND[scheme] and err_b < CONTACT_FREE_BOUND[scheme], (err_a, err_b)


def test_one_sided_takes_the_side_without_a_switch(ant):
    """Where a coordinate's forward and backward quotients agree, one_sided is central; where one side
    holds a jump (a contact switch inside the stencil), it is the other side's quotient."""
    sim = make("mujoco_warp", ant, num_envs=1, seed=0, fd_scheme="one_sided")
    steps = sim._fd_steps
    p, d = steps.numel(), 3
    slope = torch.arange(1.0, d + 1.0, dtype=torch.float64)
    nominal = torch.zeros(1, 1, d, dtype=torch.float64)
    plus = steps.reshape(p, 1, 1).double() * slope  # a linear function: f(x + eps e_i) = eps * slope
    minus = -plus.clone()
    plus[0] += 10.0  # a jump on the + side of coordinate 0
    quotients = sim._fd_quotients(torch.cat((nominal, plus, minus)))
    assert torch.allclose(quotients[0, 0], slope)  # the backward side, without the jump
    assert torch.allclose(quotients[1:, 0], slope.expand(p - 1, d))  # no switch: the central quotient


def _settled(ant, n: int, seed: int):
    """``n`` Ant states on the ground after 30 random steps, and random controls there."""
    walker = make("mujoco_warp", ant, num_envs=n, seed=seed)
    walker.reset()
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for _ in range(30):
            walker.step(_actions(n, gen))
    return walker.state.engine.detach(), ant.actions_to_control(_actions(n, gen))


def test_constraint_signatures_tell_constraint_sets_apart(ant):
    """Worlds with the same state have the same signature at every substep; a world in the air (no
    contact rows) and one on the ground differ, and so do ground worlds with different contacts."""
    sim = make("mujoco_warp", ant, num_envs=4, seed=0, fd_scheme="adaptive")
    engine, control = _settled(ant, 4, 0)
    lifted = engine.clone()
    lifted[0, 2] += 2.0
    rows = torch.cat((engine, engine[:1], lifted[:1]))
    marks: list[torch.Tensor] = []
    sim._run_worlds(
        rows[:, :15].float(), rows[:, 15:].float(), torch.cat((control, control[:2])).float(), signatures=marks
    )
    marks = torch.stack(marks)  # (substeps, 6, 2)
    assert marks.shape == (ant.physics.substeps, 6, 2)
    assert torch.equal(marks[:, 4], marks[:, 0])  # the same state: the same sets
    assert not torch.equal(marks[:, 5], marks[:, 0])  # in the air: no contact rows
    keys, valid = sim._signatures[6].row_keys()
    assert int(valid[5].sum()) < int(valid[0].sum())


def test_adaptive_is_forward_differences_in_the_air_and_pays_the_second_side_only_at_switches(ant):
    """In the air no constraint switches: ``adaptive`` steps no -eps world and its Jacobians are forward
    differences'. On the ground, each (env, coordinate) is the forward quotient where its +eps world kept
    the nominal's constraint sets, else the backward quotient where the -eps world kept them, else the
    smaller of the two: checked against quotients recomputed from central's worlds at the same steps."""
    adaptive = make("mujoco_warp", ant, num_envs=4, seed=0, fd_scheme="adaptive")
    steps = {"fd_eps_state": 2.5e-4, "fd_eps_velocity": 1e-2}  # adaptive's defaults
    forward = make("mujoco_warp", ant, num_envs=4, seed=0, fd_scheme="forward", **steps)
    central = make("mujoco_warp", ant, num_envs=4, seed=0, fd_scheme="central", **steps)
    gen = torch.Generator().manual_seed(4)
    q, qd = ant.sample_initial_state(4, gen)
    q[:, 2] = 2.0
    engine = adaptive.state_from_generalized(q, qd).engine.detach()
    control = ant.actions_to_control(0.5 * _actions(4, gen))
    air = adaptive.fd_jacobians(engine, control)
    assert adaptive.second_side_share == 0.0
    for mine, theirs in zip(air, forward.fd_jacobians(engine, control), strict=True):
        assert torch.equal(mine, theirs)

    engine, control = _settled(ant, 4, 1)
    nominal, jac_state, jac_control = adaptive.fd_jacobians(engine, control)
    assert 0.0 < adaptive.second_side_share < 0.5  # switches exist on the ground, in a few stencils
    deltas = central._fd_deltas()
    qpos, qvel, torque = central._retract(engine.double(), control.double(), deltas)
    y = central._run_worlds(qpos.float(), qvel.float(), torque.float()).double().reshape(deltas.shape[0], 4, -1)
    p, steps = deltas.shape[1], central._fd_steps.reshape(-1, 1, 1)
    ahead, behind = (y[1 : 1 + p] - y[:1]) / steps, (y[:1] - y[1 + p :]) / steps
    got = torch.cat((jac_state, jac_control), dim=2).permute(2, 0, 1)  # (P, n, D)
    assert torch.equal(nominal, y[0].float())
    is_forward = (got - ahead).norm(dim=-1) <= 1e-6 * ahead.norm(dim=-1).clamp_min(1.0)
    is_backward = (got - behind).norm(dim=-1) <= 1e-6 * behind.norm(dim=-1).clamp_min(1.0)
    assert bool((is_forward | is_backward).all())
    share_backward = float((is_backward & ~is_forward).float().mean())
    assert share_backward <= adaptive.second_side_share + 1e-9


def test_adaptive_keeps_the_data_of_few_second_batch_sizes(ant):
    sim = make("mujoco_warp", ant, num_envs=2, seed=0, fd_scheme="adaptive")
    for size in (8, 12, 16, 24, 32, 48):
        sim._data_for(size)
        sim._hold_second_size(size, keep=2 * sim.worlds_per_env_with_grad)
    assert set(sim._data) == {16, 24, 32, 48}


def test_adaptive_is_refused_for_soft_bodies():
    with pytest.raises(ValueError, match="fd_scheme adaptive"):
        make("mujoco_warp", make_task("soft_jumper"), num_envs=1, fd_scheme="adaptive")


def test_the_float64_whole_step_reference_agrees_with_mjd_transition_fd(sim, ant):
    """The reference of ``harness fd-schemes`` (float64 central differences of a whole control step on
    MuJoCo C) against chained ``mjd_transitionFD``: two float64 references, ~1e-8 apart when correct."""
    gen = torch.Generator().manual_seed(6)
    q, qd = ant.sample_initial_state(2, gen)
    q[:, 2] = 2.0
    engine = sim.state_from_generalized(q, qd).engine.detach()[0]
    control = ant.actions_to_control(0.5 * _actions(2, gen))[0]
    y, jac_state, jac_control = float64_step_jacobians(sim, engine, control)
    a_ref, b_ref = _transition_fd_reference(ant, engine.double().numpy(), control.double().numpy())
    a, b = _tangent_rows(jac_state, y), _tangent_rows(jac_control, y)
    assert np.linalg.norm(a - a_ref) / np.linalg.norm(a_ref) < 1e-6
    assert np.linalg.norm(b - b_ref) / np.linalg.norm(b_ref) < 1e-6


def test_forward_differences_step_half_the_worlds_and_share_the_nominal_world(sim, ant):
    forward = make("mujoco_warp", ant, num_envs=2, seed=1, fd_scheme="forward")
    assert forward.worlds_per_env_with_grad == 1 + (2 * 14 + 8)
    assert sim.worlds_per_env_with_grad == 1 + 2 * (2 * 14 + 8)
    engine, control = sim.state.engine.detach(), ant.actions_to_control(torch.zeros(2, 8))
    assert torch.equal(forward.fd_jacobians(engine, control)[0], sim.fd_jacobians(engine, control)[0])
    with pytest.raises(ValueError, match="fd_scheme must be one of central, forward"):
        make("mujoco_warp", ant, num_envs=1, fd_scheme="backward")


# -- (d) stability -----------------------------------------------------------------------------
def test_64_envs_one_step_stays_finite(ant):
    big = make("mujoco_warp", ant, num_envs=64, seed=5)
    with torch.no_grad():
        state = big.step(_actions(64, torch.Generator().manual_seed(5)))
    assert torch.isfinite(state.engine).all() and torch.isfinite(state.joint_qd).all()


def test_8_envs_200_random_steps_stay_finite_and_in_a_sane_box(ant):
    eight = make("mujoco_warp", ant, num_envs=8, seed=2)
    gen = torch.Generator().manual_seed(0)
    lowest, highest = math.inf, -math.inf
    with torch.no_grad():
        for _ in range(200):
            state = eight.step(_actions(8, gen))  # raises NonFiniteStateError on any NaN/inf
            z = state.root_pos[:, 2]
            lowest, highest = min(lowest, float(z.min())), max(highest, float(z.max()))
    # torso sphere (r = 0.25) neither sinks through the ground nor gets launched
    assert 0.1 < lowest and highest < 1.5, (lowest, highest)


# -- (e) refusals ------------------------------------------------------------------------------
def test_activations_without_a_soft_body_and_particles_on_the_ant_are_refused(sim, ant):
    class ActivatedAnt(type(ant)):
        control_kind = ControlKind.TET_ACTIVATION

    with pytest.raises(BackendError, match="task 'ant' asks for tet activations but defines no soft_body"):
        make("mujoco_warp", ActivatedAnt(), num_envs=1)
    q, qd = ant.default_state()
    with pytest.raises(BackendError, match="particles"):
        n = sim.num_envs
        sim.state_from_generalized(q.repeat(n, 1), qd.repeat(n, 1), particle_q=torch.zeros(n, 1, 3))


def test_bad_actions_are_refused_and_simulation_nan_is_reported_per_env(sim, ant):
    with pytest.raises(InvalidActionError, match="shape"):
        sim.step(torch.zeros(2, 7))
    q, qd = ant.sample_initial_state(2, torch.Generator().manual_seed(0))
    qd[1, 6:] = 1e38  # joint velocities that overflow float32 arithmetic in env 1 only
    sim.state = sim.state_from_generalized(q, qd)
    kept = sim.state
    with pytest.raises(NonFiniteStateError) as info, torch.no_grad():
        sim.step(torch.zeros(2, 8))
    assert info.value.env_ids == [1]
    assert sim.state is kept
    sim.reset(info.value.env_ids)
    with torch.no_grad():
        assert torch.isfinite(sim.step(torch.zeros(2, 8)).engine).all()


# -- (f) graph capture: the replayed substeps are the eager substeps, to the bit -------------------------
@pytest.mark.parametrize("task_name", ["ant", "go2", "soft_jumper"])
def test_captured_substeps_replay_bit_identical_steps_and_jacobians(task_name):
    """With ``graph_capture`` on (the CPU default) each ``Data``'s ``mujoco_warp.step`` runs directly
    once, is captured on its second call and replayed after. Three forward steps and two steps'
    finite-difference Jacobians (the first captures every batch's graph, the second replays it) must
    equal those of ``graph_capture=0`` to the bit: torques (Ant), the per-substep PD law between
    replays (Go2), per-substep activation forces (SoftJumper: forward steps only, its Jacobian steps
    3,109 worlds per env, minutes on this CPU)."""
    task = make_task(task_name)
    n = 1 if task_name == "soft_jumper" else 2

    def run(sim):
        gen = torch.Generator().manual_seed(4)
        out = []
        state = sim.state
        with torch.no_grad():
            for _ in range(3):
                control = task.actions_to_control(2.0 * torch.rand(n, task.action_dim, generator=gen) - 1.0)
                state = sim.simulate(state, control)
                out.append(state.engine.clone())
        for _ in range(0 if task_name == "soft_jumper" else 2):
            control = task.actions_to_control(2.0 * torch.rand(n, task.action_dim, generator=gen) - 1.0)
            out += list(sim.fd_jacobians(state.engine.detach(), control))
        return out

    captured = make("mujoco_warp", task, num_envs=n, seed=2)
    eager = make("mujoco_warp", task, num_envs=n, seed=2, graph_capture=0)
    assert captured.stepper.enabled and not eager.stepper.enabled
    a, b = run(captured), run(eager)
    graphs = [entry.graph for entry in captured.stepper._entries.values()]
    assert graphs and all(g is not None for g in graphs) and not eager.stepper._entries
    assert all(x.abs().max() > 0 for x in a)
    for x, y in zip(a, b, strict=True):
        assert torch.equal(x, y)


def test_graph_capture_option_takes_0_or_1(ant):
    with pytest.raises(BackendError, match="graph_capture must be 0 or 1"):
        make("mujoco_warp", ant, num_envs=1, graph_capture=2)
