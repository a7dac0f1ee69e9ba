"""The in-contact Jacobian check: its control (the same states lifted off the ground) agrees with the
reference, so a disagreement it reports in contact is the contact's; its sampler keeps only states
MuJoCo C finds in contact; bad input is refused in one line."""

from __future__ import annotations

import pytest

pytest.importorskip("newton")
pytest.importorskip("mujoco_warp")

from harness.checks.contact_jacobians import compare, contact_jacobians, gains  # noqa: E402
from harness.cli import main as cli  # noqa: E402


@pytest.mark.parametrize("backend", ["mujoco_warp", "newton"])
def test_the_lifted_control_agrees_and_every_sampled_state_is_in_contact(backend):
    # two step sizes of Newton's sweep are enough to find a plateau off the ground
    result = contact_jacobians(
        "ant",
        backend,
        states=2,
        num_envs=2,
        settle=10,
        policy_epochs=1,
        eps_sweep=(1e-2, 3e-3),
        progress=lambda line: None,
    )
    assert result["all"]["states"] == 2 and all(row["contacts"] > 0 for row in result["rows"])
    # one state from random actions, one from the briefly trained policy, each row says which
    assert [row["source"] for row in result["rows"]] == ["random actions", "SHAC policy after 1 epochs"]
    assert all(s["states"] == 1 for s in result["by_source"].values())
    assert result["control_in_contact"] == 0
    assert result["control_lifted"]["median_rel_error"] < 1e-2  # smooth off the ground: the comparison is exact
    for row in result["rows"]:
        assert -1.0 - 1e-9 <= row["cosine"] <= 1.0 + 1e-9 and row["rel_error"] >= 0.0
        assert row["state_gain"] >= row["velocity_from_position_gain"] > 0.0
    if backend == "mujoco_warp":
        # off the ground the adapter's differences are exact, so its gains are the reference's
        lifted = result["control_lifted"]
        assert lifted["median_state_gain"] == pytest.approx(lifted["median_reference_state_gain"], rel=1e-2)


def test_newton_agrees_with_its_own_differences_in_contact_wherever_they_converge():
    """The tape's Jacobian takes one backward pass per output coordinate through the same step; were a
    repeated pass to differ from the first (Newton's kernels rewrite forward values while their tape
    replays), the tape would disagree with converged differences by O(1) at most states in contact."""
    result = contact_jacobians(
        "ant", "newton", states=6, num_envs=3, policy_epochs=0, eps_sweep=(1e-3, 3e-4, 1e-4), progress=lambda line: None
    )
    converged = [row for row in result["rows"] if row["plateau_eps"] is not None]
    assert len(converged) >= 3, result["rows"]
    assert max(row["rel_error"] for row in converged) < 5e-2, [row["rel_error"] for row in converged]


def test_without_contact_damping_newtons_go2_tape_agrees_in_contact():
    """The Go2's feet rest on the ground, where the one-sided contact damping min(v_n, 0) kd switches
    inside every stencil; with it off (the control the check runs beside) the step is smooth and the
    tape must agree with the differences."""
    result = contact_jacobians(
        "go2", "newton", states=2, num_envs=2, policy_epochs=0, eps_sweep=(1e-3, 3e-4, 1e-4), progress=lambda line: None
    )
    assert result["control_no_contact_damping"]["median_rel_error"] < 2e-2, result["control_no_contact_damping"]


def test_gains_are_the_spectral_norms_of_the_chosen_blocks():
    import numpy as np

    # rows: next q (2), next qd (2); columns: q0, q1 (left out), qd0, qd1
    jac = np.array([[1.0, 9.0, 0.0, 0.0], [0.0, 9.0, 1.0, 0.0], [50.0, 9.0, 2.0, 0.0], [0.0, 9.0, 0.0, 3.0]])
    g = gains(jac, nq=2, position_cols=[0], velocity_cols=[2, 3])
    assert g["velocity_from_position_gain"] == pytest.approx(50.0)
    assert g["velocity_from_velocity_gain"] == pytest.approx(np.linalg.norm([[2.0, 0.0], [0.0, 3.0]], 2))
    assert g["state_gain"] == pytest.approx(np.linalg.norm(jac[:, [0, 2, 3]], 2))


def test_compare_is_relative_and_scale_free():
    import numpy as np

    ref = np.arange(6.0).reshape(2, 3)
    assert compare(ref, ref) == (0.0, pytest.approx(1.0))
    rel, cos = compare(2.0 * ref, ref)
    assert rel == pytest.approx(1.0) and cos == pytest.approx(1.0)


def test_bad_input_is_one_line(capsys):
    # the suite passes --device to every single-backend check
    assert (
        cli(["contact-jacobians", "--backend", "newton", "--task", "soft_jumper", "--device", "cpu", "--states", "2"])
        == 2
    )
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "soft bodies" in err
