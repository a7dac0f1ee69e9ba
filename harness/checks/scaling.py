"""How an adapter's cost grows with the number of envs: throughput over num_envs, CSV and a log-log plot.

For each env count a fresh adapter is built and :func:`harness.checks.throughput.measure` times forward-only
and forward+backward windows (best of ``windows`` after a warm-up; no bare-engine rounds, which
``throughput`` reports). An env count that fails (memory, a buffer overflow) is recorded with its
error and the sweep goes on; a count over ``max_seconds`` of estimated time is skipped and recorded as
such, so the curve says where it stops and why.

Reading the curve: while the CPU is launch-bound, a step costs about the same whatever N, so
env-steps/s grow linearly with N (slope 1 on the log-log plot); once compute-bound, the time per
step grows with N and the curve flattens (slope 0).
"""

from __future__ import annotations

import csv
import io
import time
from pathlib import Path

import pandas as pd

from harness.checks.throughput import forward_rate, measure
from harness.envs import make_sim
from harness.figures import NoPlotData, pyplot, save_figure
from harness.results import atomic_write_text
from tasks import make_task

DEFAULT_ENVS = (1, 4, 16, 64, 256)
FIELDS = ("backend", "task", "num_envs", "horizon", "forward_steps_per_s", "forward_backward_steps_per_s", "note")


def scaling(
    backend: str,
    task_name: str,
    env_counts=DEFAULT_ENVS,
    horizon: int = 8,
    windows: int = 3,
    device: str = "cpu",
    seed: int = 0,
    max_seconds: float = 600.0,
    options: dict | None = None,
    forward_only: bool = False,
    progress=print,
) -> list[dict]:
    """One row per env count (see the module docstring).

    ``max_seconds`` bounds the measured time of one env count: the next count's cost is predicted
    from the last measured step times scaled by the env ratio (an over-estimate while launch-bound),
    and a count predicted to exceed it is skipped with a note.
    """
    rows = []
    last = None  # (num_envs, seconds for warm-up + windows of both variants)
    for n in env_counts:
        row = {"backend": backend, "task": task_name, "num_envs": n, "horizon": horizon, "options": options or {}}
        if last is not None and last[1] * n / last[0] > max_seconds:
            row.update(forward_steps_per_s=None, forward_backward_steps_per_s=None)
            row["note"] = f"skipped: ~{last[1] * n / last[0]:.0f} s predicted > max {max_seconds:.0f} s"
            progress(f"  {n:5d} envs: {row['note']}")
            rows.append(row)
            continue
        start = time.perf_counter()
        try:
            sim = make_sim(backend, make_task(task_name), n, device, seed, horizon, **(options or {}))
            if forward_only:
                result = None
                forward = forward_rate(sim, horizon=horizon, windows=windows, seed=seed)
            else:
                result = measure(sim, horizon=horizon, windows=windows, seed=seed, bare=False)
                forward = result.forward_steps_per_s
        except (RuntimeError, ValueError, MemoryError) as exc:
            row.update(forward_steps_per_s=None, forward_backward_steps_per_s=None)
            row["note"] = f"failed: {type(exc).__name__}: {str(exc).splitlines()[0][:200]}"
            progress(f"  {n:5d} envs: {row['note']}")
            rows.append(row)
            continue
        last = (n, time.perf_counter() - start)
        with_grad = None if result is None else result.forward_backward_steps_per_s
        row.update(forward_steps_per_s=forward, forward_backward_steps_per_s=with_grad, note="")
        grad_text = "(not measured)" if with_grad is None else f"{with_grad:10.1f}"
        progress(f"  {n:5d} envs: forward {forward:10.1f}  forward+backward {grad_text} env-steps/s  ({last[1]:.0f} s)")
        rows.append(row)
    return rows


def to_csv(rows: list[dict], command: str, provenance: dict) -> str:
    """CSV with a comment header saying how it was made (command, commit, machine)."""
    out = io.StringIO()
    out.write(f"# {command}\n")
    out.write(f"# commit {provenance.get('git_commit')}, {provenance['machine']['cpu_model']}, ")
    out.write(f"{provenance['machine']['cpu_count']} cores, created {provenance['created_utc']}\n")
    writer = csv.DictWriter(out, fieldnames=FIELDS)
    writer.writeheader()
    for row in rows:
        writer.writerow({k: row.get(k) for k in FIELDS})
    return out.getvalue()


