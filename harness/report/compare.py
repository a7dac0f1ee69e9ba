"""The ``report`` verb (``python -m harness report --runs RUN... --out PREFIX``): tables and curves from run
directories (``config.json``, ``metrics.jsonl``, ``eval.json``).

:func:`write_report` writes ``PREFIX.md`` and ``PREFIX.csv`` (one row per run), ``PREFIX_by_algo.csv`` and a
second table in ``PREFIX.md`` (over training seeds, per task, backend, setting and algorithm: the bench
report's rows, so runs of other adapter options, env counts, planned epochs or horizons never pool), and ``PREFIX.png``
(curves). Over seeds every column gets the bench report's statistics (:mod:`harness.report.stats`): the
interquartile mean with a 95% percentile-bootstrap confidence interval over seeds (2000 resamples,
``np.random.default_rng(0)``; n/a under 2 seeds or with an infinite value), and the mean and sample std.
The curves show the mean over seeds with a 95% bootstrap band.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from harness.figures import pyplot, save_figure
from harness.formatting import fmt, fmt_ci, is_missing, markdown_table
from harness.report.plots import CURVE_BOOTSTRAP
from harness.report.records import RunRecord, load_run, say
from harness.report.stats import BOOTSTRAP_SEED, epoch_median, iqm, iqm_with_ci, sample_std
from harness.results import RunError, atomic_write_text

COLUMNS = (
    "run",
    "algo",
    "backend",
    "task",
    "seed",
    "epochs",
    "env_steps",
    "wall_min",
    "sim_forward_min",
    "backward_min",
    "update_min",
    "train_return_last20",
    "eval_initial",
    "eval_final",
    "eval_std_over_seeds",
    "eval_seeds",
    "final_lambda",
    "median_actor_grad_var",
    "median_actor_grad_nsr",
    "median_actor_grad_cosine",
    "skipped_actor_updates",
)


def _median(rows: list[dict], key: str) -> float | None:
    """The median of ``key`` over the epochs that logged it (:func:`harness.report.stats.epoch_median`:
    NaN, a skipped update, dropped; +inf, an unresolved noise-to-signal ratio, kept); None when none did."""
    median = epoch_median(r.get(key) for r in rows)
    return None if math.isnan(median) else median


def summarize(run: str | Path | RunRecord, stream=None) -> dict | None:
    """One run's row. Read by the bench report's reader (:func:`harness.report.records.load_run`): a damaged
    file is skipped with one line on ``stream``, a resumed run's repeated epochs count once, an eval.json
    older than the run's last epoch counts as no evaluation; None where config.json is unusable."""
    record = run if isinstance(run, RunRecord) else load_run(Path(run), stream)
    if record is None:
        return None
    rows = record.metrics.to_dict("records")
    ev = record.evaluation
    returns = [r["train_episode_return"] for r in rows[-20:] if not is_missing(r.get("train_episode_return"))]
    total = lambda key: sum(r[key] for r in rows if not is_missing(r.get(key))) / 60.0  # noqa: E731
    final = lambda key: ev["final"].get(key) if ev else None  # noqa: E731
    return {
        "run": record.path.name,
        "algo": record.algo,
        "backend": record.backend,
        "task": record.task,
        "seed": record.seed,
        "num_envs": record.num_envs,
        "horizon": record.horizon,
        "planned_epochs": record.planned_epochs,
        "epochs": record.epochs,
        "env_steps": record.env_steps,
        "wall_min": record.wall_s / 60.0,
        "sim_forward_min": total("sim_forward_s"),
        "backward_min": total("backward_s"),
        "update_min": total("update_s"),
        "train_return_last20": sum(returns) / len(returns) if returns else None,
        "eval_initial": ev["initial"]["mean_return"] if ev else None,
        "eval_final": final("mean_return"),
        "eval_std_over_seeds": final("std_over_seeds"),
        "eval_seeds": ev.get("seeds") if ev else None,
        "final_lambda": rows[-1].get("lam") if rows else None,
        # raw (scales with the loss squared) and scale-free (algorithms/grad_variance.py); runs from before
        # the scale-free statistics have none
        "median_actor_grad_var": _median(rows, "actor_grad_var"),
        "median_actor_grad_nsr": _median(rows, "actor_grad_nsr"),
        "median_actor_grad_cosine": _median(rows, "actor_grad_cosine"),
        "skipped_actor_updates": sum(r.get("actor_update_skipped") is True for r in rows),
    }


def _csv_cell(value) -> str:
    return "" if value is None else str(value)


