"""The SoftJumper: its generated mesh, the task in torch, the activation term, Newton, bad input.

The contract suite (tests/test_contract.py) also runs the SoftJumper on Newton (shapes, seeding,
resets, graph cuts, gradients against finite differences on a contact-free segment, NaN reports).
"""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np
import pytest
import torch

from simcore import SimState, SoftBodySpec, TetMeshError, activation_nodal_forces, check_tet_mesh, signed_tet_volumes
from tasks.soft_jumper import SoftJumper
from tasks.tetmesh import TableShape, table_mesh


@pytest.fixture(scope="module")
def jumper():
    return SoftJumper()


# -- 1. the mesh ---------------------------------------------------------------------------------
def test_the_table_mesh_has_the_peers_size_and_positive_tets():
    vertices, tets = table_mesh()
    assert vertices.shape == (179, 3) and tets.shape == (480, 4)
    assert np.allclose(vertices.min(0), (-1.25, -1.25, 0.0)) and np.allclose(vertices.max(0), (1.25, 1.25, 1.8))
    volumes = signed_tet_volumes(torch.from_numpy(vertices), torch.from_numpy(tets))
    assert bool((volumes > 0).all())
    # slab 2.5 x 2.5 x 0.9 plus four legs of (2.5 / 6)^2 x 0.9
    assert float(volumes.sum()) == pytest.approx(2.5 * 2.5 * 0.9 + 4 * (2.5 / 6) ** 2 * 0.9, rel=1e-12)


def test_the_mesh_is_conforming_and_every_particle_is_used():
    """Every triangular face is shared by at most two tets (no hanging vertices, no overlaps), and
    no vertex is left out of the tets."""
    vertices, tets = table_mesh()
    faces = Counter()
    for tet in tets.tolist():
        for drop in range(4):
            faces[tuple(sorted(tet[:drop] + tet[drop + 1 :]))] += 1
    assert set(faces.values()) == {1, 2}
    assert np.array_equal(np.unique(tets), np.arange(len(vertices)))


def test_other_table_shapes_also_give_valid_meshes():
    vertices, tets = table_mesh(TableShape(cells_x=4, cells_y=3, slab_layers=1, leg_layers=3, size_y=1.8, height=2.5))
    check_tet_mesh(torch.from_numpy(vertices), torch.from_numpy(tets))
    assert np.allclose(vertices.max(0) - vertices.min(0), (2.5, 1.8, 2.5))


@pytest.mark.parametrize(
    "case, change, message",
    [
        ("inverted", lambda v, t: (v, t[:, [1, 0, 2, 3]]), "inverted"),
        ("zero volume", lambda v, t: (v, np.concatenate([t, t[:1, [0, 0, 1, 2]]])), "zero-volume"),
        ("no tets", lambda v, t: (v, t[:0]), "no tetrahedra"),
        ("index out of range", lambda v, t: (v, t + 1000), "must lie in"),
        ("NaN vertex", lambda v, t: (np.where(v == v.max(), np.nan, v), t), "finite"),
        ("wrong width", lambda v, t: (v, t[:, :3]), "shape (T, 4)"),
    ],
)
def test_bad_meshes_are_one_clear_error(case, change, message):
    vertices, tets = change(*table_mesh())
    with pytest.raises(TetMeshError) as info:
        SoftBodySpec(torch.from_numpy(vertices), torch.from_numpy(tets), 1e3, 1e3, 1.0, 1.0)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_bad_shapes_and_materials_are_refused():
    with pytest.raises(TetMeshError, match="leg_cells"):
        TableShape(cells_x=1)
    vertices, tets = (torch.from_numpy(a) for a in table_mesh())
    with pytest.raises(ValueError, match="k_lambda"):
        SoftBodySpec(vertices, tets, 1e3, 0.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="scale_spread"):
        SoftBodySpec(vertices, tets, 1e3, 1e3, 1.0, 1.0, scale_spread=1.5)


