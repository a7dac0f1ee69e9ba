"""The benchmark suite (`harness bench`): specs, content addressing, reuse and resume, the whole pipeline.

Most tests use the point-mass plug-in (a backend and a task of its own, milliseconds per step); the
newcomer's test runs a tiny spec on the real Newton Ant through checks, training, evaluation, a loss
landscape, tables and plots, as `tox -e bench` does at a larger scale.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import backends
from harness.results import RunError
from harness.suite.bench import RunSpec, load_spec, plan, train_job
from harness.suite.runner import run_suite

POINTMASS = pytest.mark.skipif("pointmass" not in backends.available(), reason="the point-mass plug-in is absent")

POINTMASS_SPEC = """
[suite]
name = "pm"
jobs = 2

[eval]
seeds = 1
num_envs = 4

[[train]]
backends = ["pointmass"]
tasks = ["pointmass"]
algos = ["shac", "shac-tdadpt"]
seeds = [0, 1]
horizons = [4, 8]
epochs = 3
num_envs = 4
hyperparameters = { critic_iterations = 1 }  # the suite's mechanics are under test here, not the critic
"""


def _write(tmp_path: Path, text: str, name: str = "spec.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _env() -> dict:
    return dict(os.environ, OMP_NUM_THREADS="1", PYTHONUNBUFFERED="1")


# -- specs and addresses ----------------------------------------------------------------------------


def test_every_shipped_profile_plans(tmp_path):
    """Every shipped profile parses and expands to jobs (names, algorithms and configs all valid)."""
    counts = {}
    for profile in ("smoke", "standard", "perf", "paper", "protocol"):
        data, _ = load_spec(profile=profile)
        jobs = plan(data, tmp_path)
        counts[profile] = sum(j.kind == "train" for j in jobs)
        assert len({j.label for j in jobs}) == len(jobs), f"{profile}: two jobs share a label"
    # the paper's protocol: 6 algorithms x 3 tasks x 10 seeds x 5 horizons on Newton, 6 x 2 x 10 on MuJoCo-Warp
    assert counts["paper"] == 6 * 3 * 10 * 5 + 6 * 2 * 10
    assert counts["smoke"] < counts["standard"] < counts["paper"]
    # the Ant SHAC family, the Go2, the Ant SAPO family at 5 seeds (the sequential blocks' first look, on an
    # empty store: their seeds 0-4 are those runs), then the Fig. 6 ablation: 4 lambda updates x 3 seeds
    assert counts["protocol"] == 3 * 5 + 2 * 5 + 3 * 5 + 4 * 3


def test_block_order_runs_each_blocks_seeds_before_the_next_block(tmp_path):
    grid = (
        "[suite]\nname='x'\n{order}"
        "[[train]]\nbackends=['newton']\ntasks=['ant']\nalgos=['shac']\nepochs=3\nseeds=[0,1]\nnum_envs=4\n"
        "[[train]]\nbackends=['newton']\ntasks=['go2']\nalgos=['shac']\nepochs=3\nseeds=[0,1]\nnum_envs=4\n"
    )
    orders = {}
    for order in ("", "order='seed'\n", "order='block'\n"):
        data, _ = load_spec(spec_file=str(_write(tmp_path, grid.format(order=order))))
        orders[order] = [(j.run.task, j.run.seed) for j in plan(data, tmp_path)]
    assert orders[""] == orders["order='seed'\n"] == [("ant", 0), ("go2", 0), ("ant", 1), ("go2", 1)]
    assert orders["order='block'\n"] == [("ant", 0), ("ant", 1), ("go2", 0), ("go2", 1)]
    with pytest.raises(RunError, match="order: unknown .random.; choose from: seed, block"):
        plan(load_spec(spec_file=str(_write(tmp_path, grid.format(order="order='random'\n"))))[0], tmp_path)


def test_run_address_is_its_full_config():
    base = RunSpec(task="ant", backend="newton", algo="shac", seed=0, epochs=10, num_envs=8, horizon=16, device="cpu")
    same = RunSpec(**{**base.__dict__, "eval_seeds": 3})  # how a run is evaluated is not what it is
    assert base.key == same.key and base.dirname == same.dirname
    for change in ({"seed": 1}, {"epochs": 11}, {"horizon": 8}, {"hyperparameters": (("actor_lr", 1e-3),)}):
        other = RunSpec(**{**base.__dict__, **change})
        assert other.key != base.key, change
    assert base.dirname.startswith("ant_newton_shac_h16_s0_")


def test_a_run_is_addressed_by_its_adapters_gradient_settings(monkeypatch):
    """Finite-difference gradients depend on their steps: a MuJoCo-Warp run's address holds its adapter's
    settings, so a changed default plans new runs; exact gradients add nothing (Newton's addresses stay)."""
    pytest.importorskip("mujoco_warp")
    from backends.mujoco_warp import adapter
    from harness.suite import bench

    spec = dict(task="ant", algo="shac", seed=0, epochs=10, num_envs=8, horizon=16, device="cpu")
    newton = RunSpec(backend="newton", **spec)
    assert "gradients" not in newton.identity()
    mujoco = RunSpec(backend="mujoco_warp", **spec)
    settings = mujoco.identity()["gradients"]["mujoco_warp"]
    assert settings["fd_scheme"] == "one_sided" and settings["fd_eps_state"] == adapter.FD_EPS_STATE["one_sided"]
    before = mujoco.key
    monkeypatch.setitem(adapter.FD_EPS_STATE, "one_sided", adapter.FD_EPS_STATE["one_sided"] / 2)
    bench._gradient_settings.cache_clear()
    try:
        assert mujoco.key != before
    finally:
        monkeypatch.undo()
        bench._gradient_settings.cache_clear()
    assert mujoco.key == before


def test_a_check_is_addressed_by_the_gradient_settings_of_the_options_it_names(tmp_path, monkeypatch):
    """A check run with --backend-option differentiates with that option's settings: its address holds
    them (not the default's), so changing the forward step re-plans only the forward check."""
    pytest.importorskip("mujoco_warp")
    from backends.mujoco_warp import adapter
    from harness.suite import bench

    check = "[[check]]\nkind='contact-jacobians'\nbackends=['mujoco_warp']\ntasks=['ant']\nargs=[{}]\n"
    named = ("", "'--backend-option', 'fd_scheme=forward'", "'--backend-option', 'fd_scheme=one_sided'")
    text = "[suite]\nname='c'\n" + "".join(check.format(words) for words in named)
    data, _ = load_spec(spec_file=str(_write(tmp_path, text)))

    def outputs():
        bench._gradient_settings.cache_clear()
        return [j.output.name for j in plan(data, tmp_path)]

    default, forward, one_sided = outputs()
    monkeypatch.setitem(adapter.FD_EPS_STATE, "forward", adapter.FD_EPS_STATE["forward"] / 2)
    try:
        changed = outputs()
        assert changed[0] == default and changed[1] != forward and changed[2] == one_sided
    finally:
        monkeypatch.undo()
        bench._gradient_settings.cache_clear()


def test_a_block_may_choose_a_physics_preset(tmp_path):
    """A block's preset is part of its runs' addresses and names; naming the task's default preset
    addresses the same runs as leaving it out."""
    block = "[[train]]\nbackends=['newton']\ntasks=['ant']\nalgos=['shac']\nseeds=[0]\nhorizons=[8]\nepochs=2\n"
    text = "[suite]\nname='p'\n" + block + block + "preset='bench'\n" + block + "preset='rewarped'\n"
    data, _ = load_spec(spec_file=str(_write(tmp_path, text)))
    runs = [j.run for j in plan(data, tmp_path) if j.kind == "train"]
    assert len(runs) == 2  # the default named and unnamed are one run
    default, rewarped = runs
    assert default.dirname.startswith("ant_newton_shac_h8_s0_") and default.preset is None
    assert rewarped.dirname.startswith("ant.rewarped_newton_shac_h8_s0_")
    assert rewarped.identity()["physics"]["preset"] == "rewarped" != default.identity()["physics"]["preset"]
    assert rewarped.key != default.key


def test_an_analysis_block_chooses_between_two_train_blocks_or_is_refused(tmp_path):
    """Two [[train]] blocks that share task, backend, algorithm, seed and horizon but not epochs: a
    sim-to-sim block selects by ``epochs``/``train_num_envs``, and without them names the clash."""
    grid = (
        "[suite]\nname='x'\n"
        "[[train]]\nbackends=['newton']\ntasks=['ant']\nalgos=['shac']\nepochs=3\nhorizons=[8]\nnum_envs=4\n"
        "[[train]]\nbackends=['newton']\ntasks=['ant']\nalgos=['shac']\nepochs=5\nhorizons=[8]\nnum_envs=8\n"
        "[[sim_to_sim]]\ntask='ant'\ntrain_backend='newton'\neval_backend='mujoco_warp'\nhorizon=8\n"
    )
    with pytest.raises(RunError, match="matches runs of two"):
        plan(load_spec(spec_file=str(_write(tmp_path, grid)))[0], tmp_path)
    for choice, epochs in (("epochs=5\n", 5), ("train_num_envs=4\n", 3)):
        data, _ = load_spec(spec_file=str(_write(tmp_path, grid + choice)))
        jobs = plan(data, tmp_path)
        trains = {j.label: j.run for j in jobs if j.kind == "train"}
        sources = {trains[j.after[0]] for j in jobs if j.kind == "sim_to_sim"}
        assert [r.epochs for r in sources] == [epochs]


def test_a_train_block_builds_one_backend_with_options(tmp_path):
    text = (
        "[suite]\nname='x'\n[[train]]\nbackends=['newton','mujoco_warp']\ntasks=['ant']\nalgos=['shac']\n"
        "epochs=1\nnum_envs=4\n[train.backend_options.mujoco_warp]\nfd_scheme='one_sided'\n"
    )
    runs = {j.run.backend: j.run for j in plan(load_spec(spec_file=str(_write(tmp_path, text)))[0], tmp_path)}
    assert runs["mujoco_warp"].identity()["backend_options"] == {"fd_scheme": "one_sided"}
    assert runs["mujoco_warp"].identity()["gradients"]["mujoco_warp"]["fd_scheme"] == "one_sided"
    assert "backend_options" not in runs["newton"].identity()
    for bad, message in (
        ("[train.backend_options.go2]\nx=1\n", "not one of the block's backends"),
        ("[train.backend_options.newton]\nsolver=[1]\n", "a string or a number"),
    ):
        text = "[suite]\nname='x'\n[[train]]\nbackends=['newton']\ntasks=['ant']\nalgos=['shac']\nepochs=1\n"
        with pytest.raises(RunError, match=message):
            plan(load_spec(spec_file=str(_write(tmp_path, text + bad)))[0], tmp_path)


def test_bad_specs_fail_with_one_line(tmp_path):
    cases = {
        "[suite]\nname='x'\n[[train]]\nbackends=['newton']\ntasks=['ant']\nalgos=['shac']\nepoch=3\n": "unknown key",
        "[suite]\nname='x'\n[[train]]\nbackends=['nope']\ntasks=['ant']\nalgos=['shac']\nepochs=3\n": "unknown 'nope'",
        "[suite]\nname='x'\n[[train]]\nbackends=['newton']\ntasks=['ant']\nalgos=['ppo']\nepochs=3\n": "unknown 'ppo'",
        "[suite]\nname='x'\n[[check]]\nkind='lint'\nbackends=['newton']\ntasks=['ant']\n": "unknown 'lint'",
        "[suite]\nname='x'\n[[landscape]]\ntask='ant'\nbackend='newton'\n": "selects no run",
        "[suite]\nname = \n": "not valid TOML",
        "[suite]\nname='x'\n[[train]]\nbackends=['newton']\ntasks=['ant']\nalgos=['shac']\nepochs=3\npreset='x'\n": (
            "unknown physics preset of ant 'x'"
        ),
    }
    for text, message in cases.items():
        with pytest.raises(RunError, match=message) as info:
            data, _ = load_spec(spec_file=str(_write(tmp_path, text)))
            plan(data, tmp_path)
        assert "\n" not in str(info.value)
    with pytest.raises(RunError, match="unknown profile"):
        load_spec(profile="nightly")
    out = subprocess.run(
        [sys.executable, "-m", "harness", "bench", "--spec", str(tmp_path / "missing.toml")],
        capture_output=True,
        text=True,
        env=_env(),
    )
    assert out.returncode == 2 and out.stderr.strip().count("\n") == 0 and "no such file" in out.stderr


def test_seed_major_order(tmp_path):
    """Wherever a long suite stops, every algorithm has as many finished seeds as the others."""
    data, _ = load_spec(spec_file=str(_write(tmp_path, POINTMASS_SPEC)))
    runs = [j.run for j in plan(data, tmp_path) if j.kind == "train"]
    assert [r.seed for r in runs] == sorted(r.seed for r in runs)
    assert [(r.algo, r.horizon) for r in runs[:4]] == [("shac", 4), ("shac-tdadpt", 4), ("shac", 8), ("shac-tdadpt", 8)]


# -- running: reuse and resume ----------------------------------------------------------------------


@POINTMASS
def test_finished_runs_are_reused_and_interrupted_ones_resumed(tmp_path):
    spec = _write(tmp_path, POINTMASS_SPEC.replace("seeds = [0, 1]", "seeds = [0]"))  # 4 runs
    store = tmp_path / "store"
    log = []

    class Stream:
        def write(self, text):
            log.append(text)

        def flush(self):
            pass

    assert run_suite(spec_file=str(spec), store=store, stream=Stream()) == 0
    text = "".join(log)
    assert "jobs 4/4 (runs 4/4; 0 running, 0 reused, 0 failed)" in text and "ETA" in text
    run_dirs = sorted((store / "pm" / "runs").iterdir())
    assert len(run_dirs) == 4
    stamps = {d.name: (d / "metrics.jsonl").stat().st_mtime_ns for d in run_dirs}
    assert (store / "pm" / "returns.md").is_file()

    # an interrupted run: its checkpoint says epoch 1 of 3 and it has no evaluation yet
    victim = run_dirs[0]
    config = json.loads((victim / "config.json").read_text())
    import torch

    payload = torch.load(victim / "checkpoint.pt", weights_only=False)
    payload["epoch"] = 1  # as if stopped after epoch 1: the suite must resume it, not start over
    torch.save(payload, victim / "checkpoint.pt")
    (victim / "eval.json").unlink()
    # a finished run whose checkpoints were not kept (a store committed to git): done, not retrained
    for name in ("checkpoint.pt", "checkpoint_init.pt"):
        (run_dirs[1] / name).unlink()

    log.clear()
    assert run_suite(spec_file=str(spec), store=store, stream=Stream()) == 0
    text = "".join(log)
    assert "3 reused" in text, text
    for d in run_dirs[1:]:
        assert (d / "metrics.jsonl").stat().st_mtime_ns == stamps[d.name], f"{d.name} was recomputed"
    resumed = json.loads((victim / "config.json").read_text())
    assert resumed["provenance"] == config["provenance"]  # the original command stays
    assert len(resumed["resumed"]) == 1  # resumed once, by the suite
    assert (victim / "eval.json").is_file()
    rows = [json.loads(line) for line in (victim / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [0, 1, 2]


def _finished_at(run: RunSpec, store: Path, epochs: int | None = None) -> Path:
    """A run folder as a suite leaves it once ``run`` trained ``epochs`` (default: all) and was evaluated,
    its checkpoints not kept (as in a store committed to git)."""
    from harness.suite.runner import _write_job_file

    job = train_job(run, store / "runs" / run.dirname)
    _write_job_file(job)
    done = run.epochs if epochs is None else epochs
    (job.run_dir / "metrics.jsonl").write_text("".join(json.dumps({"epoch": e}) + "\n" for e in range(done)))
    (job.run_dir / "eval.json").write_text(json.dumps(job.expect))
    return job.run_dir


def test_a_run_finished_on_another_device_is_reused_by_its_own_address(tmp_path):
    """A GPU session's finished run stands in for the same configuration planned on the CPU (its folder,
    so its provenance, is its own); an unfinished one does not, nor does one of another configuration."""
    data = load_spec(spec_file=str(_write(tmp_path, POINTMASS_SPEC)))[0]
    cpu = [j for j in plan(data, tmp_path) if j.kind == "train"]
    on_gpu, half_done, other_config = (dataclasses.replace(j.run, device="cuda") for j in cpu[:3])
    gpu_dir = _finished_at(on_gpu, tmp_path)
    _finished_at(half_done, tmp_path, epochs=1)
    _finished_at(dataclasses.replace(other_config, epochs=other_config.epochs + 1), tmp_path)
    again = [j for j in plan(data, tmp_path) if j.kind == "train"]
    assert again[0].run_dir == gpu_dir and again[0].run.device == "cuda" and again[0].is_done()
    assert [j.run_dir for j in again[1:]] == [j.run_dir for j in cpu[1:]]  # the CPU's own addresses
    assert not any(j.is_done() for j in again[1:])
    # the run finished on the CPU too: its own address wins
    cpu_dir = _finished_at(cpu[0].run, tmp_path)
    assert next(j for j in plan(data, tmp_path) if j.kind == "train").run_dir == cpu_dir


def test_a_resumed_runs_cost_counts_only_the_epochs_it_has_left(tmp_path):
    data = load_spec(spec_file=str(_write(tmp_path, POINTMASS_SPEC)))[0]
    fresh = {j.label: j.estimate_s for j in plan(data, tmp_path) if j.kind == "train"}
    label = sorted(fresh)[0]
    metrics = tmp_path / "runs" / label / "metrics.jsonl"
    metrics.parent.mkdir(parents=True)
    metrics.write_text("".join(json.dumps({"epoch": e}) + "\n" for e in range(2)))  # 2 of its 3 epochs logged
    again = {j.label: j.estimate_s for j in plan(data, tmp_path) if j.kind == "train"}
    assert again[label] < fresh[label]
    assert {k: v for k, v in again.items() if k != label} == {k: v for k, v in fresh.items() if k != label}
    metrics.write_text(metrics.read_text() + json.dumps({"epoch": 2}) + "\n")  # trained out: only evaluation left
    finished = next(j.estimate_s for j in plan(data, tmp_path) if j.label == label)
    assert finished < again[label] and fresh[label] - again[label] == pytest.approx(2.0 * (again[label] - finished))


# -- the newcomer's path ----------------------------------------------------------------------------

NEWCOMER_SPEC = """
[suite]
name = "tiny"
jobs = 2

[eval]
seeds = 1
num_envs = 4
max_steps = 30

[[train]]
backends = ["newton"]
tasks = ["ant"]
algos = ["shac", "shac-tdadpt"]
seeds = [0]
horizons = [4]
epochs = 2
num_envs = 4

[[check]]
kind = "gradcheck"
backends = ["newton"]
tasks = ["ant"]
args = ["--steps", "2"]

[[check]]
kind = "throughput"
backends = ["newton"]
tasks = ["ant"]
args = ["--num-envs", "4", "--horizon", "4", "--windows", "3"]

[[landscape]]
task = "ant"
backend = "newton"
algos = ["shac-tdadpt"]
horizon = 4
grid = 3
span = 0.5
num_envs = 4
"""


def test_newcomer_tiny_spec_end_to_end(tmp_path):
    """One backend, one task, two algorithms, 2 epochs: checks, training, evaluation, a landscape,
    then every table and plot, through the command line a user types."""
    spec = _write(tmp_path, NEWCOMER_SPEC)
    store = tmp_path / "store"
    out = subprocess.run(
        [sys.executable, "-m", "harness", "bench", "--spec", str(spec), "--store", str(store)],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=900,
    )
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert "jobs 5/5 (runs 2/2; 0 running, 0 reused, 0 failed)" in out.stdout
    tables = store / "tiny"
    closing = out.stdout[out.stdout.index("[bench tiny] wrote") :]
    for name in ("returns", "grad_variance_vs_h", "wall_time", "throughput", "landscape", "checks"):
        assert (tables / f"{name}.md").is_file(), name
        assert (tables / f"{name}.csv").is_file(), name
        assert str(tables / f"{name}.md") in closing  # the closing lines name the files written
    commit = json.loads((tables / "jobs.json").read_text())["provenance"]["git_commit"]
    assert commit and commit in (tables / "returns.md").read_text()
    for png in ("learning_curves_steps.png", "grad_variance_vs_h.png", "wall_time.png", "throughput.png"):
        assert (tables / png).stat().st_size > 1000, png
    returns = (tables / "returns.md").read_text()
    assert "shac-tdadpt" in returns and "shac" in returns
    runs = sorted((store / "tiny" / "runs").iterdir())
    landscape = json.loads(next(d for d in runs if "tdadpt" in d.name).joinpath("landscape.json").read_text())
    assert len(landscape["losses"]["td_lambda"]) == 3
    # a second call reuses everything
    again = subprocess.run(
        [sys.executable, "-m", "harness", "bench", "--spec", str(spec), "--store", str(store)],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=300,
    )
    assert again.returncode == 0 and "jobs 5/5 (runs 2/2; 0 running, 5 reused, 0 failed)" in again.stdout, again.stdout[
        -2000:
    ]


@POINTMASS
def test_ctrl_c_stops_the_suite_resumably(tmp_path):
    """SIGINT to the suite: its running jobs checkpoint and stop, it exits 130, and the same command then
    finishes every run from where it stopped (no epoch lost or run twice)."""
    import signal
    import time

    spec = _write(
        tmp_path, POINTMASS_SPEC.replace("epochs = 3", "epochs = 60").replace("seeds = [0, 1]", "seeds = [0]")
    )
    store = tmp_path / "store"
    command = [sys.executable, "-m", "harness", "bench", "--spec", str(spec), "--store", str(store)]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
    deadline = time.time() + 300
    while time.time() < deadline:
        metrics = list((store / "pm" / "runs").glob("*/metrics.jsonl")) if (store / "pm" / "runs").exists() else []
        if metrics and max(len(m.read_text().splitlines()) for m in metrics) >= 3:
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, out[-2000:] + err[-2000:]
    assert "run the same command again" in err
    stopped = [d for d in (store / "pm" / "runs").iterdir() if not (d / "eval.json").exists()]
    assert stopped, "every run finished before the signal: the test did not interrupt anything"
    again = subprocess.run(command, capture_output=True, text=True, env=_env(), timeout=600)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-2000:]
    for run in (store / "pm" / "runs").iterdir():
        rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
        assert [r["epoch"] for r in rows] == list(range(60)), run.name
        assert (run / "eval.json").is_file()


@POINTMASS
@pytest.mark.parametrize("signum", ["SIGINT", "SIGTERM"])
def test_a_signal_during_the_evaluation_releases_the_runs_claim(tmp_path, signum):
    """A run stopped while it evaluates exits 128 + signal and leaves no claim behind (another worker then
    takes the run at once, even from another machine, instead of waiting for the claim to go stale),
    no evaluation file and no half-written file."""
    import signal

    from harness.suite.runner import _write_job_file

    spec = POINTMASS_SPEC.replace("seeds = [0, 1]", "seeds = [0]").replace("horizons = [4, 8]", "horizons = [4]")
    spec = spec.replace('algos = ["shac", "shac-tdadpt"]', 'algos = ["shac"]').replace("seeds = 1", "seeds = 1000")
    jobs = plan(load_spec(spec_file=str(_write(tmp_path, spec)))[0], tmp_path / "store")
    (job,) = [j for j in jobs if j.kind == "train"]
    _write_job_file(job)
    command = [sys.executable, "-m", "harness", "bench-run", str(job.run_dir)]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
    for line in proc.stdout:  # the evaluation reports each seed it finished
        if line.startswith("  eval "):
            break
    proc.send_signal(getattr(signal, signum))
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + getattr(signal, signum), out[-2000:] + err[-2000:]
    assert not (job.run_dir / "eval.json").exists(), "the evaluation finished before the signal: nothing was tested"
    assert not list(job.run_dir.glob(".claim.*")), "the stopped run kept its claim"
    assert not list(job.run_dir.glob(".*.tmp")), "a half-written file was left behind"


def test_a_killed_suite_takes_its_jobs_down_resumably(tmp_path):
    """SIGKILL to the suite, which cannot pass anything on: its jobs still stop at an epoch boundary with a
    checkpoint instead of training on unseen, and the same command then finishes every run exactly once."""
    import signal
    import time

    spec = _write(
        tmp_path,
        POINTMASS_SPEC.replace("epochs = 3", "epochs = 100")
        .replace("seeds = [0, 1]", "seeds = [0]")
        .replace('algos = ["shac", "shac-tdadpt"]', 'algos = ["shac"]')
        .replace("horizons = [4, 8]", "horizons = [8]"),
    )
    store = tmp_path / "store"
    runs = store / "pm" / "runs"
    command = [sys.executable, "-m", "harness", "bench", "--spec", str(spec), "--store", str(store)]
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_env())
    deadline = time.time() + 300
    while time.time() < deadline:
        metrics = list(runs.glob("*/metrics.jsonl")) if runs.exists() else []
        if metrics and max(len(m.read_text().splitlines()) for m in metrics) >= 3:
            break
        time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    deadline = time.time() + 120
    while any(runs.glob("*/.claim.*")) and time.time() < deadline:  # a job releases its claim as it exits
        time.sleep(0.2)
    assert not any(runs.glob("*/.claim.*")), "a job of the killed suite is still running"
    stopped = [d for d in runs.iterdir() if not (d / "eval.json").exists()]
    assert stopped, "no job stopped with the suite: it trained on as an orphan or finished before the kill"
    assert all((d / "checkpoint.pt").is_file() for d in stopped)
    # one stop request, answered at the epoch boundary: never escalated to "stop now" by a repeat
    for log in (store / "pm" / "logs").glob("*.log"):
        text = log.read_text()
        assert text.count("finishing this epoch") == 1 and "stopped now" not in text, text[-2000:]
    again = subprocess.run(command, capture_output=True, text=True, env=_env(), timeout=600)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-2000:]
    for run in runs.iterdir():
        rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
        assert [r["epoch"] for r in rows] == list(range(100)), run.name
        assert (run / "eval.json").is_file()


