"""The Newton adapter on the Ant: gradients, stability, graph cuts, layout and bad input."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

pytest.importorskip("newton")

import backends  # noqa: E402
from backends import BackendError, ControlKind, InvalidActionError, NonFiniteStateError, make  # noqa: E402
from backends.newton import NewtonSim  # noqa: E402
from harness.checks.gradcheck import DEFAULT_TOLERANCE, gradcheck  # noqa: E402
from tasks import make_task  # noqa: E402


@pytest.fixture(scope="module")
def ant():
    return make_task("ant")


@pytest.fixture(scope="module")
def small(ant):
    return make("newton", ant, num_envs=4, seed=0, max_graph_steps=16)


def _actions(n, gen, grad=False):
    a = 2.0 * torch.rand(n, 8, generator=gen) - 1.0
    return a.requires_grad_(grad)


# -- (a) gradients against finite differences ------------------------------------------------
def test_gradients_match_finite_differences_on_contact_free_rollout(ant):
    """8 control steps, w.r.t. every action and the initial state.

    Tolerance 2e-2 relative (vector norm per env): the simulation is float32, so central
    differences carry ~1e-4..1e-3 relative round-off; the adapter measures ~5e-4..8e-4.
    A wrong gradient (lost term, stale tape) is off by O(1): see the negative control below.
    """
    sim = make("newton", ant, num_envs=2, seed=1)
    result = gradcheck(sim, steps=8, seed=0, start_height=2.0)
    assert result.action_rel_error < DEFAULT_TOLERANCE
    assert result.state_rel_error < DEFAULT_TOLERANCE


class _DropsStateGradient(NewtonSim):
    """A deliberately broken adapter: forgets d(next state)/d(previous state) across steps."""

    name = "broken"

    def simulate(self, state, control):
        return super().simulate(state.detach(), control)


def test_gradcheck_catches_a_broken_adapter(ant):
    sim = _DropsStateGradient(ant, num_envs=2, seed=1, solver="featherstone")  # the Ant preset's solver
    result = gradcheck(sim, steps=8, seed=0, start_height=2.0)
    assert result.max_rel_error > 10 * DEFAULT_TOLERANCE


# -- (b) stability ---------------------------------------------------------------------------
def test_64_envs_1000_random_steps_stay_finite_and_in_a_sane_box(ant):
    sim = make("newton", ant, num_envs=64, seed=2)
    gen = torch.Generator().manual_seed(0)
    lowest, highest, farthest = math.inf, -math.inf, 0.0
    with torch.no_grad():
        for _ in range(1000):
            state = sim.step(_actions(64, gen))  # raises NonFiniteStateError on any NaN/inf
            z = state.root_pos[:, 2]
            lowest, highest = min(lowest, float(z.min())), max(highest, float(z.max()))
            farthest = max(farthest, float(state.root_pos[:, :2].abs().max()))
            assert torch.isfinite(state.joint_qd).all()
    # torso sphere (r = 0.25) neither sinks through the ground nor gets launched, nor flies away
    assert 0.1 < lowest and highest < 1.5, (lowest, highest)
    assert farthest < 10.0, farthest


# -- (c) graph cuts: per-env resets and window cuts are checked for every adapter in test_contract.py --
def test_graph_longer_than_the_buffer_ring_refuses_backward(ant):
    sim = make("newton", ant, num_envs=2, seed=0, max_graph_steps=3)
    gen = torch.Generator().manual_seed(3)
    first = _actions(2, gen, grad=True)
    sim.step(first)
    for _ in range(4):
        state = sim.step(_actions(2, gen))
    with pytest.raises(BackendError, match="max_graph_steps"):
        state.joint_q.sum().backward()


# -- bad input -----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "actions, match",
    [
        (torch.zeros(4, 7), "shape"),
        (torch.zeros(3, 8), "shape"),
        (torch.zeros(4, 8, dtype=torch.int64), "floating-point"),
        (torch.tensor([[0.0] * 8, [float("nan")] + [0.0] * 7, [0.0] * 8, [float("inf")] * 8]), r"env\(s\) \[1, 3\]"),
        ([[0.0] * 8] * 4, "torch.Tensor"),
    ],
)
def test_bad_actions_are_refused_before_the_engine(small, actions, match):
    before = small.step_count
    with pytest.raises(InvalidActionError, match=match):
        small.step(actions)
    assert small.step_count == before


def test_simulation_nan_is_reported_per_env(small, ant):
    q, qd = ant.sample_initial_state(4, torch.Generator().manual_seed(0))
    qd[2, 6:] = 1e38  # joint velocities that overflow float32 arithmetic in env 2 only
    small.state = small.state_from_generalized(q, qd)
    kept = small.state
    with pytest.raises(NonFiniteStateError) as info, torch.no_grad():
        small.step(torch.zeros(4, 8))
    assert info.value.env_ids == [2]
    assert small.state is kept  # the non-finite result was not stored
    small.reset(info.value.env_ids)
    with torch.no_grad():
        assert torch.isfinite(small.step(torch.zeros(4, 8)).engine).all()


def test_malformed_asset_is_one_clear_error(tmp_path, ant):
    bad = tmp_path / "broken.xml"
    bad.write_text("<mujoco><worldbody><body name='a'><geom type='sphere' size='x'/></worldbody></mujoco>")

    class BrokenAnt(type(ant)):
        asset_path = bad

    with pytest.raises(BackendError, match="cannot load mjcf asset"):
        make("newton", BrokenAnt(), num_envs=1)


def test_a_control_kind_the_task_cannot_back_is_refused_at_build(ant):
    """Newton supports every control kind; an articulated task that asks for tet activations has no
    soft body to drive, and gets one line saying so."""
    assert set(backends.get("newton").supported_control_kinds()) == set(ControlKind)

    class ActivatedAnt(type(ant)):
        control_kind = ControlKind.TET_ACTIVATION

    with pytest.raises(BackendError, match="task 'ant' asks for tet activations but defines no soft_body"):
        make("newton", ActivatedAnt(), num_envs=1)


# -- (f) the model carries no parameter gradients, and that changes no state/control gradient --------
@pytest.mark.parametrize("task_name, num_envs, steps", [("ant", 2, 6), ("go2", 2, 3), ("soft_jumper", 1, 3)])
def test_a_model_without_parameter_gradients_gives_bit_identical_gradients(task_name, num_envs, steps):
    """The adapter finalizes the model with ``requires_grad=False`` (the adjoint kernels then skip their
    accumulators into masses, gains and contact parameters). Against the same adapter built with
    ``parameter_gradients=1`` (a model with parameter gradients, as Rewarped builds it), d(loss)/d(actions)
    and d(loss)/d(initial state) must be equal to the bit on all three tasks (semi-implicit with contacts,
    Featherstone with PD, FEM soft body): a gradient path that ran through a buffer allocated with the
    model's flag would show up as a difference (checked by hand: dropping the gradients of Featherstone's
    per-frame matrices changes the Go2's action gradients by up to 9.8).
    """
    task = make_task(task_name)
    plain = make("newton", task, num_envs=num_envs, seed=0)
    with_params = make("newton", task, num_envs=num_envs, seed=0, parameter_gradients=1)
    assert not plain.model.requires_grad and with_params.model.requires_grad
    _, ga, ea = _window_gradients(plain, steps, torch.Generator().manual_seed(5))
    _, gb, eb = _window_gradients(with_params, steps, torch.Generator().manual_seed(5))
    assert ga.abs().max() > 0 and ea.abs().max() > 0
    assert torch.equal(ga, gb) and torch.equal(ea, eb)


def _window_gradients(sim, steps: int, gen: torch.Generator):
    """One window of ``steps`` random actions from the current state, with a loss on every output:
    the next engine states, d(loss)/d(actions) stacked, and d(loss)/d(initial engine state)."""
    engine = sim.state.engine.detach().clone().requires_grad_(True)
    sim.state = dataclasses.replace(sim.state, engine=engine)
    actions = [
        (2.0 * torch.rand(sim.num_envs, sim.task.action_dim, generator=gen) - 1.0).requires_grad_(True)
        for _ in range(steps)
    ]
    loss, states = 0.0, []
    for a in actions:
        s = sim.step(a)
        states.append(s.engine.detach().clone())
        loss = loss + s.engine.square().sum() + s.joint_q.sum() + s.joint_qd.sum()
    loss.backward()
    return states, torch.stack([a.grad for a in actions]), engine.grad


def test_parameter_gradients_option_takes_0_or_1(ant):
    with pytest.raises(BackendError, match="parameter_gradients must be 0 or 1"):
        make("newton", ant, num_envs=1, parameter_gradients=2)


# -- (g) graph capture replays exactly what the uncaptured step runs -----------------------------------
@pytest.mark.parametrize("task_name, num_envs, steps", [("ant", 2, 4), ("go2", 2, 3), ("soft_jumper", 1, 3)])
def test_captured_frames_replay_bit_identical_states_and_gradients(task_name, num_envs, steps):
    """With ``graph_capture`` on (the CPU default) each frame's Warp work runs eagerly on first use, is
    captured on the second and replayed afterwards. Four windows on a ring of ``steps`` frames (the
    second captures every frame's graphs, the last two replay them on new inputs), then forward-only
    steps (eager, captured, replayed), must give the same states and the same d(loss)/d(actions) and
    d(loss)/d(initial state) to the bit as ``graph_capture=0``.
    """
    task = make_task(task_name)

    def run(sim):
        gen = torch.Generator().manual_seed(11)
        out = []
        for _window in range(4):
            sim.cut_graph()
            states, action_grads, engine_grad = _window_gradients(sim, steps, gen)
            out += states + [action_grads, engine_grad]
        with torch.no_grad():
            for _ in range(3):
                out.append(sim.step(torch.rand(num_envs, task.action_dim, generator=gen) * 2.0 - 1.0).engine.clone())
        return out

    captured = make("newton", task, num_envs=num_envs, seed=0, max_graph_steps=steps)
    eager = make("newton", task, num_envs=num_envs, seed=0, max_graph_steps=steps, graph_capture=0)
    assert captured.graph_capture and not eager.graph_capture
    a, b = run(captured), run(eager)
    assert all(f.forward_graph is not None and f.backward_graph is not None for f in captured.stepper.frames)
    assert captured.stepper.scratch.forward_graph is not None
    assert all(f.forward_graph is None for f in eager.stepper.frames)
    assert len(a) == len(b) and all(x.abs().max() > 0 for x in a)
    for x, y in zip(a, b, strict=True):
        assert torch.equal(x, y)


def test_graph_capture_option_takes_0_or_1(ant):
    with pytest.raises(BackendError, match="graph_capture must be 0 or 1"):
        make("newton", ant, num_envs=1, graph_capture="yes")


def test_forward_kinematics_gradient_matches_central_differences(ant):
    """``state_from_generalized`` differentiates through Newton's FK tape (``_NewtonFK``): d(w . engine) /
    d(joint_q, joint_qd) against central differences of the same map (float32, step 1e-3)."""
    sim = make("newton", ant, num_envs=2, seed=0)
    gen = torch.Generator().manual_seed(3)
    q, qd = ant.sample_initial_state(2, gen)
    w = torch.randn(2, sim.state.engine.shape[1], generator=gen)

    def value(q_, qd_):
        return (sim.state_from_generalized(q_, qd_).engine * w).sum()

    q_var, qd_var = q.clone().requires_grad_(True), qd.clone().requires_grad_(True)
    value(q_var, qd_var).backward()
    eps = 1e-3
    for analytic, base, is_q in ((q_var.grad, q, True), (qd_var.grad, qd, False)):
        numeric = torch.zeros_like(base)
        for i in range(base.numel()):
            plus, minus = base.clone(), base.clone()
            plus.view(-1)[i] += eps
            minus.view(-1)[i] -= eps
            with torch.no_grad():
                up = value(plus, qd) if is_q else value(q, plus)
                down = value(minus, qd) if is_q else value(q, minus)
            numeric.view(-1)[i] = (up - down) / (2 * eps)
        assert analytic.abs().max() > 0
        assert torch.allclose(analytic, numeric, rtol=2e-2, atol=2e-2 * float(numeric.abs().max()))
