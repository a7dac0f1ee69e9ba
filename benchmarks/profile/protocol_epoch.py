"""Where a protocol epoch's wall time goes: the engine's own work against everything else.

    OMP_NUM_THREADS=1 python benchmarks/profile/protocol_epoch.py --algo shac [--epochs 12] [--warmup 2] \
        [--tree DIR] [--out FILE.json]
    OMP_NUM_THREADS=1 python benchmarks/profile/protocol_epoch.py --algo shac --compare OLD_TREE [--rounds 3]

One run is trained exactly as ``python -m harness train --task ant --backend newton --num-envs 64
--horizon 32`` trains it (``harness.run.train.train``: a checkpoint after every epoch, metrics.jsonl,
TensorBoard, the progress line, the gradient statistics), in a temporary folder. Timers are wrapped
around the functions that make up an epoch, in this process only: they read the clock and call the
original, so the run's metrics are those of the plain command. Why wrappers rather than a sampling
profiler: the engine's work runs as captured Warp graphs (``wp.capture_launch``), one call per
forward, backward and gradient-zeroing of each control step, so timing those calls splits the
engine's own work from everything around it exactly, at no cost.

An epoch's wall time is measured from the start of its ``train_epoch`` to the start of the next one,
so it includes what the harness does between epochs (metrics row, TensorBoard events, progress line,
checkpoint with fsync). The first ``--warmup`` epochs are left out of the summary: a frame runs
eagerly on its first use and is captured on its second (``backends/newton/tape.py``).

``--tree DIR`` imports the project from another checkout (a ``git worktree`` of an older commit), so
that two versions of the code can be timed on the same machine. ``--compare OLD_TREE`` does that
side by side: it runs this tree and OLD_TREE in alternating processes, one at a time, ``--rounds``
times each, so that a change in the machine's load falls on both alike; it reports both trees'
epoch wall times (median and quartiles over every measured epoch) and whether the two trees' runs
were identical (every metrics field but the wall-time ones, compared exactly).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from harness.formatting import markdown_table

HERE = Path(__file__).resolve()
ROOT = HERE.parents[2]

#: the parts of an epoch, in the order of the report (seconds per epoch, see :func:`_parts`)
PARTS = (
    "engine forward (graph replay)",
    "engine backward (graph replay)",
    "engine gradient zeroing (graph replay)",
    "adapter around the engine (copies torch <-> Warp, eval_fk, frames)",
    "rollout: policy, critic bootstrap, task code, env bookkeeping",
    "torch backward of networks and task code",
    "actor clip + step (SAPO: + temperature)",
    "gradient statistics (group gradients + moments)",
    "reward weight",
    "lambda update",
    "critic update",
    "metrics.jsonl row",
    "TensorBoard events",
    "progress line",
    "checkpoint (write, fsync, rename)",
    "unattributed",
)


class Clock:
    """Seconds per epoch and label, from wrappers installed with :meth:`wrap`."""

    def __init__(self):
        self.epoch = -1
        self.starts: list[float] = []
        self.seconds: list[dict[str, float]] = []

    def new_epoch(self) -> None:
        self.epoch += 1
        self.starts.append(time.perf_counter())
        self.seconds.append(defaultdict(float))

    def wrap(self, owner, name: str, label, on_call=None) -> None:
        """Replace ``owner.name`` by a timed call of the original; ``label`` is a string or a function of
        the call's arguments returning one."""
        original = getattr(owner, name)
        clock = self

        def timed(*args, **kwargs):
            if on_call is not None:
                on_call()
            start = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                if clock.epoch >= 0:
                    key = label if isinstance(label, str) else label(*args, **kwargs)
                    clock.seconds[clock.epoch][key] += time.perf_counter() - start

        setattr(owner, name, timed)


def _instrument(clock: Clock) -> None:
    """Wrap every function an epoch is made of (imports resolve in the tree chosen by ``--tree``)."""
    import algorithms.actor_critic as ac
    import harness.run.train as train
    from backends.newton import tape

    algo = ac.FirstOrderActorCritic
    clock.wrap(algo, "train_epoch", "train_epoch", on_call=clock.new_epoch)
    clock.wrap(algo, "rollout", "rollout")
    clock.wrap(algo, "group_gradients", "group_gradients")
    clock.wrap(ac, "gradient_statistics", "gradient_statistics")
    clock.wrap(algo, "reward_weight", "reward weight")
    clock.wrap(tape.FrameStepper, "_replay", lambda self, frame, name, work: f"replay {name}")
    clock.wrap(tape.FrameStepper, "step", "adapter forward")
    clock.wrap(tape.FrameStepper, "backward_taped", "adapter backward")
    clock.wrap(train, "save_checkpoint", "checkpoint (write, fsync, rename)")
    clock.wrap(train, "_append_metrics", "metrics.jsonl row")
    clock.wrap(train.EpochScalars, "write", "TensorBoard events")
    clock.wrap(train._EpochProgress, "update", "progress line")


