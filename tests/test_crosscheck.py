"""The cross-backend gradient comparison, on a backend against itself (must agree exactly)."""

from __future__ import annotations

import pytest

pytest.importorskip("newton")

from harness.checks.crosscheck import crosscheck  # noqa: E402
from harness.checks.gradcheck import DEFAULT_TOLERANCE  # noqa: E402


def test_a_backend_agrees_with_itself_and_reports_its_own_check():
    report = crosscheck("ant", ["newton", "newton"], num_envs=2, steps=2)
    for segment in ("contact_free", "with_contact"):
        pair = report["segments"][segment]["pairs"]["newton vs newton"]
        for kind in ("actions", "initial_state"):
            assert pair[kind]["rel_diff"] == 0.0
            assert pair[kind]["cosine"] == pytest.approx(1.0, abs=1e-9)
    own = report["segments"]["contact_free"]["own_finite_difference_check"]["newton"]
    assert own["actions_rel_error"] < DEFAULT_TOLERANCE and own["initial_state_rel_error"] < DEFAULT_TOLERANCE