# -- 2. the task ---------------------------------------------------------------------------------
def test_sizes_of_the_task(jumper):
    assert jumper.action_dim == 240 and jumper.layout.num_tets == 480 and jumper.layout.num_particles == 179
    assert jumper.obs_dim == 6 + 6 * 179 + 240
    assert jumper.physics.substeps == 80 and jumper.physics.frame_dt == pytest.approx(1 / 60)
    body = jumper.soft_body
    assert (body.k_mu, body.k_lambda, body.k_damp, body.density) == (1e3, 1e3, 1.0, 1.0)
    phys = jumper.physics
    assert (phys.contact_ke, phys.contact_kd, phys.contact_kf, phys.contact_mu) == (2e3, 0.1, 10.0, 0.7)


def test_each_action_drives_two_tets_clipped_and_scaled(jumper):
    actions = torch.zeros(2, 240)
    actions[0, 0], actions[0, 5], actions[1, 239] = 0.5, 3.0, -2.0
    act = jumper.actions_to_control(actions)
    assert act.shape == (2, 480)
    assert act[0, 0] == act[0, 1] == pytest.approx(0.15)
    assert act[0, 10] == act[0, 11] == pytest.approx(0.3)  # clipped to 1, then scaled
    assert act[1, 478] == act[1, 479] == pytest.approx(-0.3)
    assert int((act != 0).sum()) == 6


def test_initial_states_spread_size_offset_and_drop(jumper):
    n = 256
    q, qd, pq, pqd = jumper.sample_initial_state(n, torch.Generator().manual_seed(0))
    assert q.shape == (n, 0) and qd.shape == (n, 0) and pq.shape == (n, 179, 3) and torch.all(pqd == 0)
    scales = jumper.soft_body.rest_scales(n).float()
    assert float(scales.min()) > 0.9 and float(scales.max()) < 1.1 and float(scales.max() - scales.min()) > 0.15
    extent = pq[..., 0].amax(1) - pq[..., 0].amin(1)
    assert torch.allclose(extent, 2.5 * scales, rtol=1e-5)  # the env's own size, undeformed
    lowest = pq[..., 2].amin(1) - jumper.soft_body.particle_radius
    assert float(lowest.min()) >= 0.0 and float(lowest.max()) <= 0.2 and float(lowest.std()) > 0.03
    centre = 0.5 * (pq[..., :2].amax(1) + pq[..., :2].amin(1))
    assert float(centre.abs().max()) <= 0.25 and float(centre.std()) > 0.05
    again = jumper.sample_initial_state(n, torch.Generator().manual_seed(0))[2]
    assert torch.equal(pq, again)


def test_reward_and_observation_of_a_hand_made_state(jumper):
    n = 2
    _, _, pq, _ = jumper.sample_initial_state(n, torch.Generator().manual_seed(1))
    pq = pq - torch.tensor([0.0, 0.0, 1.0]) * (pq[..., 2].amin(1, keepdim=True) - 0.02).unsqueeze(-1)  # feet down
    pqd = torch.zeros_like(pq)
    pqd[..., 0] = 2.0  # every particle moving forward at 2 m/s
    pq[1, :, 2] += 0.5  # env 1 half a metre up
    state = SimState(torch.zeros(n, 0), torch.zeros(n, 0), torch.zeros(n, 1), pq, pqd)
    actions = torch.full((n, 240), 0.5)
    prev = torch.zeros(n, 240)
    reward = jumper.reward(state, jumper.observe(state, prev), actions, prev)
    expected = 10 * 2.0 + 30 * torch.tensor([0.0, 0.5]) - 1e-3 * 240 * 0.25
    assert torch.allclose(reward, expected, atol=1e-4), reward
    obs = jumper.observe(state, actions)
    assert obs.shape == (n, jumper.obs_dim)
    com, com_vel = jumper.com(state)
    assert torch.allclose(obs[:, 3:6], torch.tensor([2.0, 0.0, 0.0]).expand(n, 3))
    assert torch.allclose(obs[:, 6 : 6 + 537].reshape(n, 179, 3), pq - com.unsqueeze(1))
    assert float(obs[:, 6 + 537 : 6 + 1074].abs().max()) < 1e-5  # rigid translation: no relative velocity
    assert torch.equal(obs[:, -240:], actions)
    assert not bool(jumper.terminated(state, obs).any())