def _parts(wall: float, s: dict[str, float], row: dict) -> dict[str, float]:
    """An epoch's wall time split into :data:`PARTS` from its timers ``s`` and its metrics ``row``.

    ``backward_s`` (the actor loss's backward) holds the adapter's backward, ``sim_forward_s`` (the
    env steps) the adapter's forward; each adapter call holds its graph replays; the rest of each is
    torch, task and harness work. ``actor_update_s`` holds the gradient statistics and SAPO's
    temperature update."""
    fwd, bwd, zero = (s.get(f"replay {n}_graph", 0.0) for n in ("forward", "backward", "zero"))
    adapter = s.get("adapter forward", 0.0) + s.get("adapter backward", 0.0) - fwd - bwd - zero
    grad_stats = s.get("group_gradients", 0.0) + s.get("gradient_statistics", 0.0)
    parts = {
        PARTS[0]: fwd,
        PARTS[1]: bwd,
        PARTS[2]: zero,
        PARTS[3]: adapter,
        PARTS[4]: s.get("rollout", 0.0) - s.get("adapter forward", 0.0),
        PARTS[5]: row["backward_s"] - s.get("adapter backward", 0.0),
        PARTS[6]: row["actor_update_s"] - grad_stats,
        PARTS[7]: grad_stats,
        PARTS[8]: s.get("reward weight", 0.0),
        PARTS[9]: row.get("lambda_update_s", 0.0),
        PARTS[10]: row["critic_update_s"],
    }
    for name in PARTS[11:15]:
        parts[name] = s.get(name, 0.0)
    parts[PARTS[15]] = wall - sum(parts.values())
    return parts


def measure(args) -> dict:
    """Train one run under the timers; per-epoch wall times, parts and metrics (wall-time fields dropped)."""
    clock = Clock()
    _instrument(clock)
    import harness.run.train as train
    from algorithms.config import preset

    cfg = preset(args.algo).replace(num_envs=args.num_envs, horizon=args.horizon)
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run"
        with open(Path(tmp) / "progress.txt", "w") as stream:
            train.train(run, args.task, args.backend, cfg, args.epochs, seed=args.seed, stream=stream)
        end = time.perf_counter()
        rows = [json.loads(line) for line in (run / train.METRICS).read_text().splitlines()]
    if len(rows) != len(clock.starts):  # an epoch that went non-finite is re-run without a row
        raise SystemExit(f"{len(clock.starts)} epochs started, {len(rows)} rows written: a non-finite epoch")
    ends = clock.starts[1:] + [end]
    epochs = []
    for k, row in enumerate(rows):
        wall = ends[k] - clock.starts[k]
        epochs.append({"epoch": k, "wall_s": wall, "parts": _parts(wall, clock.seconds[k], row)})
    results = [{k: v for k, v in row.items() if k not in train.WALL_TIME_FIELDS} for row in rows]
    return {
        "tree": str(Path(args.tree or ROOT).resolve()),
        "imported_from": str(Path(train.__file__).resolve().parents[1]),
        "commit": _commit(args.tree or ROOT),
        "algo": args.algo,
        "epochs": epochs,
        "warmup": args.warmup,
        "metrics": results,
    }


