"""The contract suite (:mod:`harness.contract_suite`) on every registered adapter, built-in and plugged
in, each on its ``contract_tasks``; and the registry and finiteness checks it rests on."""

from __future__ import annotations

import pytest
import torch

import backends
from harness.contract_suite import ContractSuite
from simcore import SimState, nonfinite_rows

BACKENDS = backends.available()


def test_the_builtin_adapters_are_registered():
    assert "newton" in BACKENDS


def test_the_third_party_plugin_is_registered_without_editing_this_repo():
    """tests/plugins/diffsim_pointmass is its own package (tox installs it beside ours)."""
    if "pointmass" not in BACKENDS:
        pytest.skip("the test plugin is not installed here (tox -e py installs it)")
    import tasks

    assert "pointmass" in tasks.available()
    assert backends.get("pointmass").__module__.startswith("diffsim_pointmass")


class TestContract(ContractSuite):
    """Every registered adapter (``backend_names`` left empty)."""


@pytest.mark.parametrize(
    ("entries", "expected"),
    [
        ({}, []),
        ({(3, 1): float("nan")}, [3]),
        ({(0, 0): float("inf"), (4, 2): float("-inf")}, [0, 4]),
        ({(2, 0): float("inf"), (2, 1): float("-inf")}, [2]),  # inf - inf: the sum is NaN, still caught
        ({(1, 0): 3.0e38, (1, 1): 3.0e38}, []),  # finite entries whose sum overflows: the exact check decides
    ],
)
def test_the_one_sum_finiteness_check_finds_exactly_the_bad_rows(entries, expected):
    """The per-step checks (actions, controls, states) sum a tensor first and look row by row only
    when the sum is not finite; the rows they report equal the row-by-row isfinite check's."""
    values = torch.randn(6, 3, 2)
    for (row, col), value in entries.items():
        values[row, col, 0] = value
    reference = (~torch.isfinite(values).flatten(1).all(dim=1)).nonzero().flatten().tolist()
    assert reference == expected
    assert nonfinite_rows(values) == expected
    state = SimState(joint_q=torch.zeros(6, 2), joint_qd=values[:, :, 0], engine=torch.zeros(6, 1))
    assert state.nonfinite_envs() == expected
