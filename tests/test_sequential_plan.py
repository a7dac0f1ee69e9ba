"""A `sequential = true` [[train]] block: the suite plans the seeds the pre-registered group-sequential
design wants (harness/report/sequential.py, harness.report.claims.seeds_wanted), never fewer than the runs
already started, and the key changes no run's address. The runs here are folders written by hand (no
training): what a finished, evaluated run leaves for the design to read."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from harness.results import RunError
from harness.suite.bench import RunSpec, load_spec, plan, train_job

BLOCK = """
[[train]]
backends = ["newton"]
tasks = ["ant"]
algos = ["shac", "shac-tdfixed"]
seeds = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
horizons = [4]
epochs = 2
num_envs = 4
{extra}
"""
SPEC = '[suite]\nname = "seq"\norder = "block"\n[eval]\nseeds = 1\nnum_envs = 4\n' + BLOCK

# five seed pairs whose claim (SHAC-TDFixed +25% over SHAC) the 5-pair look leaves undecided and not futile
BASE = np.array([1000.0, 1200.0, 800.0, 1100.0, 900.0])
UNDECIDED_VARIANT = BASE + np.array([150.0, -50.0, 350.0, 100.0, 200.0])
# ... and five that decide it (three times the base, a little noise): confirmed at the first look
DECIDED_VARIANT = 3.0 * BASE * (1.0 + 1e-3 * np.array([1.0, -2.0, 0.5, -1.0, 2.0]))


def _spec(tmp_path: Path, extra: str = "sequential = true", spec: str = SPEC, text: str | None = None) -> dict:
    """The spec ``spec`` with ``extra`` in its block, or ``text`` as it is, loaded (validated)."""
    path = tmp_path / "spec.toml"
    path.write_text(spec.format(extra=extra) if text is None else text)
    return load_spec(spec_file=str(path))[0]


def _plan(data: dict, store: Path) -> tuple[dict[str, list[int]], str]:
    """The planned seeds of each algorithm, and the lines the planner said."""
    said = io.StringIO()
    seeds: dict[str, list[int]] = {}
    for job in plan(data, store, stream=said):
        if job.kind == "train":
            seeds.setdefault(job.run.algo, []).append(job.run.seed)
    return seeds, said.getvalue()


def _runs(data: dict, store: Path) -> dict[tuple[str, int], RunSpec]:
    """Every run of the spec's (only) block, all ten seeds, by (algo, seed): a plan with the block not
    sequential."""
    whole = {**data, "train": [{k: v for k, v in block.items() if k != "sequential"} for block in data["train"]]}
    return {(j.run.algo, j.run.seed): j.run for j in plan(whole, store / "elsewhere") if j.kind == "train"}


def _evaluated(run: RunSpec, store: Path, final_return: float, velocity: float | None = None) -> Path:
    """The folder a finished, evaluated run leaves (its checkpoints not kept): job.json, config.json, every
    epoch's metrics and an eval.json with the final policy's mean return (and ``velocity``, its mean forward
    velocity, when given)."""
    from harness.suite.runner import _write_job_file

    job = train_job(run, store / "runs" / run.dirname)
    _write_job_file(job)
    identity = run.identity()
    config = {k: identity[k] for k in ("task", "backend", "seed", "device", "epochs", "algo")}
    (job.run_dir / "config.json").write_text(json.dumps(config))
    rows = [{"epoch": e, "env_steps": (e + 1) * run.num_envs * run.horizon} for e in range(run.epochs)]
    (job.run_dir / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    payload = {**job.expect, "initial": {"mean_return": 10.0}, "final": {"mean_return": float(final_return)}}
    if velocity is not None:
        payload["initial"]["mean_forward_velocity"] = 0.0
        payload["final"]["mean_forward_velocity"] = float(velocity)
    (job.run_dir / "eval.json").write_text(json.dumps(payload))
    assert job.is_done()
    return job.run_dir


def _five_pairs(data: dict, store: Path, variant: np.ndarray) -> str:
    """Seeds 0-4 of SHAC (BASE) and SHAC-TDFixed (``variant``) finished and evaluated; the design's state of
    their claim, as the report's claims table gives it."""
    from harness.report.claims import claims_table
    from harness.report.records import load_run

    runs = _runs(data, store)
    dirs = [_evaluated(runs["shac", s], store, BASE[s]) for s in range(5)]
    dirs += [_evaluated(runs["shac-tdfixed", s], store, variant[s]) for s in range(5)]
    table = claims_table([load_run(d) for d in dirs])
    (row,) = [row for _, row in table.iterrows() if row["algo"] == "shac-tdfixed"]
    assert row["pairs"] == 5
    return row["design"]


