"""Carry finished runs whose physics did not change into a suite store whose run addresses now
include the physics record, after proving each one reproduces.

Run addresses gained the task's physics record (preset, constants, engine settings), so every run
made before that has a new address, including runs whose physics is exactly what the default preset
gives today. Re-training those costs core-hours and changes nothing; adopting them on trust would be
a guess. This script adopts a run only on evidence: it trains the run's first ``--replay-epochs``
epochs again with today's code (same task, backend, seed, hyperparameters) and requires the logged
actor loss, actor gradient norm and variance, critic loss and lambda of every replayed epoch to be
bit-identical to the old run's (same seed, same machine: identical runs). An adopted run is copied
to its new address, its config.json gains today's physics record and an ``adopted`` entry (old
address, commit, replayed epochs), and every run checked is listed in ``STORE/adopted.json``.

    python benchmarks/adopt_unchanged_runs.py --profile standard --old OLD_STORE/standard \\
        --store results/bench --tasks go2 soft_jumper --backend newton
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

from algorithms.config import AlgoConfig
from harness import bench
from harness.results import provenance, write_json
from harness.train import train

COMPARED = ("actor_loss", "actor_grad_norm", "actor_grad_var", "critic_loss", "lam")


def _rows(path: Path, count: int) -> list[dict]:
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return [r for r in rows if "epoch" in r][:count]


def _same(a, b) -> bool:
    return a == b or (a != a and b != b)  # NaN (no lambda loss) equals NaN


def replay_matches(old_dir: Path, config: dict, epochs: int) -> tuple[bool, str]:
    """Train ``epochs`` epochs of the old run with today's code; compare the logged statistics."""
    with tempfile.TemporaryDirectory() as tmp:
        fresh = Path(tmp) / "replay"
        train(
            fresh,
            config["task"],
            config["backend"],
            AlgoConfig.from_dict(config["algo"]),
            epochs,
            seed=config["seed"],
            device=config["device"],
            stream=open("/dev/null", "w"),
        )
        new, old = _rows(fresh / "metrics.jsonl", epochs), _rows(old_dir / "metrics.jsonl", epochs)
    if len(new) < epochs or len(old) < epochs:
        return False, f"only {min(len(new), len(old))} epochs to compare"
    for n, o in zip(new, old, strict=True):
        for field in COMPARED:
            if not _same(n.get(field), o.get(field)):
                return False, f"epoch {o['epoch']} {field}: {o.get(field)!r} then, {n.get(field)!r} now"
    return True, f"epochs 0-{epochs - 1}: {', '.join(COMPARED)} bit-identical"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--profile", required=True)
    p.add_argument("--old", required=True, type=Path, help="the old store's suite folder (holding runs/)")
    p.add_argument("--store", default=Path("results/bench"), type=Path)
    p.add_argument("--tasks", nargs="+", required=True)
    p.add_argument("--backend", required=True)
    p.add_argument("--replay-epochs", type=int, default=2)
    args = p.parse_args(argv)

    data, _ = bench.load_spec(args.profile)
    store = args.store / data["suite"]["name"]
    planned = {
        (j.run.task, j.run.backend, j.run.algo, j.run.seed, j.run.horizon): j
        for j in bench.plan(data, store)
        if j.kind == "train" and j.run.task in args.tasks and j.run.backend == args.backend
    }
    report = []
    for (task, backend, algo, seed, horizon), job in sorted(planned.items()):
        identity = job.run.identity()
        old_identity = {k: v for k, v in identity.items() if k != "physics"}
        old_dir = args.old / "runs" / f"{task}_{backend}_{algo}_h{horizon}_s{seed}_{bench._hash(old_identity)}"
        entry = {"run": job.run_dir.name, "old": old_dir.name}
        if job.is_done():
            entry.update(adopted=False, why="already done at its new address")
        elif not (old_dir / "config.json").is_file() or not (old_dir / "eval.json").is_file():
            entry.update(adopted=False, why="no finished old run with today's hyperparameters")
        else:
            config = json.loads((old_dir / "config.json").read_text())
            ok, why = replay_matches(old_dir, config, args.replay_epochs)
            entry.update(adopted=ok, why=why, old_commit=config["provenance"]["git_commit"])
            if ok:
                shutil.copytree(old_dir, job.run_dir)
                config["preset"] = identity["physics"]["preset"]
                config["physics_record"] = identity["physics"]
                config["adopted"] = {"from": old_dir.name, "evidence": why, "by": provenance(" ".join(sys.argv))}
                write_json(job.run_dir / "config.json", config)
                bench._write_job_file(job)
                if not job.is_done():
                    raise SystemExit(f"{job.run_dir}: adopted but not done; remove it")
        print(f"{'adopted' if entry['adopted'] else 'kept out'}: {entry['run']} ({entry['why']})", flush=True)
        report.append(entry)
    path = store / "adopted.json"
    previous = json.loads(path.read_text())["runs"] if path.is_file() else []
    write_json(path, {"runs": previous + report, "provenance": provenance(" ".join(sys.argv))})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
