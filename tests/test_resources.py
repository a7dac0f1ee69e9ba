"""Sizes this machine cannot hold are refused before any work, in one line with the estimate and the
limit (harness/resources.py): on the command line, and for a suite before its first job."""

from __future__ import annotations

import pytest

from harness import resources
from harness.cli import main

GIB = float(1 << 30)
ANT = ["--task", "ant", "--backend", "newton"]


@pytest.fixture
def eight_gib(monkeypatch):
    """A machine with 8 GiB free, whatever this one has."""
    monkeypatch.setattr(resources, "available_bytes", lambda device="cpu": 8 * GIB)


def test_the_estimate_grows_with_envs_and_with_the_window_only_with_gradients():
    one = resources.estimate_bytes("newton", "ant", 64, 32)
    assert resources.estimate_bytes("newton", "ant", 128, 32) == pytest.approx(2 * one)
    assert resources.estimate_bytes("newton", "ant", 64, 64) > 1.9 * one
    assert resources.estimate_bytes("newton", "ant", 64, 64, grads=False) == resources.estimate_bytes(
        "newton", "ant", 64, 1, grads=False
    )
    assert resources.estimate_bytes("newton", "ant.bench_kf3000", 64, 32) == one  # a preset: the same robot
    assert resources.estimate_bytes("pointmass", "ant", 64, 32) is None  # nothing measured: no estimate


def test_a_size_that_fits_passes_and_one_that_does_not_names_estimate_limit_and_largest_count():
    assert resources.memory_problem("newton", "ant", 64, 32, available=8 * GIB) is None
    assert resources.memory_problem("pointmass", "ant", 10**9, 32, available=1.0) is None
    problem = resources.memory_problem("newton", "ant", 4096, 32, available=8 * GIB)
    need = resources.estimate_bytes("newton", "ant", 4096, 32)
    assert f"{need / GIB:.1f} GiB" in problem and "8.0 GiB free" in problem
    fits = int(problem.split("at most ")[1].split()[0])
    assert resources.estimate_bytes("newton", "ant", fits, 32) <= 8 * GIB
    assert resources.estimate_bytes("newton", "ant", fits + 1, 32) > 8 * GIB
    twice = resources.memory_problem("newton", "ant", 600, 32, copies=2, available=0.1 * GIB + need / 4096 * 600)
    assert "x 2 jobs at once" in twice and "per job" in twice


def test_this_machine_says_how_much_memory_is_free():
    assert resources.available_bytes() > 0


@pytest.mark.parametrize(
    "args",
    [
        ["train", *ANT, "--algo", "shac", "--epochs", "1", "--num-envs", "8192", "--horizon", "32", "--out", "o"],
        ["throughput", *ANT, "--num-envs", "8192", "--horizon", "32"],
        ["scaling", *ANT, "--envs", "64", "8192", "--horizon", "32", "--out", "s"],
        ["grad-paths", *ANT, "--num-envs", "8192", "--horizon", "32"],
        ["gradcheck", *ANT, "--num-envs", "8192", "--steps", "32"],
        ["crosscheck", "--task", "ant", "--backends", "newton", "mujoco_warp", "--num-envs", "8192", "--steps", "32"],
    ],
    ids=lambda a: a[0],
)
def test_the_verbs_refuse_too_many_envs_in_one_line_before_work(args, eight_gib, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --") and err.count("\n") == 1 and "need at least" in err and "8.0 GiB free" in err
    assert not any(tmp_path.iterdir())


def test_a_suite_whose_runs_cannot_fit_together_is_refused_before_its_first_job(eight_gib, tmp_path, capsys):
    spec = tmp_path / "spec.toml"
    store = tmp_path / "store"
    block = "[[train]]\nbackends=['newton']\ntasks=['ant']\nalgos=['shac']\nseeds=[0, 1]\nepochs=1\nhorizons=[32]\n"
    spec.write_text(f"[suite]\nname='x'\njobs=2\n{block}num_envs=600\n")  # ~5.6 GiB each: one fits, not two
    assert main(["bench", "--spec", str(spec), "--store", str(store)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the 2 largest at once" in err and "(--jobs 1)" in err, err
    assert not store.exists()
    assert main(["bench", "--spec", str(spec), "--store", str(store), "--dry-run"]) == 0  # planning is not work