def test_results_show_a_spec_inside_the_repository_by_its_relative_path(tmp_path, monkeypatch):
    from harness.results import harness_command, shown_path

    profile = Path(__file__).resolve().parents[1] / "harness" / "profiles" / "standard.toml"
    monkeypatch.chdir(tmp_path)
    assert shown_path(profile) == str(Path("harness") / "profiles" / "standard.toml")
    assert shown_path(tmp_path / "mine.toml") == "mine.toml"
    elsewhere = tmp_path.parent / "elsewhere.toml"
    assert shown_path(elsewhere) == str(elsewhere)
    # a recorded command shows its paths the same way; other words stay as they were
    out = tmp_path / "store" / "checks" / "gradcheck.json"
    recorded = harness_command(["gradcheck", "--task", "ant", "--out", str(out), "--spec", str(elsewhere)])
    shown_out = Path("store", "checks", "gradcheck.json")
    assert recorded == f"python -m harness gradcheck --task ant --out {shown_out} --spec {elsewhere}"


@POINTMASS
def test_a_killed_report_phase_leaves_the_previous_set_whole(tmp_path):
    """A report phase killed while it writes leaves the tables, plots, index.md and jobs.json of the
    report before it, byte for byte (the new set is staged aside); the next report discards the stage
    and puts a whole new set in place."""
    import signal
    import time

    spec = _write(
        tmp_path, POINTMASS_SPEC.replace("seeds = [0, 1]", "seeds = [0]").replace("horizons = [4, 8]", "horizons = [4]")
    )
    store = tmp_path / "store"
    command = [sys.executable, "-m", "harness", "bench", "--spec", str(spec), "--store", str(store)]
    first = subprocess.run(command, capture_output=True, text=True, env=_env(), timeout=600)
    assert first.returncode == 0, first.stdout[-2000:] + first.stderr[-2000:]
    folder = store / "pm"
    before = {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}
    assert {"index.md", "returns.md", "returns.csv", "jobs.json"} <= set(before)
    slow = _env() | {"DIFFSIM_BENCH_TEST_WRITE_DELAY": "1"}  # every staged file stays half-written a second
    proc = subprocess.Popen(
        [*command, "--report-only"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=slow
    )
    stage = folder / f".report-staging-{proc.pid}"
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if stage.is_dir() and len(list(stage.iterdir())) >= 3:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, out[-2000:] + err[-2000:]
    assert {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()} == before
    again = subprocess.run([*command, "--report-only"], capture_output=True, text=True, env=_env(), timeout=600)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-2000:]
    assert not stage.exists() and set(before) <= {p.name for p in folder.iterdir() if p.is_file()}