# -- 3. the activation term ----------------------------------------------------------------------
def test_activation_forces_are_minus_the_gradient_of_the_activation_energy(jumper):
    """E_act = sum_t k_lambda V_t a_t J_t (the activation part of Newton's volume energy); with
    J_t = det(D_s) / det(D_m) = V_t(x) / V_t(rest), its gradient gives the nodal forces."""
    body = jumper.soft_body
    gen = torch.Generator().manual_seed(0)
    x = (body.vertices + 0.05 * torch.randn(body.vertices.shape, generator=gen, dtype=torch.float64)).unsqueeze(0)
    x.requires_grad_(True)
    act = 0.3 * (2 * torch.rand(1, body.num_tets, generator=gen, dtype=torch.float64) - 1)
    energy = (body.k_lambda * act * signed_tet_volumes(x[0], body.tets)).sum()
    (grad,) = torch.autograd.grad(energy, x)
    forces = activation_nodal_forces(x.detach(), body.tets, act, body.k_lambda)
    assert torch.allclose(forces, -grad, atol=1e-12)
    assert float(forces.sum(dim=1).abs().max()) < 1e-12  # internal: no net force


def test_newtons_activation_term_is_the_nodal_force_formula(jumper):
    """One tiny substep from rest, in the air, without gravity: the velocity an activation adds is
    dt * F_act / m, with F_act from :func:`simcore.activation_nodal_forces` (what MuJoCo-Warp applies)."""
    from backends import make

    physics = dataclasses.replace(jumper.physics, frame_dt=1e-4, substeps=1, gravity=0.0, ground_plane=False)
    task = SoftJumper(physics)
    sim = make("newton", task, num_envs=2, seed=0)
    q, qd, pq, pqd = task.sample_initial_state(2, torch.Generator().manual_seed(0))
    start = sim.state_from_generalized(q, qd, pq + torch.tensor([0.0, 0.0, 1.0]), pqd)
    act = 0.3 * (2 * torch.rand(2, 480, generator=torch.Generator().manual_seed(1)) - 1)
    with torch.no_grad():
        driven = sim.simulate(start, act).particle_qd
        idle = sim.simulate(start, torch.zeros_like(act)).particle_qd
    scales = task.soft_body.rest_scales(2).reshape(2, 1)
    masses = (task.soft_body.particle_masses().unsqueeze(0) * scales**3).unsqueeze(-1)
    force = activation_nodal_forces(start.particle_q.double(), task.soft_body.tets, act.double(), 1e3)
    expected = 1e-4 * force / masses
    assert torch.allclose((driven - idle).double(), expected, rtol=1e-3, atol=1e-6 * float(expected.abs().max()))


# -- 4. Newton -----------------------------------------------------------------------------------
def test_a_broken_soft_body_gradient_fails_the_check(jumper):
    """The directional check the soft body gets (hundreds of coordinates) still fails an adapter that
    drops the state gradient."""
    from backends.newton import NewtonSim
    from harness.checks.gradcheck import DEFAULT_TOLERANCE, gradcheck

    class DropsStateGradient(NewtonSim):
        def simulate(self, state, control):
            return super().simulate(dataclasses.replace(state, engine=state.engine.detach()), control)

    sim = DropsStateGradient(jumper, num_envs=2, seed=1, max_graph_steps=4)
    result = gradcheck(sim, steps=2, seed=0, start_height=jumper.airborne_height)
    assert result.state_mode == "directions" and result.action_mode == "directions"
    assert result.state_rel_error > 10 * DEFAULT_TOLERANCE


