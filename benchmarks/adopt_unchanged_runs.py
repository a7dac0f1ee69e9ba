"""Carry finished runs whose physics did not change into a suite store whose run addresses now
include the physics record, after proving each one reproduces.

Run addresses gained the task's physics record (preset, constants, engine settings), so every run
made before that has a new address, including runs whose physics is exactly what the default preset
gives today. Re-training those costs core-hours and changes nothing; adopting them on trust would be
a guess. This script adopts a run only on evidence: it trains the run's first epoch again with
today's code (same task, backend, seed, hyperparameters) and compares what that epoch logs before
any update has acted on it: the actor loss (a whole h-step rollout of the initial policy through
the physics), its gradient's norm and variance, and the critic loss. The code between the two
differs in float32 summation order (captured graphs, fused checks), so they are not bit-identical.
The tolerance is measured, not chosen: ``--control`` replays runs of a task whose physics did change
(the Ant: semi-implicit then, Featherstone now), and a run is adopted only if each statistic's
relative difference is ``--margin`` times smaller than the smallest difference the controls show in
it (the least a real physics change moved that statistic). An adopted run is copied to its new
address, its config.json gains today's physics record and an ``adopted`` entry (old address, the
evidence, the command), and every run checked is listed in ``STORE/adopted.json``.

    PYTHONPATH=. python benchmarks/adopt_unchanged_runs.py --profile standard --old OLD_STORE/standard \\
        --store results/bench --tasks go2 soft_jumper --backend newton --control ant
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

from algorithms.config import AlgoConfig
from harness.results import provenance, write_json
from harness.run.train import train
from harness.suite import bench, runner

COMPARED = ("actor_loss", "actor_grad_norm", "actor_grad_var", "critic_loss")


def first_epoch(path: Path) -> dict:
    for line in path.read_text().splitlines():
        if line.strip() and json.loads(line).get("epoch") == 0:
            return json.loads(line)
    raise ValueError(f"{path}: no epoch 0")


def replay_difference(old_dir: Path, config: dict) -> dict:
    """Train the old run's first epoch with today's code; the relative difference of each statistic."""
    with tempfile.TemporaryDirectory() as tmp:
        fresh = Path(tmp) / "replay"
        train(
            fresh,
            config["task"],
            config["backend"],
            AlgoConfig.from_dict(config["algo"]),
            1,
            seed=config["seed"],
            device=config["device"],
            stream=open("/dev/null", "w"),
        )
        new = first_epoch(fresh / "metrics.jsonl")
    old = first_epoch(old_dir / "metrics.jsonl")
    return {f: abs(new[f] - old[f]) / max(abs(old[f]), 1e-12) for f in COMPARED}


def _fmt(diff: dict) -> str:
    return ", ".join(f"{k} {v:.1e}" for k, v in diff.items())


def old_run_dir(old: Path, job: bench.Job) -> Path:
    """Where the run was addressed before run addresses held the physics record."""
    r = job.run
    before = {k: v for k, v in r.identity().items() if k != "physics"}
    return old / "runs" / f"{r.task}_{r.backend}_{r.algo}_h{r.horizon}_s{r.seed}_{bench._hash(before)}"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--profile", required=True)
    p.add_argument("--old", required=True, type=Path, help="the old store's suite folder (holding runs/)")
    p.add_argument("--store", default=Path("results/bench"), type=Path)
    p.add_argument("--tasks", nargs="+", required=True)
    p.add_argument("--backend", required=True)
    p.add_argument("--control", nargs="+", required=True, help="tasks whose physics changed (negative controls)")
    p.add_argument("--control-runs", type=int, default=3, help="runs of each control task replayed")
    p.add_argument("--margin", type=float, default=10.0, help="how much closer than any control an adopted run is")
    args = p.parse_args(argv)

    data, _ = bench.load_spec(args.profile)
    store = args.store / data["suite"]["name"]
    trains = [j for j in bench.plan(data, store) if j.kind == "train" and j.run.backend == args.backend]
    report = []
    for task in args.control:
        for job in [j for j in trains if j.run.task == task][: args.control_runs]:
            old_dir = old_run_dir(args.old, job)
            diff = replay_difference(old_dir, json.loads((old_dir / "config.json").read_text()))
            report.append({"run": old_dir.name, "control": True, "rel_diff": diff})
            print(f"control {old_dir.name}: relative differences {_fmt(diff)}", flush=True)
    tolerance = {f: min(e["rel_diff"][f] for e in report) / args.margin for f in COMPARED}
    print(f"adopting runs whose relative differences are below {_fmt(tolerance)}", flush=True)
    for job in [j for j in trains if j.run.task in args.tasks]:
        old_dir = old_run_dir(args.old, job)
        entry = {"run": job.run_dir.name, "old": old_dir.name}
        if job.is_done():
            entry.update(adopted=False, why="already done at its new address")
        elif not (old_dir / "config.json").is_file() or not (old_dir / "eval.json").is_file():
            entry.update(adopted=False, why="no finished old run with today's hyperparameters")
        else:
            config = json.loads((old_dir / "config.json").read_text())
            diff = replay_difference(old_dir, config)
            ok = all(diff[f] < tolerance[f] for f in COMPARED)
            why = "epoch 0 replayed: every statistic within tolerance" if ok else "epoch 0 replayed: outside tolerance"
            entry.update(adopted=ok, why=why, rel_diff=diff, old_commit=config["provenance"]["git_commit"])
            if ok:
                identity = job.run.identity()
                shutil.copytree(old_dir, job.run_dir)
                config["preset"] = identity["physics"]["preset"]
                config["physics_record"] = identity["physics"]
                config["adopted"] = {"from": old_dir.name, "evidence": why, "by": provenance(" ".join(sys.argv))}
                write_json(job.run_dir / "config.json", config)
                runner._write_job_file(job)
                if not job.is_done():
                    raise SystemExit(f"{job.run_dir}: adopted but not done; remove it")
        diffs = f"; {_fmt(entry['rel_diff'])}" if "rel_diff" in entry else ""
        print(f"{'adopted' if entry['adopted'] else 'kept out'}: {entry['run']} ({entry['why']}{diffs})", flush=True)
        report.append(entry)
    path = store / "adopted.json"
    previous = json.loads(path.read_text())["runs"] if path.is_file() else []
    write_json(path, {"tolerance": tolerance, "runs": previous + report, "provenance": provenance(" ".join(sys.argv))})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