def test_a_sequential_block_plans_the_first_look_when_no_run_exists(tmp_path):
    seeds, said = _plan(_spec(tmp_path), tmp_path / "store")
    assert seeds == {"shac": [0, 1, 2, 3, 4], "shac-tdfixed": [0, 1, 2, 3, 4]}
    where = "(newton, N 4, h 4, 2 epochs)"
    assert f"sequential: ant shac-tdfixed vs shac {where}: no evaluated pair yet -> 5 seeds" in said
    assert f"sequential: [[train]] #1 ant {where} plans shac 5, shac-tdfixed 5 of its 10 seeds" in said


def test_a_claim_that_continues_plans_ten_seeds_of_both_its_algorithms(tmp_path):
    data, store = _spec(tmp_path), tmp_path / "store"
    assert _five_pairs(data, store, UNDECIDED_VARIANT) == "continue"
    seeds, said = _plan(data, store)
    assert seeds == {"shac": list(range(10)), "shac-tdfixed": list(range(10))}
    assert "shac-tdfixed vs shac (newton, N 4, h 4, 2 epochs): 5 pairs, undecided, continue -> 10 seeds" in said


def test_a_claim_decided_at_the_first_look_plans_no_seed_beyond_it(tmp_path):
    data, store = _spec(tmp_path), tmp_path / "store"
    assert _five_pairs(data, store, DECIDED_VARIANT) == "decided"
    seeds, said = _plan(data, store)
    assert seeds == {"shac": [0, 1, 2, 3, 4], "shac-tdfixed": [0, 1, 2, 3, 4]}
    assert "5 pairs, confirmed (larger than claimed), decided -> 5 seeds" in said


@pytest.mark.parametrize(
    ("velocities", "said", "planned"),
    [
        (None, "no evaluated seed yet -> 5 seeds", 5),
        ([0.0, 1.0, 0.1, 0.9, 0.5], "5 seeds, undecided, continue -> 10 seeds", 10),
        ([0.0, 0.01, -0.02, 0.0, 0.01], "5 seeds, does not move forward, decided -> 5 seeds", 5),
    ],
)
def test_the_papers_locomotion_claim_plans_seeds_as_its_looks_ask(tmp_path, velocities, said, planned):
    """The Go2's SHAC alone (no paired claim in the block): the paper says it does not move forward, and
    the design plans seeds for that verdict's looks (docs/statistics.md)."""
    text = SPEC.format(extra="sequential = true").replace('tasks = ["ant"]', 'tasks = ["go2"]')
    data, store = _spec(tmp_path, text=text.replace('algos = ["shac", "shac-tdfixed"]', 'algos = ["shac"]')), tmp_path
    if velocities is not None:
        runs = _runs(data, store)
        for s, velocity in enumerate(velocities):
            _evaluated(runs["shac", s], store / "store", 100.0, velocity)
    seeds, lines = _plan(data, store / "store")
    assert seeds == {"shac": list(range(planned))}
    assert f"sequential: go2 shac moves forward? (newton, N 4, h 4, 2 epochs): {said}" in lines