def test_tet_activations_with_nan_or_the_wrong_count_are_one_clear_error(jumper):
    from backends import BackendError, InvalidActionError, make

    sim = make("newton", jumper, num_envs=2, seed=0)
    bad = torch.zeros(2, 240)
    bad[1, 3] = float("nan")
    for actions, kind in ((bad, "NaN"), (torch.zeros(2, 239), "shape")):
        with pytest.raises(InvalidActionError) as info:
            sim.step(actions)
        assert kind in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(BackendError, match=r"tet activations must have shape \(2, 480\)"):
        sim.simulate(sim.state, torch.zeros(2, 479))
    nan_control = torch.zeros(2, 480)
    nan_control[0, 0] = float("inf")
    with pytest.raises(InvalidActionError, match="NaN or inf"):
        sim.simulate(sim.state, nan_control)


def test_a_mesh_that_does_not_match_the_layout_is_refused(jumper):
    from backends import BackendError, make
    from simcore import StateLayout

    other = type("OtherJumper", (SoftJumper,), {"layout": StateLayout(0, False, 100, 480)})()
    with pytest.raises(BackendError, match="179 particles and 480 tets"):
        make("newton", other, num_envs=1)


def test_non_finite_particle_states_are_refused(jumper):
    from backends import InvalidStateError, make

    sim = make("newton", jumper, num_envs=2, seed=0)
    q, qd, pq, pqd = jumper.sample_initial_state(2, torch.Generator().manual_seed(0))
    pqd[1, 5, 2] = float("nan")
    with pytest.raises(InvalidStateError, match=r"env\(s\) \[1\]"):
        sim.state_from_generalized(q, qd, pq, pqd)
    with pytest.raises(InvalidStateError, match="particle_q must have shape"):
        sim.state_from_generalized(q, qd, pq[:, :10], pqd)


# -- 5. MuJoCo-Warp ------------------------------------------------------------------------------
class TinyJumper(SoftJumper):
    """The same task on a 2 x 2 voxel slab with four one-voxel legs (27 particles, 48 tets), so that a
    finite-difference step with gradients costs 421 worlds instead of 3109, and with 8 substeps of
    the same length as the task's (control steps of 1/600 s) to keep these tests fast."""

    name = "tiny_jumper"
    soft_body = dataclasses.replace(
        SoftJumper.soft_body,
        vertices=torch.from_numpy(table_mesh(TableShape(cells_x=2, cells_y=2, slab_layers=1, leg_layers=1))[0]),
        tets=torch.from_numpy(table_mesh(TableShape(cells_x=2, cells_y=2, slab_layers=1, leg_layers=1))[1]),
    )
    from simcore import StateLayout as _Layout

    layout = _Layout(num_dofs=0, floating_base=False, num_particles=27, num_tets=48)
    action_dim = 24
    obs_dim = 6 + 6 * 27 + 24

    def __init__(self, physics=None):
        default = dataclasses.replace(SoftJumper().physics, frame_dt=1.0 / 600.0, substeps=8)
        super().__init__(physics or default)


def test_mujoco_warp_soft_body_state_round_trip_and_fall():
    pytest.importorskip("mujoco_warp")
    from backends import make

    task = TinyJumper()
    sim = make("mujoco_warp", task, num_envs=2, seed=0)
    q, qd, pq, pqd = task.sample_initial_state(2, torch.Generator().manual_seed(0))
    pq = pq + torch.tensor([0.0, 0.0, 1.0])  # in the air
    state = sim.state_from_generalized(q, qd, pq, pqd)
    assert torch.allclose(state.particle_q, pq, atol=1e-6) and torch.equal(state.particle_qd, pqd)
    with torch.no_grad():
        after = sim.simulate(state, torch.zeros(2, 48))
    dt, n = task.physics.frame_dt, task.physics.substeps
    fall = task.com(state)[0][:, 2] - task.com(after)[0][:, 2]
    expected = 9.81 * dt**2 * (n + 1) / (2 * n)  # free fall under n semi-implicit Euler substeps
    assert torch.allclose(fall, torch.full((2,), expected), rtol=0.02), fall