def read_csv(path: str | Path) -> list[dict]:
    lines = [line for line in Path(path).read_text().splitlines() if not line.startswith("#")]
    rows = []
    for row in csv.DictReader(lines):
        for key in ("forward_steps_per_s", "forward_backward_steps_per_s"):
            row[key] = float(row[key]) if row[key] else None
        row["num_envs"] = int(row["num_envs"])
        rows.append(row)
    return rows


def plot(csv_paths: list[str | Path], out_png: str | Path, title: str = "") -> Path:
    """The log-log plot (:func:`plot_scaling`) of the rows of one or more CSVs."""
    return plot_scaling([row for path in csv_paths for row in read_csv(path)], Path(out_png), title)


def write(rows: list[dict], out_prefix: str | Path, command: str, provenance: dict) -> list[Path]:
    out_prefix = Path(out_prefix)
    csv_path = atomic_write_text(out_prefix.with_suffix(".csv"), to_csv(rows, command, provenance))
    png = plot([csv_path], out_prefix.with_suffix(".png"), title=f"{rows[0]['backend']} / {rows[0]['task']}")
    return [csv_path, png]


SCALING_PASSES = (("forward_steps_per_s", "forward"), ("forward_backward_steps_per_s", "forward+backward"))


def plot_scaling(rows: list[dict], path: Path, title: str = "") -> Path:
    """Log-log env-steps/s against the number of envs (``scaling`` rows, :mod:`harness.checks.scaling`): one colour
    per backend x task, solid forward, dashed with gradients; counts without a rate (skipped) are left out."""
    points = [
        {
            "num envs": row["num_envs"],
            "env-steps/s": float(row[key]),
            "backend / task": f"{row['backend']} / {row['task']}",
            "pass": label,
        }
        for row in rows
        for key, label in SCALING_PASSES
        if row.get(key)
    ]
    if not points:
        raise NoPlotData("no scaling check")
    plt, sns = pyplot()
    fig, ax = plt.subplots(figsize=(10, 5.5))
    sns.lineplot(
        data=pd.DataFrame(points),
        x="num envs",
        y="env-steps/s",
        hue="backend / task",
        style="pass",
        markers=True,
        ax=ax,
    )
    sns.move_legend(ax, "upper left", bbox_to_anchor=(1.01, 1.0))  # beside the axes: inside, it hid curves
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_title(title or "throughput vs number of envs (scaling checks, log-log)")
    fig.tight_layout()
    return save_figure(fig, path)


# -- the verb and its line in the suite's checks table ---------------------------------------------


def verb(args) -> int:
    """``python -m harness scaling``: env-steps/s over env counts, as CSV, plot and check file."""
    from harness.inputs import BadInput, check_device, check_memory, check_output, out_stem, validate_names
    from harness.results import harness_command, provenance, write_check

    validate_names(args.backend, args.task)
    check_device(args.device)
    if sorted(args.envs) != list(args.envs) or len(set(args.envs)) != len(args.envs):
        raise BadInput(f"--envs must be distinct and increasing, got {args.envs}")
    out = out_stem(args.out) if args.out else None  # without --out, as every measuring verb: print, write nothing
    if out:
        check_output(out + ".csv")
    check_memory(
        args.backend, args.task, args.envs[-1], 0 if args.forward_only else args.horizon, args.device, "--envs"
    )
    print(f"scaling {args.backend}/{args.task}: envs {args.envs}, {args.horizon}-step windows, best of {args.windows}")
    rows = scaling(
        args.backend,
        args.task,
        env_counts=args.envs,
        horizon=args.horizon,
        windows=args.windows,
        device=args.device,
        seed=args.seed,
        max_seconds=args.max_seconds,
        options=dict(args.backend_option or []),
        forward_only=args.forward_only,
    )
    prov = provenance()
    if not out:
        print(to_csv(rows, harness_command(), prov), end="")
        return 0
    for path in write(rows, out, harness_command(), prov):
        print(f"wrote {path}")
    result = {"backend": args.backend, "task": args.task, "rows": rows}
    print(f"wrote {write_check(out + '.json', 'scaling', result)}")
    return 0


def summary(result: dict, kind: str) -> str:
    from harness.formatting import fmt

    rows = [row for row in result.get("rows", []) if row.get("forward_backward_steps_per_s")]
    if not rows:
        return "no env count measured with gradients"
    rates = ", ".join(f"{row['num_envs']}: {fmt(row['forward_backward_steps_per_s'])}" for row in rows)
    return f"env-steps/s with gradients by env count: {rates}"