def test_a_started_run_beyond_what_the_design_wants_stays_planned(tmp_path):
    """A run the design no longer wants but that has begun (in flight: its job.json written, or stopped
    with metrics) is never orphaned: it stays in the plan, and resumes."""
    from harness.suite.runner import _write_job_file

    data, store = _spec(tmp_path), tmp_path / "store"
    assert _five_pairs(data, store, DECIDED_VARIANT) == "decided"
    runs = _runs(data, store)
    _write_job_file(train_job(runs["shac", 7], store / "runs" / runs["shac", 7].dirname))  # in flight
    stopped = store / "runs" / runs["shac-tdfixed", 5].dirname
    stopped.mkdir(parents=True)
    (stopped / "metrics.jsonl").write_text(json.dumps({"epoch": 0}) + "\n")  # stopped after an epoch
    seeds, said = _plan(data, store)
    assert seeds == {"shac": [0, 1, 2, 3, 4, 7], "shac-tdfixed": [0, 1, 2, 3, 4, 5]}
    assert "plans shac 6, shac-tdfixed 6 of its 10 seeds; 2 started run(s) beyond that kept" in said


def test_the_design_reads_only_runs_of_the_blocks_hyperparameters(tmp_path):
    """An ablation's runs (other hyperparameters, their own addresses) are no seeds of the algorithm's claims,
    though the report's groups would pool them: pairs that continue there leave the block at its first look."""
    ablation = BLOCK.replace("seeds = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]", "seeds = [0, 1, 2, 3, 4]")
    text = SPEC.format(extra="sequential = true") + ablation.format(extra="hyperparameters = { actor_lr = 1e-3 }")
    data, store = _spec(tmp_path, text=text), tmp_path / "store"
    ablated = {
        (j.run.algo, j.run.seed): j.run for j in plan(data, store, stream=io.StringIO()) if j.run.hyperparameters
    }
    for s in range(5):
        _evaluated(ablated["shac", s], store, BASE[s])
        _evaluated(ablated["shac-tdfixed", s], store, UNDECIDED_VARIANT[s])
    own = [j.run for j in plan(data, store, stream=io.StringIO()) if j.kind == "train" and not j.run.hyperparameters]
    assert sorted({r.seed for r in own}) == [0, 1, 2, 3, 4] and len(own) == 10


def test_sequential_must_be_true_or_false(tmp_path):
    with pytest.raises(RunError) as info:
        _spec(tmp_path, 'sequential = "yes"')
    assert str(info.value) == "[[train]] #1 sequential: expected true or false, got 'yes'"
    with pytest.raises(RunError, match="unknown key"):  # a block's key, not a task's
        _spec(tmp_path, "[train.per_task.ant]\nsequential = true")


def test_the_key_changes_no_runs_address(tmp_path):
    """A run's folder is the same whether its block is sequential or not, and a sequential block beside
    another changes none of the other's runs."""
    store = tmp_path / "store"
    five = SPEC.replace("seeds = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]", "seeds = [0, 1, 2, 3, 4]")
    dirs = {}
    for extra in ("", "sequential = false", "sequential = true"):
        dirs[extra] = [j.run_dir for j in plan(_spec(tmp_path, extra, five), store, stream=io.StringIO())]
    assert dirs[""] == dirs["sequential = false"] == dirs["sequential = true"] and len(dirs[""]) == 10
    go2 = BLOCK.replace('"ant"', '"go2"')
    planned = {}
    for extra in ("", "sequential = true"):  # the Go2's block sequential or not; the Ant's never
        text = SPEC.format(extra="") + go2.format(extra=extra)
        ant = [j.run_dir for j in plan(_spec(tmp_path, text=text), store, stream=io.StringIO()) if j.run.task == "ant"]
        planned[extra] = ant
    assert planned[""] == planned["sequential = true"] and len(planned[""]) == 20


