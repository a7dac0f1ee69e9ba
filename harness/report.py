"""Tables and figures from run directories (``config.json``, ``metrics.jsonl``, ``eval.json``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from harness.results import atomic_write_text

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
    "skipped_actor_updates",
)


def _read_rows(run: Path) -> list[dict]:
    path = run / "metrics.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line] if path.exists() else []


def summarize(run: str | Path) -> dict:
    run = Path(run)
    config = json.loads((run / "config.json").read_text())
    rows = _read_rows(run)
    ev = json.loads((run / "eval.json").read_text()) if (run / "eval.json").exists() else None
    returns = [r["train_episode_return"] for r in rows[-20:] if r.get("train_episode_return") is not None]
    grad_vars = sorted(r["actor_grad_var"] for r in rows if r.get("actor_grad_var") == r.get("actor_grad_var"))
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
        "median_actor_grad_var": grad_vars[len(grad_vars) // 2] if grad_vars else None,
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
        df["return (smoothed)"] = df["train_episode_return"].astype(float).rolling(smooth, min_periods=1).mean()
        df["wall time (min)"] = df["wall_s"] / 60.0
        df["actor grad variance"] = df["actor_grad_var"].astype(float)
        frames.append(df)
    data = pd.concat(frames, ignore_index=True)
    sns.set_theme(style="whitegrid")
    fig, axes = plt.subplots(1, 4, figsize=(22, 4.5))
    sns.lineplot(data=data, x="env_steps", y="return (smoothed)", hue="run", ax=axes[0])
    sns.lineplot(data=data, x="wall time (min)", y="return (smoothed)", hue="run", ax=axes[1], legend=False)
    sns.lineplot(data=data, x="epoch", y="actor grad variance", hue="run", ax=axes[2], legend=False)
    axes[2].set_yscale("log")
    sns.lineplot(data=data, x="epoch", y="lam", hue="run", ax=axes[3], legend=False)
    axes[0].set_title("train episode return vs env steps")
    axes[1].set_title("train episode return vs wall time")
    axes[2].set_title("actor-gradient variance (K groups)")
    axes[3].set_title("lambda")
    fig.tight_layout()
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=90)
    plt.close(fig)
    return out_png