def test_a_swap_cut_short_is_finished_by_the_next_report(tmp_path):
    """A writer killed outright between the moves of a swap leaves its journal; recovering finishes the
    moves and removals, so the folder holds the new set alone. A dead writer's stage without a journal
    is an unfinished report: discarded, the set in place stands. A live writer's stage is left alone."""
    from harness.report import swap

    out = tmp_path / "report"
    out.mkdir()
    for name in ("a.md", "b.md", "old_plot.png"):
        (out / name).write_text("old " + name)
    (out / swap.SET).write_text(json.dumps(["a.md", "b.md", "old_plot.png"]))
    dead = "999999999"  # no such process
    staged = out / f"{swap.STAGE}{dead}"
    staged.mkdir()
    for name in ("a.md", "b.md"):
        (staged / name).write_text("new " + name)
    # as a kill after the journal and the first move leaves it
    (out / f"{swap.JOURNAL}{dead}.json").write_text(json.dumps({"move": ["a.md", "b.md"], "remove": ["old_plot.png"]}))
    (staged / "a.md").replace(out / "a.md")
    live = out / f"{swap.STAGE}{os.getppid()}"  # a report being written by a process that runs
    live.mkdir()
    assert "finished the swap" in swap.recover(out)
    assert {p.name: p.read_text() for p in out.iterdir() if not p.name.startswith(".")} == {
        "a.md": "new a.md",
        "b.md": "new b.md",
    }
    assert not staged.exists() and not list(out.glob(f"{swap.JOURNAL}*")) and live.is_dir()
    staged.mkdir()
    (staged / "a.md").write_text("half")
    assert "discarded" in swap.recover(out) and (out / "a.md").read_text() == "new a.md" and not staged.exists()


