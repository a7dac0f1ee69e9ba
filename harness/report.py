"""Tables and figures from run directories (``config.json``, ``metrics.jsonl``, ``eval.json``).

:func:`write_report` writes a per-run table and, grouped by (task, backend, algorithm), the mean over
training seeds with the standard deviation and a 95% confidence interval of the mean (Student t,
n - 1 degrees of freedom); the curves show the mean over seeds with a 95% bootstrap band.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from harness.results import atomic_write_text, read_metrics

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


def _read_rows(run: Path) -> list[dict]:
    return read_metrics(run / "metrics.jsonl")  # a torn last line (a killed run) is dropped


def _median(rows: list[dict], key: str) -> float | None:
    """The median of ``key`` over the epochs that logged it (NaN, a skipped update, dropped; +inf, an
    unresolved noise-to-signal ratio, kept: a median is defined with it)."""
    values = sorted(r[key] for r in rows if r.get(key) is not None and r[key] == r[key])
    return values[len(values) // 2] if values else None


def summarize(run: str | Path) -> dict:
    run = Path(run)
    config = json.loads((run / "config.json").read_text())
    rows = _read_rows(run)
    ev = json.loads((run / "eval.json").read_text()) if (run / "eval.json").exists() else None
    returns = [r["train_episode_return"] for r in rows[-20:] if r.get("train_episode_return") is not None]
    total = lambda key: sum(r.get(key, 0.0) for r in rows) / 60.0  # noqa: E731
    return {
        "run": run.name,
        "algo": config["algo"]["algo"],
        "backend": config["backend"],
        "task": config["task"],
        "seed": config["seed"],
        "epochs": len(rows),
        "env_steps": rows[-1]["env_steps"] if rows else 0,
        "wall_min": rows[-1]["wall_s"] / 60.0 if rows else 0.0,
        "sim_forward_min": total("sim_forward_s"),
        "backward_min": total("backward_s"),
        "update_min": total("update_s"),
        "train_return_last20": sum(returns) / len(returns) if returns else None,
        "eval_initial": ev["initial"]["mean_return"] if ev else None,
        "eval_final": ev["final"]["mean_return"] if ev else None,
        "eval_std_over_seeds": ev["final"]["std_over_seeds"] if ev else None,
        "eval_seeds": ev["seeds"] if ev else None,
        "final_lambda": rows[-1]["lam"] if rows else None,
        # raw (scales with the loss squared) and scale-free (algorithms/grad_variance.py); runs from before
        # the scale-free statistics have none
        "median_actor_grad_var": _median(rows, "actor_grad_var"),
        "median_actor_grad_nsr": _median(rows, "actor_grad_nsr"),
        "median_actor_grad_cosine": _median(rows, "actor_grad_cosine"),
        "skipped_actor_updates": sum(bool(r.get("actor_update_skipped")) for r in rows),
    }


def _fmt(value) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return f"{value:.3g}" if abs(value) >= 1e4 or (0 < abs(value) < 1e-2) else f"{value:.2f}"
    return str(value)


def write_table(summaries: list[dict], out_prefix: str | Path, command: str) -> tuple[Path, Path]:
    out_prefix = Path(out_prefix)
    md = [f"Made by: `{command}`", "", "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    md += ["| " + " | ".join(_fmt(s[c]) for c in COLUMNS) + " |" for s in summaries]
    csv = [",".join(COLUMNS)] + [",".join("" if s[c] is None else str(s[c]) for c in COLUMNS) for s in summaries]
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
# two-sided 95% Student t quantiles for n - 1 = 1..30 degrees of freedom
_T95 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131)
_T95 += (2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042)


def aggregate(summaries: list[dict]) -> list[dict]:
    """Per (task, backend, algo): seeds, and mean / std / 95% CI half-width of every AGGREGATED column."""
    groups: dict[tuple, list[dict]] = {}
    for s in summaries:
        groups.setdefault((s["task"], s["backend"], s["algo"]), []).append(s)
    rows = []
    for (task, backend, algo), members in groups.items():
        row = {"task": task, "backend": backend, "algo": algo, "seeds": len(members)}
        row["env_steps"] = members[0]["env_steps"]
        for col in AGGREGATED:
            values = [m[col] for m in members if m[col] is not None and not math.isnan(m[col])]
            n = len(values)
            mean = sum(values) / n if n else None
            std = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1)) if n > 1 else None
            half = _T95[min(n - 1, len(_T95)) - 1] * std / math.sqrt(n) if n > 1 else None
            row[f"{col}_mean"], row[f"{col}_std"], row[f"{col}_ci95"] = mean, std, half
        rows.append(row)
    return rows


def write_report(runs: list[Path], out_prefix: str | Path, command: str, plot: bool = True) -> list[Path]:
    """``PREFIX.md`` (both tables), ``PREFIX.csv`` (per run), ``PREFIX_by_algo.csv``, ``PREFIX.png``."""
    out_prefix = Path(out_prefix)
    summaries = [summarize(r) for r in runs]
    md_path, csv_path = write_table(summaries, out_prefix, command)
    agg = aggregate(summaries)
    cols = ["task", "backend", "algo", "seeds", "env_steps"] + [
        f"{c}_{k}" for c in AGGREGATED for k in ("mean", "std", "ci95")
    ]
    csv = [",".join(cols)] + [",".join("" if r[c] is None else str(r[c]) for c in cols) for r in agg]
    agg_csv = atomic_write_text(out_prefix.parent / f"{out_prefix.name}_by_algo.csv", "\n".join(csv) + "\n")
    md = [
        "",
        "Mean over training seeds (std; 95% CI of the mean, Student t):",
        "",
    ]
    if any(r["seeds"] < 2 for r in agg):
        md += [
            "**One training seed for some algorithms: no confidence interval, so this table is a record of what",
            "ran, not a ranking.**",
            "",
        ]
    md += [
        "| task | backend | algo | seeds | env steps | eval final | eval initial | train return, last 20 | "
        "median actor-grad var | final lambda | wall min |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in agg:
        cells = [r["task"], r["backend"], r["algo"], str(r["seeds"]), _fmt(r["env_steps"])]
        for c in AGGREGATED:
            cells.append(f"{_fmt(r[c + '_mean'])} ({_fmt(r[c + '_std'])}; ±{_fmt(r[c + '_ci95'])})")
        md.append("| " + " | ".join(cells) + " |")
    with md_path.open("a") as fh:
        fh.write("\n".join(md) + "\n")
    paths = [md_path, csv_path, agg_csv]
    if plot:
        paths.append(plot_curves(runs, out_prefix.parent / f"{out_prefix.name}.png"))
    return paths


def plot_curves(runs: list[str | Path], out_png: str | Path, smooth: int = 10) -> Path:
    """Train return vs env steps and vs wall time, actor-gradient variance and lambda, per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import pandas as pd
    import seaborn as sns

    frames = []
    for run in runs:
        rows = _read_rows(Path(run))
        if not rows:
            continue
        df = pd.DataFrame(rows)
        df["run"] = f"{Path(run).name}"
        df["algo"] = json.loads((Path(run) / "config.json").read_text())["algo"]["algo"]
        df["return (smoothed)"] = df["train_episode_return"].astype(float).rolling(smooth, min_periods=1).mean()
        df["wall time (min)"] = df["wall_s"] / 60.0
        df["actor grad variance"] = df["actor_grad_var"].astype(float)
        frames.append(df)
    data = pd.concat(frames, ignore_index=True)
    # several seeds of one algorithm: one line per algorithm (mean, 95% bootstrap band); else one per run
    hue = "algo" if data.groupby("algo")["run"].nunique().max() > 1 else "run"
    band = {"errorbar": ("ci", 95), "n_boot": 200, "seed": 0}
    sns.set_theme(style="whitegrid")
    fig, axes = plt.subplots(1, 4, figsize=(22, 4.5))
    sns.lineplot(data=data, x="env_steps", y="return (smoothed)", hue=hue, ax=axes[0], **band)
    sns.lineplot(data=data, x="epoch", y="wall time (min)", hue=hue, ax=axes[1], legend=False, **band)
    sns.lineplot(data=data, x="epoch", y="actor grad variance", hue=hue, ax=axes[2], legend=False, **band)
    axes[2].set_yscale("log")
    sns.lineplot(data=data, x="epoch", y="lam", hue=hue, ax=axes[3], legend=False, **band)
    axes[0].set_title("train episode return vs env steps")
    axes[1].set_title("wall time")
    axes[2].set_title("actor-gradient variance (K groups)")
    axes[3].set_title("lambda")
    fig.tight_layout()
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=90)
    plt.close(fig)
    return out_png
