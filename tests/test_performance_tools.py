"""The measuring verbs of the performance work: ``scaling`` (CSV, plot, skips) and ``fd-schemes``."""

from __future__ import annotations

import json

import pytest

from harness.cli import main


def _pointmass_or_skip():
    import backends

    if "pointmass" not in backends.available():
        pytest.skip("the test plugin is not installed here (tox -e py installs it)")


def test_scaling_writes_csv_json_and_plot_and_skips_what_would_take_too_long(tmp_path, capsys, monkeypatch):
    _pointmass_or_skip()
    # without --out it prints its table and writes nothing, as every measuring verb
    monkeypatch.chdir(tmp_path)
    args = ["scaling", "--backend", "pointmass", "--task", "pointmass", "--envs", "1", "2"]
    assert main([*args, "--horizon", "2", "--windows", "1"]) == 0
    assert "pointmass,pointmass,2,2," in capsys.readouterr().out
    assert not list(tmp_path.iterdir())
    out = tmp_path / "scaling_pm"
    args = ["scaling", "--backend", "pointmass", "--task", "pointmass", "--envs", "1", "2", "4"]
    assert main([*args, "--horizon", "2", "--windows", "1", "--out", str(out)]) == 0
    rows = json.loads(out.with_suffix(".json").read_text())["result"]["rows"]
    assert [r["num_envs"] for r in rows] == [1, 2, 4]
    assert all(r["forward_steps_per_s"] > 0 and r["forward_backward_steps_per_s"] > 0 for r in rows)
    csv_text = out.with_suffix(".csv").read_text()
    assert csv_text.startswith("# python -m harness") and "# commit " in csv_text
    assert "pointmass,pointmass,4,2," in csv_text
    assert out.with_suffix(".png").stat().st_size > 0

    tight = tmp_path / "scaling_tight"
    assert main([*args, "--horizon", "2", "--windows", "1", "--max-seconds", "1e-9", "--out", str(tight)]) == 0
    rows = json.loads(tight.with_suffix(".json").read_text())["result"]["rows"]
    assert rows[0]["forward_steps_per_s"] > 0
    assert all(r["forward_steps_per_s"] is None and r["note"].startswith("skipped") for r in rows[1:])

    forward = tmp_path / "scaling_forward"
    assert main([*args, "--horizon", "2", "--windows", "1", "--forward-only", "--out", str(forward)]) == 0
    rows = json.loads(forward.with_suffix(".json").read_text())["result"]["rows"]
    assert all(r["forward_steps_per_s"] > 0 and r["forward_backward_steps_per_s"] is None for r in rows)

    both = tmp_path / "both.png"
    csvs = [str(out.with_suffix(".csv")), str(tight.with_suffix(".csv")), str(forward.with_suffix(".csv"))]
    assert main(["scaling-plot", "--csv", *csvs, "--out", str(both)]) == 0
    assert both.stat().st_size > 0

    # the bench report draws every scaling check's curves in one figure; without one it says so
    from harness.report import write_bench_report
    from harness.results import provenance

    checks = [out.with_suffix(".json"), tight.with_suffix(".json")]
    written = write_bench_report([], checks, tmp_path / "report", provenance() | {"profile": "t"})
    assert (tmp_path / "report" / "scaling.png") in written
    assert "`scaling.png`" in (tmp_path / "report" / "index.md").read_text()
    write_bench_report([], [], tmp_path / "report", provenance() | {"profile": "t"})
    assert not (tmp_path / "report" / "scaling.png").exists()
    assert "scaling.png: no scaling check" in (tmp_path / "report" / "index.md").read_text()


