"""Proposition 1's measurement (harness/checks/step_gain.py): the tape's one-step Jacobian against central
differences of the same step where the step is smooth (an Ant lifted clear of the ground), the gains
as spectral norms, the window's growth against the one-step gain, and the end-to-end file of a tiny
trained run."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import torch

from algorithms.config import preset
from harness.checks.step_gain import (
    compute_step_gain,
    gains,
    state_columns,
    step_jacobians,
    window_gain,
    write_step_gain,
)
from harness.results import RunError


def test_gains_are_the_spectral_norms_of_the_state_and_action_blocks():
    jac = np.zeros((3, 5))
    jac[:, :3] = np.diag([2.0, -0.5, 1.0])  # three state columns, singular values 2, 1, 0.5
    jac[0, 3], jac[1, 4] = 3.0, 4.0  # two action columns, singular values 4 and 3
    g = gains(jac, 3)
    assert g["state_gain"] == pytest.approx(2.0)
    assert g["action_gain"] == pytest.approx(4.0)
    assert g["joint_gain"] == pytest.approx(np.linalg.svd(jac, compute_uv=False)[0])


@pytest.fixture(scope="module")
def airborne():
    """A Newton Ant of 2 envs lifted clear of the ground, mid-air with some joint motion: its step is smooth."""
    pytest.importorskip("newton")
    from harness.envs import make_sim
    from tasks import make_task

    task = make_task("ant")
    sim = make_sim("newton", task, 2, seed=0, horizon=4)
    sim.reset()
    q, qd = sim.state.joint_q.detach().clone(), sim.state.joint_qd.detach().clone()
    q[:, 2] = task.airborne_height
    qd[:, 6:] = 0.3 * torch.linspace(-1.0, 1.0, qd.shape[1] - 6)
    actions = 0.2 * torch.ones(2, task.action_dim)
    return sim, q, qd, actions


def test_the_tapes_step_jacobian_agrees_with_central_differences_in_the_air(airborne):
    sim, q, qd, actions = airborne
    jac = step_jacobians(sim, q, qd, actions)
    nq, cols = sim.layout.nq, state_columns(sim.layout)
    assert 3 not in cols and 6 not in cols and len(cols) == nq + sim.layout.nv - 4  # the root quaternion left out

    def step(x, a):
        with torch.no_grad():
            nxt = sim.advance(sim.state_from_generalized(x[:, :nq], x[:, nq:]), a)
            return torch.cat((nxt.joint_q, nxt.joint_qd), dim=1).double()

    x, eps = torch.cat((q, qd), dim=1), 1e-3
    fd = torch.zeros_like(jac)
    for k in range(len(cols) + actions.shape[1]):
        plus_x, minus_x, plus_a, minus_a = x.clone(), x.clone(), actions.clone(), actions.clone()
        if k < len(cols):
            plus_x[:, cols[k]] += eps
            minus_x[:, cols[k]] -= eps
        else:
            plus_a[:, k - len(cols)] += eps
            minus_a[:, k - len(cols)] -= eps
        fd[:, :, k] = (step(plus_x, plus_a) - step(minus_x, minus_a)) / (2.0 * eps)
    for env in range(2):
        rel = float(torch.linalg.norm(jac[env] - fd[env]) / torch.linalg.norm(fd[env]))
        assert rel < 0.02, (env, rel)


def test_a_one_step_window_grows_by_the_one_step_state_gain(airborne):
    sim, q, qd, actions = airborne
    jac = step_jacobians(sim, q, qd, actions).numpy()
    width = len(state_columns(sim.layout))
    one_step = [gains(jac[i], width)["state_gain"] for i in range(2)]
    np.testing.assert_allclose(window_gain(sim, q, qd, [actions]), one_step, rtol=1e-6)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    pytest.importorskip("newton")
    from harness.run.train import train

    cfg = preset("shac-tdfixed").replace(num_envs=2, horizon=4, critic_iterations=1, grad_var_groups=2)
    return train(tmp_path_factory.mktemp("step_gain") / "run", "ant", "newton", cfg, epochs=1, stream=io.StringIO())


def test_step_gain_end_to_end(run):
    out = io.StringIO()
    result = compute_step_gain(run, states=5, num_envs=2, stride=2, stream=out)
    assert len(result["rows"]) == 5 and "5/5 states" in out.getvalue()
    assert result["paper_bound"] == pytest.approx(1.0 / (0.99 * 0.95))
    assert result["lambda"] == pytest.approx(0.95)  # TDFixed: the constant lambda
    summary = result["summary"]["state_gain"]
    states = [r["state_gain"] for r in result["rows"]]
    assert summary["median"] == pytest.approx(float(np.median(states)))
    assert summary["fraction_above_bound"] == pytest.approx(np.mean(np.array(states) > result["paper_bound"]))
    assert all(r["joint_gain"] >= max(r["state_gain"], r["action_gain"]) - 1e-9 for r in result["rows"])
    assert result["window"]["steps"] == 4 and result["window"]["per_step_growth"]["median"] > 0
    path = write_step_gain(run, result)
    assert json.loads(path.read_text())["states"] == 5


def test_step_gain_refuses_bad_requests(run):
    with pytest.raises(RunError, match="states must be an integer >= 1"):
        compute_step_gain(run, states=0)
    with pytest.raises(RunError, match="stride must be"):
        compute_step_gain(run, stride=True)


def test_the_verb_refuses_a_bad_flag_in_one_line(capsys):
    from harness.cli import main

    try:
        code = main(["step-gain", "--run", "nowhere", "--stride", "100000"])
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert "--stride: expected an integer in [1, 1000], got 100000" in err and len(err.strip().splitlines()) == 1