def test_the_protocol_keeps_every_committed_run_at_its_address(tmp_path):
    """The protocol profile plans every run folder committed in results/bench/protocol/runs under its own
    name: on an empty store (where its sequential blocks want their first 5 seeds) the first group's,
    and on the committed store (where the design reads the finished seeds and may add more) every one."""
    committed = Path(__file__).resolve().parents[1] / "results" / "bench" / "protocol" / "runs"
    if not committed.is_dir():
        pytest.skip("no committed protocol store")
    data, _ = load_spec(profile="protocol")
    fresh = {j.run_dir.name for j in plan(data, tmp_path, stream=io.StringIO()) if j.kind == "train"}
    first_group = {
        d.name
        for d in committed.iterdir()
        if (d / "job.json").is_file() and int(d.name.split("_s")[-1].split("_")[0]) < 5
    }
    assert first_group and first_group <= fresh, sorted(first_group - fresh)
    before = sorted(p.relative_to(committed) for p in committed.rglob("*"))
    planned = {j.run_dir.name for j in plan(data, committed.parent, stream=io.StringIO()) if j.kind == "train"}
    assert sorted(p.relative_to(committed) for p in committed.rglob("*")) == before  # planning writes nothing
    folders = {d.name for d in committed.iterdir() if (d / "job.json").is_file()}
    assert folders and folders <= planned, sorted(folders - planned)


def test_analyses_of_final_policies_skip_runs_whose_policy_was_not_kept(tmp_path):
    """[[landscape]] and [[step_gain]] plan one job per selected run, after its training; a finished run
    without its final checkpoint is named once and skipped; an ablation's runs are selected only by a block
    naming their hyperparameters."""
    ablation = BLOCK.replace("seeds = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]", "seeds = [0, 1]")
    analyses = (
        '\n[[landscape]]\ntask = "ant"\nbackend = "newton"\nalgos = ["shac", "shac-tdfixed"]\ngrid = 8\n'
        '\n[[step_gain]]\ntask = "ant"\nbackend = "newton"\nalgos = ["shac-tdfixed"]\nstates = 16\n'
        '\n[[step_gain]]\ntask = "ant"\nbackend = "newton"\nalgos = ["shac"]\nseeds = [1]\n'
        "hyperparameters = { actor_lr = 1e-3 }\n"
    )
    text = SPEC.format(extra="") + ablation.format(extra="hyperparameters = { actor_lr = 1e-3 }") + analyses
    data, store = _spec(tmp_path, text=text), tmp_path / "store"
    (first,) = [
        j.run
        for j in plan(data, store, stream=io.StringIO())
        if j.kind == "train" and (j.run.algo, j.run.seed) == ("shac", 0) and not j.run.hyperparameters
    ]
    lost = _evaluated(first, store, 1000.0)  # finished, its checkpoint not kept
    said = io.StringIO()
    jobs = plan(data, store, stream=said)
    ablated = {j.run_dir for j in jobs if j.kind == "train" and j.run.hyperparameters}
    landscapes = [j.output.parent for j in jobs if j.kind == "landscape"]
    gains = {j.output.parent: j for j in jobs if j.kind == "step_gain"}
    # the own block's 20 runs less the one whose policy is lost; none of the ablation's
    assert len(landscapes) == 19 and not set(landscapes) & (ablated | {lost})
    assert "[[landscape]] #1: skips 1 finished runs whose final policy was not kept: shac s0" in said.getvalue()
    own = [j for run_dir, j in gains.items() if run_dir not in ablated]
    assert len(own) == 10 and all(j.expect == {"states": 16, "stride": 8, "num_envs": 4} for j in own)
    (theirs,) = [j for run_dir, j in gains.items() if run_dir in ablated]
    assert theirs.expect == {"states": 256, "stride": 8, "num_envs": 4} and "_s1_" in theirs.output.parent.name
    # a lost policy analysed before it was lost keeps its analysis job (done), and is not named as skipped
    (lost / "landscape.json").write_text("{}")
    said = io.StringIO()
    jobs = plan(data, store, stream=said)
    assert lost in {j.output.parent for j in jobs if j.kind == "landscape"}
    assert "[[landscape]] #1: skips" not in said.getvalue()
    assert all(j.after == [run_dir.name] and j.output.name == "step_gain.json" for run_dir, j in gains.items())