@pytest.mark.parametrize(
    "args, needle",
    [
        (["scaling", "--backend", "newton", "--task", "ant", "--envs", "4", "1"], "distinct and increasing"),
        (["scaling", "--backend", "newton", "--task", "ant", "--envs", "0"], "[1, 65536]"),
        (["scaling-plot", "--csv", "nowhere.csv", "--out", "x.png"], "no such scaling CSV"),
        (["fd-schemes", "--task", "soft_jumper"], "articulated tasks"),
        (["fd-schemes", "--task", "ant", "--schemes", "adaptive", "backward"], "unknown scheme 'backward'"),
        (["fd-schemes", "--task", "ant", "--contact-states", "0"], "--contact-states"),
        (["fd-schemes", "--task", "ant", "--contact-states", "1000000000"], "--contact-states"),
        (["fd-schemes", "--task", "ant", "--contact-states", "12"], "not a multiple of --num-envs 8"),
        (["throughput", "--backend", "newton", "--task", "ant", "--backend-option", "fd_scheme"], "KEY=VALUE"),
        (["gradcheck", "--backend", "newton", "--task", "ant", "--backend-option", "fd_scheme=forward"], "no option"),
        (
            ["peer", "--peer", "dflex", "--task", "ant", "--num-envs", "4", "--horizon", "4", "--out", "p.json"],
            "unknown peer",
        ),
        (["peer", "--task", "go2", "--num-envs", "4", "--horizon", "4", "--out", "p.json"], "has the tasks"),
        (
            ["peer", "--task", "ant", "--num-envs", "4", "--horizon", "4", "--out", "p.json", "--python", "/nowhere"],
            "not an executable",
        ),
    ],
)
def test_bad_input_to_the_measuring_verbs_is_one_line(args, needle, capsys, monkeypatch):
    monkeypatch.delenv("DIFFSIM_REWARPED_PYTHON", raising=False)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err


def test_peer_without_its_interpreter_says_what_to_set(capsys, monkeypatch, tmp_path):
    monkeypatch.delenv("DIFFSIM_REWARPED_PYTHON", raising=False)
    args = ["peer", "--task", "ant", "--num-envs", "4", "--horizon", "4", "--out", str(tmp_path / "p.json")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "DIFFSIM_REWARPED_PYTHON" in err
    assert not (tmp_path / "p.json").exists()


def test_fd_schemes_measures_forward_differences_against_the_float64_reference(tmp_path):
    pytest.importorskip("mujoco_warp")
    from backends.mujoco_warp.adapter import FD_EPS_STATE
    from harness.checks.fd_schemes import fd_schemes, markdown

    grid = (
        {"fd_scheme": "forward", "fd_eps_state": 2e-3, "fd_eps_velocity": 2e-3},
        {
            "fd_scheme": "forward",
            "fd_eps_state": 2e-3,
            "fd_eps_velocity": 2e-3,
            "fd_warmstart": "nominal",
            "fd_tolerance": 0.0,
        },
    )
    report = fd_schemes(
        "ant",
        num_envs=2,
        contact_states=2,
        timing_envs=0,
        settle=10,
        grid=grid,
        control_factors=(0.1,),
        progress=lambda _: None,
    )
    first, second, control = report["rows"]
    # the control-step row: the adapter's default settings (one-sided differences), its control step scaled
    assert control["fd_eps_control"] == pytest.approx(0.1) and control["fd_eps_state"] == FD_EPS_STATE["one_sided"]
    assert set(first["contact_error_median_by_kind"]) == {"position", "velocity", "control"}
    assert first["worlds_per_env"] == 1 + 14 * 2 + 8
    assert first["contact_free_error_max"] < 1e-3 and second["contact_free_error_max"] < 1e-3
    assert first["contact_states"] == 2 and 0.0 <= first["contact_error_median"] < float("inf")
    text = markdown(report, "cmd")
    assert "| forward | 0.002 | 0.002 | 1 | zero | model's | 37 |" in text and "| nominal | 0 | 37 |" in text


def test_fd_schemes_keeps_the_schemes_asked_for_and_counts_adaptive_second_sides():
    """``schemes`` keeps only those rows (the control-step rows belong to the default scheme); an
    ``adaptive`` row's worlds per env are its 1 + P worlds plus the -eps worlds it added in contact."""
    pytest.importorskip("mujoco_warp")
    from harness.checks.fd_schemes import GRID, fd_schemes

    report = fd_schemes(
        "ant",
        num_envs=2,
        contact_states=4,
        timing_envs=0,
        settle=10,
        grid=GRID,
        schemes=("adaptive",),
        progress=lambda _: None,
    )
    rows = report["rows"]
    assert {r["fd_scheme"] for r in rows} == {"adaptive"} and len(rows) == 3
    assert all(37 <= r["worlds_per_env"] < 73 for r in rows)
    assert report["schemes"] == ["adaptive"]
