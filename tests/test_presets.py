"""Named physics presets: chosen by name, recorded by every run, and part of what addresses a run."""

from __future__ import annotations

import dataclasses
import json

import pytest

import backends
from harness.envs import run_task
from harness.results import RunError
from harness.suite.bench import RunSpec
from tasks import UnknownPresetError, make_task, task_class


def test_a_preset_sets_constants_engine_settings_and_asset():
    bench, rewarped = make_task("ant"), make_task("ant", preset="rewarped")
    assert bench.preset_label == "bench" and rewarped.preset_label == "rewarped"
    assert bench.backend_options == {"newton": {"solver": "featherstone"}}
    assert rewarped.asset_path.name == "ant_rewarped.xml" and bench.asset_path.name == "ant.xml"
    assert rewarped.physics.contact_ke == pytest.approx(5.2e4) and rewarped.physics.joint_damping == 0.0
    custom = make_task("ant", dataclasses.replace(bench.physics, contact_kf=3.0e3))
    assert custom.preset_label == "bench+custom" and custom.physics_record()["physics"]["contact_kf"] == 3.0e3


def test_an_unknown_preset_is_refused_in_one_line_naming_the_choices():
    choices = "bench, bench_semi_implicit, bench_kf3000, diffrl_contacts, rewarped"
    with pytest.raises(UnknownPresetError, match=choices) as info:
        make_task("ant", preset="dflex")
    assert "\n" not in str(info.value)


def test_a_changed_default_preset_is_a_new_run(monkeypatch):
    spec = RunSpec(task="ant", backend="newton", algo="shac", seed=0, epochs=1, num_envs=4, horizon=4, device="cpu")
    before = spec.key
    monkeypatch.setattr(task_class("ant"), "default_preset", "rewarped")
    assert spec.key != before
    assert spec.identity()["physics"]["preset"] == "rewarped"


def test_a_run_from_before_presets_is_not_rebuilt_on_todays_defaults():
    with pytest.raises(RunError, match="predates physics presets"):
        run_task({"task": "ant", "physics": dataclasses.asdict(make_task("ant").physics)})


@pytest.mark.skipif("pointmass" not in backends.available(), reason="the point-mass plug-in is absent")
def test_resume_refuses_a_run_whose_physics_changed(tmp_path):
    from algorithms.config import preset
    from harness.run.train import resume, train

    cfg = preset("shac").replace(num_envs=4, horizon=4)
    run = tmp_path / "run"
    train(run, "pointmass", "pointmass", cfg, epochs=1, stream=open("/dev/null", "w"))
    config = json.loads((run / "config.json").read_text())
    assert config["physics_record"]["preset"] == "custom"
    config["physics_record"]["physics"]["frame_dt"] = 0.01
    (run / "config.json").write_text(json.dumps(config))
    with pytest.raises(RunError, match="change the physics mid-run"):
        resume(run, epochs=2, stream=open("/dev/null", "w"))


def test_adapter_options_travel_with_a_run(tmp_path):
    """``train --backend-option``: recorded in config.json, kept on resume, part of a bench run's address,
    a row of its own in the report; a bad option is refused before config.json is written."""
    from algorithms.config import preset
    from harness.report.records import load_run
    from harness.run.train import resume, train

    quiet = open("/dev/null", "w")
    cfg = preset("shac").replace(num_envs=4, horizon=2)
    run = tmp_path / "run"
    train(run, "ant", "newton", cfg, epochs=1, stream=quiet, backend_options={"graph_capture": 0})
    assert json.loads((run / "config.json").read_text())["backend_options"] == {"graph_capture": 0}
    resume(run, epochs=2, stream=quiet)
    config = json.loads((run / "config.json").read_text())
    assert config["backend_options"] == {"graph_capture": 0} and len(config["resumed"]) == 1
    assert load_run(run).backend == "newton+graph_capture=0"  # never pooled with the default's seeds

    with pytest.raises(RunError, match="no option 'fd_scheme'"):
        train(tmp_path / "bad", "ant", "newton", cfg, epochs=1, stream=quiet, backend_options={"fd_scheme": "central"})
    assert not (tmp_path / "bad" / "config.json").exists()

    base = RunSpec(
        task="ant", backend="mujoco_warp", algo="shac", seed=0, epochs=1, num_envs=4, horizon=2, device="cpu"
    )
    forward = dataclasses.replace(base, backend_options=(("fd_scheme", "forward"),))
    assert forward.key != base.key
    assert forward.identity()["gradients"]["mujoco_warp"]["fd_scheme"] == "forward"
    assert base.identity()["gradients"]["mujoco_warp"]["fd_scheme"] == "one_sided"  # the default