_KILLED_IN_THE_SWAP = """
import os, signal, sys
from pathlib import Path
from harness.report import swap
out = Path(sys.argv[1])
staged = swap.stage(out)
for name in ("a.md", "b.csv", "c.png"):
    (staged / name).write_text("new " + name)
real, calls = os.replace, []
def replace_then_die(src, dst):
    real(src, dst)
    calls.append(dst)
    if len(calls) == 3:  # the journal, a.md, b.csv: then SIGKILL, which no handler sees
        os.kill(os.getpid(), signal.SIGKILL)
os.replace = replace_then_die
swap.commit(out)
"""


def test_a_report_killed_inside_its_swap_is_made_whole_by_the_next(tmp_path):
    """A real SIGKILL between two moves of the swap (no signal handler runs): the folder then holds a
    mix, the journal names the rest, and the next report's recovery leaves the new set alone."""
    import signal

    from harness.report import swap

    out = tmp_path / "report"
    out.mkdir()
    for name in ("a.md", "b.csv", "c.png", "gone.png"):
        (out / name).write_text("old " + name)
    (out / swap.SET).write_text(json.dumps(["a.md", "b.csv", "c.png", "gone.png"]))
    proc = subprocess.run([sys.executable, "-c", _KILLED_IN_THE_SWAP, str(out)], capture_output=True, text=True)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    files = {p.name: p.read_text() for p in out.iterdir() if p.is_file() and not p.name.startswith(".")}
    assert files["a.md"] == "new a.md" and files["c.png"] == "old c.png"  # killed mid-swap: a mix
    assert list(out.glob(f"{swap.JOURNAL}*.json"))
    assert "finished the swap" in swap.recover(out)
    files = {p.name: p.read_text() for p in out.iterdir() if p.is_file() and not p.name.startswith(".")}
    assert files == {"a.md": "new a.md", "b.csv": "new b.csv", "c.png": "new c.png"}
    assert not list(out.glob(f"{swap.JOURNAL}*")) and not list(out.glob(f"{swap.STAGE}*"))
