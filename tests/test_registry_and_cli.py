"""Backend registry (entry points) and the harness command line."""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest

import simcore
from backends import registry
from harness.cli import main


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "harness", *args], capture_output=True, text=True, timeout=600)


def test_builtin_adapter_is_found_through_its_entry_point():
    assert "newton" in registry.REGISTRY._entry_points()  # declared in pyproject, not hard-coded
    assert "newton" in registry.available()


def test_builtin_task_is_found_through_its_entry_point_like_a_plugin_task():
    import tasks

    assert "ant" in tasks.REGISTRY._entry_points()  # no hard-coded dict of built-in tasks
    assert tasks.task_class("ant").__module__ == "tasks.ant"


def test_third_party_entry_point_is_loaded_by_name(monkeypatch):
    fake = EntryPoint(name="thirdparty", value="backends.newton:NewtonSim", group=registry.ENTRY_POINT_GROUP)
    monkeypatch.setattr(simcore, "entry_points", lambda group: [fake] if group == registry.ENTRY_POINT_GROUP else [])
    monkeypatch.setattr(registry.REGISTRY, "_installed", None)  # read the (patched) entry points again
    assert registry.available() == ["thirdparty"]
    assert registry.get("thirdparty").__name__ == "NewtonSim"


def test_entry_point_that_is_not_an_adapter_is_refused(monkeypatch):
    fake = EntryPoint(name="bogus", value="tasks.ant:Ant", group=registry.ENTRY_POINT_GROUP)
    monkeypatch.setattr(simcore, "entry_points", lambda group: [fake])
    monkeypatch.setattr(registry.REGISTRY, "_installed", None)
    with pytest.raises(TypeError, match="not a BatchedSim"):
        registry.get("bogus")


def test_unknown_backend_names_the_choices():
    with pytest.raises(registry.UnknownBackendError) as info:
        registry.get("bullet")
    assert "choose from: " in str(info.value) and "newton" in str(info.value)


def test_cli_list():
    out = _run("list")
    assert out.returncode == 0, out.stderr
    assert "newton" in out.stdout and "ant" in out.stdout


@pytest.mark.parametrize(
    "args, needle",
    [
        (["gradcheck", "--backend", "bullet", "--task", "ant"], "unknown backend 'bullet'; choose from: "),
        (["throughput", "--backend", "newton", "--task", "dog"], "unknown task 'dog'; choose from: ant"),
        (["throughput", "--backend", "newton", "--task", "ant", "--num-envs", "-3"], "an integer in [1, 65536]"),
        (["gradcheck", "--backend", "newton", "--task", "ant", "--tolerance", "nan"], "positive finite"),
        (["fly"], "invalid choice"),
        (["throughput", "--backend", "newton", "--task", "ant", "--against", "bullet"], "unknown backend 'bullet'"),
        (
            ["throughput", "--backend", "mujoco_warp", "--task", "ant", "--against", "newton", "--grad-cost-only", "4"],
            "cannot go with --grad-cost-only",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args, needle, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ")
    assert needle in err


def test_throughput_verb_writes_a_result_with_its_command(tmp_path):
    out_file = tmp_path / "tp.json"
    args = ["throughput", "--backend", "newton", "--task", "ant", "--num-envs", "2", "--horizon", "2"]
    out = _run(*args, "--windows", "1", "--out", str(out_file))
    assert out.returncode == 0, out.stderr
    assert "forward + backward" in out.stdout
    payload = json.loads(out_file.read_text())
    assert payload["kind"] == "throughput"
    result = payload["result"]
    assert result["forward_steps_per_s"] > 0 and result["forward_backward_steps_per_s"] > 0
    assert result["overhead_ratio"] > 0
    assert payload["provenance"]["command"].startswith("python -m harness throughput --backend newton")
    assert payload["provenance"]["packages"]["newton"] == "1.8.0"


def test_throughput_against_another_backend_times_both_in_turn_and_reports_the_ratio_of_medians(monkeypatch):
    """``--against``: the two adapters' windows alternate (the first round's order flipped in the next), and
    the reported share is the ratio of the median window times, with the rounds' own ratios as its range."""
    from harness.checks import throughput

    class Fake:
        def __init__(self, name, seconds):
            self.name, self.integrator, self.num_envs, self.seconds, self.calls = name, "fake", 4, seconds, 0

    order = []

    def window(sim, horizon, grad, gen):
        assert grad  # the comparison is of steps with gradients
        order.append(sim.name)
        sim.calls += 1
        return sim.seconds[(sim.calls - 1) % len(sim.seconds)]

    monkeypatch.setattr(throughput, "_window", window)
    slow = Fake("slow", [4.0, 4.0, 4.0, 8.0, 4.0, 2.0])  # two warm-ups, then rounds of 4, 8, 4, 2 s
    fast = Fake("fast", [1.0, 1.0, 1.0, 1.0, 2.0, 1.0])  # two warm-ups, then rounds of 1, 1, 2, 1 s
    result = throughput.compare(slow, fast, horizon=8, rounds=4)
    assert order[4:] == ["slow", "fast", "fast", "slow", "slow", "fast", "fast", "slow"]
    assert result["backend"] == "fast" and result["rounds"] == 4
    assert result["speed_ratio"] == pytest.approx(1.0 / 4.0)  # medians 4 s and 1 s
    assert (result["speed_ratio_min"], result["speed_ratio_max"]) == pytest.approx((1.0 / 8.0, 1.0 / 2.0))
    assert result["own_forward_backward_steps_per_s_median"] == pytest.approx(4 * 8 / 4.0)
    assert result["forward_backward_steps_per_s_median"] == pytest.approx(4 * 8 / 1.0)
    line = throughput.summary({"forward_steps_per_s": 10.0, "forward_backward_steps_per_s": 2.0, "against": result}, "")
    assert "0.25 of fast's speed with gradients, same process" in line


@pytest.mark.parametrize(
    "verb, flag, says",
    [
        ("eval", "--num-envs", "per evaluation seed"),
        ("crosscheck", "--num-envs", "compared on every engine"),
        ("solver-probe", "--max-steps", "control steps of each probe rollout"),
        ("parity", "--max-steps", "random-policy episode"),
        ("train", "--out", "run directory"),
        ("sweep", "--out", "runs, logs, tables"),
        ("grad-growth", "--windows", "replayed"),
        ("throughput", "--windows", "the best is kept"),
    ],
)
def test_a_shared_flags_help_says_what_it_means_in_that_verb(verb, flag, says, capsys):
    """One flag, declared once, may mean different things per verb: each verb's help says its own."""
    with pytest.raises(SystemExit):
        main([verb, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    start = text.index(flag + " ", text.index("options:"))  # its entry, not the usage line
    assert says in text[start : start + 200], text[start : start + 200]
    assert "(eval:" not in text and "grad-growth)" not in text  # no other verb's meaning leaks in


def test_a_reader_that_leaves_early_ends_the_command_quietly():
    """``python -m harness list | true``: the reader is gone before the first line is written (imports
    take a second); the closed pipe ends the command without a traceback."""
    out = subprocess.run(
        f"{shlex.quote(sys.executable)} -m harness list | true",
        shell=True,
        capture_output=True,
        text=True,
        timeout=120,
        cwd=Path(__file__).resolve().parents[1],
    )
    assert out.stderr == "", out.stderr