def _commit(tree) -> str:
    out = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(
        ["git", "-C", str(tree), "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True
    ).stdout.strip()
    return out.stdout.strip() + ("+changes" if dirty else "")


def summary(result: dict) -> dict:
    """Median wall time and median part over the measured epochs (after the warm-up)."""
    measured = result["epochs"][result["warmup"] :]
    walls = [e["wall_s"] for e in measured]
    parts = {name: statistics.median(e["parts"][name] for e in measured) for name in PARTS}
    return {"median_wall_s": statistics.median(walls), "walls": walls, "parts": parts}


def table(result: dict) -> str:
    s = summary(result)
    lines = [
        f"{result['algo']} at {result['commit']}: median epoch {s['median_wall_s']:.3f} s over "
        f"{len(s['walls'])} epochs",
        "",
    ]
    rows = [[name, f"{v:.4f}", f"{100 * v / s['median_wall_s']:.1f}%"] for name, v in s["parts"].items()]
    lines += markdown_table(["part of the epoch", "s (median)", "share"], rows)
    return "\n".join(lines)


def _quartiles(values: list[float]) -> tuple[float, float, float]:
    if len(values) < 2:
        return values[0], values[0], values[0]
    q1, q2, q3 = statistics.quantiles(values, n=4, method="inclusive")
    return q1, q2, q3


def compare(args) -> dict:
    """This tree against ``args.compare`` in alternating processes (ABBA order), one at a time."""
    trees = {"old": str(Path(args.compare).resolve()), "new": str(ROOT)}
    order = [("old", "new") if r % 2 == 0 else ("new", "old") for r in range(args.rounds)]
    results: dict[str, list[dict]] = {"old": [], "new": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r, pair in enumerate(order):
            for which in pair:
                out = Path(tmp) / f"{which}{r}.json"
                command = [
                    sys.executable,
                    str(HERE),
                    "--algo",
                    args.algo,
                    "--epochs",
                    str(args.epochs),
                    "--warmup",
                    str(args.warmup),
                    "--seed",
                    str(args.seed),
                    "--tree",
                    trees[which],
                    "--out",
                    str(out),
                ]
                subprocess.run(command, check=True, stdout=subprocess.DEVNULL)  # its table: in the summary below
                results[which].append(json.loads(out.read_text()))
                if results[which][-1]["imported_from"] != trees[which]:  # the editable install won over --tree
                    raise SystemExit(f"{which}: imported {results[which][-1]['imported_from']}, not {trees[which]}")
                print(
                    f"round {r + 1}/{args.rounds} {which}: median epoch "
                    f"{summary(results[which][-1])['median_wall_s']:.3f} s",
                    flush=True,
                )
    report = {"algo": args.algo, "epochs": args.epochs, "warmup": args.warmup, "rounds": args.rounds}
    for which, runs in results.items():
        walls = [w for run in runs for w in summary(run)["walls"]]
        q1, median, q3 = _quartiles(walls)
        report[which] = {
            "tree": trees[which],
            "commit": runs[0]["commit"],
            "median_wall_s": median,
            "q1_s": q1,
            "q3_s": q3,
            "min_s": min(walls),
            "max_s": max(walls),
            "epochs_measured": len(walls),
            "parts": {name: statistics.median(summary(run)["parts"][name] for run in runs) for name in PARTS},
        }
    texts = {json.dumps(run["metrics"], sort_keys=True) for runs in results.values() for run in runs}
    report["identical_metrics"] = len(texts) == 1
    report["change"] = report["new"]["median_wall_s"] / report["old"]["median_wall_s"] - 1.0
    return report


def comparison_table(report: dict) -> str:
    """Both trees' epoch wall times, then each part's median seconds side by side: a change much smaller
    than the spread between processes (the machine's load drifts) still shows in the part it touches."""
    lines = []
    for which in ("old", "new"):
        r = report[which]
        lines.append(
            f"{which} ({r['commit']}): median {r['median_wall_s']:.3f} s [quartiles {r['q1_s']:.3f}, "
            f"{r['q3_s']:.3f}] over {r['epochs_measured']} epochs"
        )
    lines.append(f"change {100 * report['change']:+.1f}%; identical metrics: {report['identical_metrics']}")
    rows = [[name, f"{report['old']['parts'][name]:.4f}", f"{report['new']['parts'][name]:.4f}"] for name in PARTS]
    lines += ["", *markdown_table(["part of the epoch", "old s", "new s"], rows)]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", default="shac")
    parser.add_argument("--task", default="ant")
    parser.add_argument("--backend", default="newton")
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--horizon", type=int, default=32)
    parser.add_argument("--epochs", type=int, default=12)
    parser.add_argument("--warmup", type=int, default=2, help="first epochs left out (eager run, graph capture)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tree", default=None, help="import the project from this checkout")
    parser.add_argument("--compare", default=None, help="an older checkout to time against this one, side by side")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    if args.epochs <= args.warmup:
        parser.error(f"--epochs {args.epochs} leaves no epoch after the {args.warmup} warm-up epochs")
    if args.compare:
        report = compare(args)
        print(comparison_table(report))
    else:
        sys.path.insert(0, str(Path(args.tree or ROOT).resolve()))  # before any project import
        report = measure(args)
        print(table(report))
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