def write_table(summaries: list[dict], out_prefix: str | Path, command: str) -> tuple[Path, Path]:
    out_prefix = Path(out_prefix)
    md = [f"Made by: `{command}`", "", *markdown_table(COLUMNS, [[fmt(s[c]) for c in COLUMNS] for s in summaries])]
    csv = [",".join(COLUMNS)] + [",".join(_csv_cell(s[c]) for c in COLUMNS) for s in summaries]
    md_path = atomic_write_text(out_prefix.with_suffix(".md"), "\n".join(md) + "\n")
    csv_path = atomic_write_text(out_prefix.with_suffix(".csv"), "\n".join(csv) + "\n")
    return md_path, csv_path


AGGREGATED = (
    "eval_final",
    "eval_initial",
    "train_return_last20",
    "median_actor_grad_var",
    "median_actor_grad_nsr",
    "median_actor_grad_cosine",
    "final_lambda",
    "wall_min",
)
#: what a row over seeds pools: the bench report's (``RunRecord.group``)
GROUP = ("task", "backend", "num_envs", "horizon", "planned_epochs", "algo")
#: what ``PREFIX_by_algo.csv`` gives of every AGGREGATED column over seeds
STATISTICS = ("iqm", "ci_low", "ci_high", "mean", "std")


def over_seeds(values: list[float]) -> dict[str, float | None]:
    """IQM with its 95% percentile-bootstrap CI (:func:`harness.report.stats.iqm_with_ci`), mean and sample
    std of one column over seeds; None for what the values cannot give (no values; a CI and std under 2
    values or with an infinite one, an unresolved noise-to-signal ratio)."""
    x = np.asarray(values, dtype=float)
    if not x.size:
        return dict.fromkeys(STATISTICS)
    if np.isfinite(x).all():
        point, low, high = iqm_with_ci(x)
        spread = sample_std(x)
    else:
        point, low, high, spread = iqm(x), math.nan, math.nan, math.nan
    found = {"iqm": point, "ci_low": low, "ci_high": high, "mean": float(x.mean()), "std": spread}
    return {k: None if math.isnan(v) else v for k, v in found.items()}


def aggregate(summaries: list[dict]) -> list[dict]:
    """Per task, backend, setting (envs, horizon, planned epochs) and algorithm: seeds, and the STATISTICS of
    every AGGREGATED column over its seeds (the seeds that have a value: a run without eval.json counts for
    the training columns only)."""
    groups: dict[tuple, list[dict]] = {}
    for s in summaries:
        groups.setdefault(tuple(s[k] for k in GROUP), []).append(s)
    rows = []
    for key, members in groups.items():
        row = dict(zip(GROUP, key, strict=True)) | {"seeds": len(members)}
        row["env_steps"] = members[0]["env_steps"]
        for col in AGGREGATED:
            found = over_seeds([m[col] for m in members if not is_missing(m[col])])
            row |= {f"{col}_{k}": v for k, v in found.items()}
        rows.append(row)
    return rows


def _iqm_cell(row: dict, col: str) -> str:
    """``IQM [CI low, CI high]``, the IQM alone where there is no interval."""
    low, high = row[f"{col}_ci_low"], row[f"{col}_ci_high"]
    interval = "" if is_missing(low) or is_missing(high) else " " + fmt_ci(low, high)
    return fmt(row[f"{col}_iqm"]) + interval


def write_report(runs: list[Path], out_prefix: str | Path, command: str, plot: bool = True, stream=None) -> list[Path]:
    """``PREFIX.md`` (both tables), ``PREFIX.csv`` (per run), ``PREFIX_by_algo.csv``, ``PREFIX.png``. A run
    folder given twice counts once; what cannot be read is said on ``stream``, one line each."""
    out_prefix = Path(out_prefix)
    stream = stream or sys.stdout
    unique = list({Path(r).resolve(): Path(r) for r in runs}.values())
    records = [r for r in (load_run(path, stream) for path in unique) if r is not None]
    if not records:
        raise RunError("none of the --runs has a usable config.json")
    summaries = [summarize(r) for r in records]
    md_path, csv_path = write_table(summaries, out_prefix, command)
    agg = aggregate(summaries)
    cols = [*GROUP, "seeds", "env_steps"] + [f"{c}_{k}" for c in AGGREGATED for k in STATISTICS]
    csv = [",".join(cols)] + [",".join(_csv_cell(r[c]) for c in cols) for r in agg]
    agg_csv = atomic_write_text(out_prefix.parent / f"{out_prefix.name}_by_algo.csv", "\n".join(csv) + "\n")
    md = [
        "",
        "Over training seeds: interquartile mean [95% percentile-bootstrap CI over seeds, 2000 resamples], the "
        "bench report's statistics; mean and std in the `_by_algo.csv`:",
        "",
    ]
    if any(r["seeds"] < 2 for r in agg):
        md += [
            "**One training seed for some algorithms: no confidence interval, so this table is a record of what",
            "ran, not a ranking.**",
            "",
        ]
    header = ["task", "backend", "envs", "h", "epochs", "algo", "seeds", "env steps", "eval final", "eval initial"]
    header += ["train return, last 20", "median actor-grad var", "median actor-grad NSR", "median actor-grad cosine"]
    header += ["final lambda", "wall min"]
    rows = [
        [*(fmt(r[k]) for k in GROUP), str(r["seeds"]), fmt(r["env_steps"]), *(_iqm_cell(r, c) for c in AGGREGATED)]
        for r in agg
    ]
    md += markdown_table(header, rows)
    with md_path.open("a") as fh:
        fh.write("\n".join(md) + "\n")
    paths = [md_path, csv_path, agg_csv]
    if plot:
        curves = plot_curves(records, summaries, out_prefix.parent / f"{out_prefix.name}.png")
        if curves is None:
            say(stream, "no run has logged an epoch: no curves")
        else:
            paths.append(curves)
    return paths


