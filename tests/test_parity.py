"""The two engines simulate the same task: the static parity targets on the default presets.

Zero-action settle of the Ant and the Go2 (trunk height within 1 cm, every joint angle within
0.02 rad after 2 s) and the probes of the penalty conversion (resting penetration of a sphere and
deflection of a hinge past its stop under a known torque, within 10% across engines and of the
penalty law). The dynamic measurements (open-loop divergence, random-policy episode lengths) are the
``parity`` verb's and live in results/.
"""

from __future__ import annotations

import pytest

from harness.checks import parity
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


def _measured(height: float, joints: list[float], penetration: float, deflection: float, length: float) -> dict:
    return {
        "settle": {"height_m": height, "joint_q": joints, "height_path": [height]},
        "probe_contact": {"penetration_m": penetration, "penalty_law_m": 0.001},
        "probe_limit": {"deflection_rad": deflection, "penalty_law_rad": 0.01},
        "first_episode": {"mean": length, "lengths": [length]},
    }


def test_any_number_of_engines_is_compared_with_the_first_and_tabulated():
    """Three engines: each other one is compared with the first, the verdict holds only where every
    comparison does, and the table has a column per engine (a plug-in is tabulated as the built-ins)."""
    per = {
        "newton": _measured(0.25, [0.0, 0.1], 0.00100, 0.0100, 40.0),
        "mujoco_warp": _measured(0.251, [0.0, 0.11], 0.00101, 0.0101, 42.0),
        "third": _measured(0.30, [0.0, 0.1], 0.00100, 0.0100, 41.0),  # stands 5 cm higher
    }
    comparisons = {other: parity._compare(per["newton"], per[other]) for other in ("mujoco_warp", "third")}
    assert comparisons["mujoco_warp"]["holds"]["settle_height"] and not comparisons["third"]["holds"]["settle_height"]
    loop = {"steps_compared": 1, "root_pos_rms_m": [0.0], "joint_rms_rad": [0.0]}
    result = {
        "task": "ant",
        "preset": "bench",
        "backends": list(per),
        "targets": parity.TARGETS,
        "per_backend": per,
        "comparisons": {k: {**v, "open_loop": loop} for k, v in comparisons.items()},
        "gaps": {k: max(c["gaps"][k] for c in comparisons.values()) for k in comparisons["third"]["gaps"]},
        "holds": {k: all(c["holds"][k] for c in comparisons.values()) for k in comparisons["third"]["holds"]},
        "open_loop": loop,
        "settings": {"num_envs": 4, "seeds": 1, "steps": 1, "max_steps": 10, "seed": 0},
    }
    text = parity.table(result)
    assert "| measurement | newton | mujoco_warp | third | largest gap to newton | target | holds |" in text
    assert "| settle trunk height (m) | 0.2500 | 0.2510 | 0.3000 | 0.0500 | <= 0.01 | no |" in text
    assert "(third)" in text and "(mujoco_warp)" in text
