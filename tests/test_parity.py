"""The two engines simulate the same task: the static parity targets on the default presets.

Zero-action settle of the Ant and the Go2 (trunk height within 1 cm, every joint angle within
0.02 rad after 2 s) and the probes of the penalty conversion (resting penetration of a sphere and
deflection of a hinge past its stop under a known torque, within 10% across engines and of the
penalty law). The dynamic measurements (open-loop divergence, random-policy episode lengths) are the
``parity`` verb's and live in results/.
"""

from __future__ import annotations

import pytest

from harness import parity
from tasks import make_task

pytest.importorskip("mujoco_warp")
BACKENDS = ("newton", "mujoco_warp")


@pytest.mark.parametrize("task_name", ["ant", "go2"])
def test_zero_action_settle_agrees_across_engines(task_name):
    task = make_task(task_name)
    a, b = (parity.settle(backend, task) for backend in BACKENDS)
    assert abs(a["height_m"] - b["height_m"]) <= parity.TARGETS["settle_height_m"], (a["height_m"], b["height_m"])
    gaps = [abs(x - y) for x, y in zip(a["joint_q"], b["joint_q"], strict=True)]
    assert max(gaps) <= parity.TARGETS["settle_joint_rad"], gaps


@pytest.mark.parametrize("preset", ["bench", "rewarped"])
def test_the_penalty_constants_mean_the_same_on_both_engines(preset, tmp_path):
    task = make_task("ant", preset=preset)
    for backend in BACKENDS:
        contact = parity.probe_penetration(backend, task, tmp_path)
        limit = parity.probe_deflection(backend, task, tmp_path)
        assert contact["penetration_m"] == pytest.approx(contact["penalty_law_m"], rel=parity.TARGETS["probe_rel"])
        assert limit["deflection_rad"] == pytest.approx(limit["penalty_law_rad"], rel=parity.TARGETS["probe_rel"])