def plot_curves(records: list[RunRecord], summaries: list[dict], out_png: str | Path, smooth: int = 10) -> Path | None:
    """Train return vs env steps and vs wall time, the actor gradient's raw variance and its scale-free
    noise-to-signal ratio, and lambda: per table row over its seeds (mean and 95% bootstrap band), or per
    run where every row has one seed; None when no run has logged an epoch. Runs from before the
    scale-free statistic leave its panel empty."""
    import pandas as pd

    plt, sns = pyplot()
    groups = [tuple(s[k] for k in GROUP) for s in summaries]
    varying = [k for k in range(len(GROUP)) if len({g[k] for g in groups}) > 1 or GROUP[k] == "algo"]
    frames = []
    for record, group in zip(records, groups, strict=True):
        needed = ("epoch", "env_steps", "wall_s", "train_episode_return", "actor_grad_var", "lam")
        if not record.epochs or any(c not in record.metrics for c in needed):
            continue
        df = record.metrics.copy()
        df["run"] = record.path.name
        # a curve pools only the seeds of one table row, named by what differs between the rows
        df["algo"] = " ".join(group[k] if GROUP[k] == "algo" else f"{GROUP[k]}={group[k]}" for k in varying)
        df["return (smoothed)"] = df["train_episode_return"].astype(float).rolling(smooth, min_periods=1).mean()
        df["wall time (min)"] = df["wall_s"] / 60.0
        df["actor grad variance"] = df["actor_grad_var"].astype(float)
        nsr = df["actor_grad_nsr"] if "actor_grad_nsr" in df else float("nan")
        # an unresolved ratio (+inf) has no place on a log axis: drawn as a gap, as a skipped update is
        df["actor grad NSR"] = pd.Series(nsr, index=df.index, dtype=float).replace(float("inf"), float("nan"))
        frames.append(df)
    if not frames:
        return None
    data = pd.concat(frames, ignore_index=True)
    # several seeds of one algorithm: one line per algorithm (mean, 95% bootstrap band); else one per run
    hue = "algo" if data.groupby("algo")["run"].nunique().max() > 1 else "run"
    band = {"errorbar": ("ci", 95), "n_boot": CURVE_BOOTSTRAP, "seed": BOOTSTRAP_SEED}
    fig, axes = plt.subplots(1, 5, figsize=(27, 4.5))
    sns.lineplot(data=data, x="env_steps", y="return (smoothed)", hue=hue, ax=axes[0], **band)
    sns.lineplot(data=data, x="epoch", y="wall time (min)", hue=hue, ax=axes[1], legend=False, **band)
    for ax, column in ((axes[2], "actor grad variance"), (axes[3], "actor grad NSR")):
        if data[column].notna().any():
            sns.lineplot(data=data, x="epoch", y=column, hue=hue, ax=ax, legend=False, **band)
            ax.set_yscale("log")
        else:
            ax.text(0.5, 0.5, "not logged by these runs", ha="center", va="center", transform=ax.transAxes)
    sns.lineplot(data=data, x="epoch", y="lam", hue=hue, ax=axes[4], legend=False, **band)
    axes[0].set_title("train episode return vs env steps")
    axes[1].set_title("wall time")
    axes[2].set_title("raw actor-gradient variance (K groups; scales with the loss squared)")
    axes[3].set_title("noise-to-signal ratio (scale-free)")
    axes[4].set_title("lambda")
    fig.tight_layout()
    return save_figure(fig, out_png)