def test_mujoco_warp_soft_body_jacobians_and_their_autograd_wiring():
    """One control step in the air (421 worlds): the finite-difference Jacobians times a random
    direction of state and activations against a central difference of two more steps along that
    direction (relative error of the whole next-state vector), and autograd through ``simulate``
    equals the vector-Jacobian product of those Jacobians."""
    pytest.importorskip("mujoco_warp")
    from backends import make

    task = TinyJumper()
    sim = make("mujoco_warp", task, num_envs=1, seed=0)
    assert sim.worlds_per_env_with_grad == 1 + 2 * (2 * 81 + 48)
    q, qd, pq, pqd = task.sample_initial_state(1, torch.Generator().manual_seed(0))
    gen = torch.Generator().manual_seed(3)
    moving = 0.1 * torch.randn(pqd.shape, generator=gen)
    state = sim.state_from_generalized(q, qd, pq + torch.tensor([0.0, 0.0, 1.0]), moving)
    act = 0.3 * (2 * torch.rand(1, 48, generator=gen) - 1)
    nominal, jac_state, jac_act = sim.fd_jacobians(state.engine, act)
    d_state = torch.randn(1, 162, generator=gen, dtype=torch.float64)
    d_act = torch.randn(1, 48, generator=gen, dtype=torch.float64)
    predicted = jac_state[0] @ d_state[0] + jac_act[0] @ d_act[0]

    def step(sign: float) -> torch.Tensor:
        moved = dataclasses.replace(state, engine=(state.engine.double() + sign * 1e-3 * d_state).float())
        with torch.no_grad():
            return sim.simulate(moved, (act.double() + sign * 1e-3 * d_act).float()).engine[0].double()

    measured = (step(1.0) - step(-1.0)) / 2e-3
    assert float((predicted - measured).norm() / measured.norm()) < 1e-2
    with torch.no_grad():
        assert torch.equal(sim.simulate(state, act).engine, nominal)  # the nominal world is the forward step

    weights = torch.randn(1, 162, generator=gen, dtype=torch.float64)
    engine = state.engine.clone().requires_grad_(True)
    act_var = act.clone().requires_grad_(True)
    out = sim.simulate(dataclasses.replace(state, engine=engine), act_var).engine
    (out.double() * weights).sum().backward()
    assert torch.allclose(engine.grad.double(), weights[0] @ jac_state[0], rtol=1e-5, atol=1e-6)
    assert torch.allclose(act_var.grad.double(), weights[0] @ jac_act[0], rtol=1e-5, atol=1e-6)


def test_forward_crosscheck_reports_com_paths_of_both_engines(monkeypatch):
    """``crosscheck`` on a soft body: the same start and actions on both engines (a 27-particle body,
    3 steps), COM paths from the same point, their distance growing from zero."""
    pytest.importorskip("mujoco_warp")
    import tasks
    from harness.checks.crosscheck import forward_crosscheck

    monkeypatch.setitem(tasks.REGISTRY._runtime, "tiny_jumper", TinyJumper)  # registered for this test only
    report = forward_crosscheck("tiny_jumper", ["newton", "mujoco_warp"], num_envs=1, steps=3, seed=0)
    pair = report["pairs"]["newton vs mujoco_warp"]
    assert len(report["com"]["newton"]) == len(report["com"]["mujoco_warp"]) == 4
    assert pair["com_distance_by_step"][0] == pytest.approx(0.0, abs=1e-6)
    assert 0.0 < pair["com_distance_max"] < 0.05


def test_mujoco_warp_soft_body_bare_engine_reference_is_forward_only():
    """A soft body's step with gradients (421 worlds per env here, 3109 for the SoftJumper) has no timed
    bare reference; the forward one steps every env's own model."""
    pytest.importorskip("mujoco_warp")
    from backends import make

    sim = make("mujoco_warp", TinyJumper(), num_envs=2, seed=0)
    assert sim.bare_engine_rollout(1, grad=True) is None
    seconds = sim.bare_engine_rollout(1, grad=False)
    assert seconds is not None and seconds > 0
