"""Aggregates across tasks, as rliable reports a benchmark: normalised scores, the aggregate IQM, the
probability of improvement over the base algorithm across tasks, and performance profiles.

Which runs: per (task, backend) the setting (N envs, planned epochs, h) that has the most evaluated runs
(on a tie, the one with the most algorithms, then the fewest env steps): one setting per task, so no
task counts twice and no setting's runs are mixed.

How scores are normalised, per (task, backend) at that setting: 0 is the untrained policy (the mean
initial-policy return of the setting's runs, from their eval.json), 1 the best algorithm (the highest IQM
final return among the setting's algorithms). A normalised score of 0.5 is half of the best algorithm's
improvement over an untrained policy on that task and engine; scores above 1 are seeds that beat the
best algorithm's IQM. Every number here: :mod:`harness.report.stats`.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pandas as pd

from harness.report.records import RunRecord, base_algo, rank, value_or_range
from harness.report.stats import (
    aggregate_iqm_with_ci,
    iqm,
    performance_profile_with_ci,
    probability_of_improvement_with_ci,
)

PROFILE_POINTS = 101  # thresholds of a performance profile


def _setting(run: RunRecord) -> tuple:
    return (run.num_envs or 0, run.planned_epochs or 0, run.horizon)


def headline_settings(runs: list[RunRecord]) -> dict[tuple[str, str], tuple]:
    """Per (task, backend) the setting (N, planned epochs, h) the aggregates use (module docstring)."""
    evaluated = [r for r in runs if r.evaluation is not None]
    counts = Counter((r.task, r.backend, _setting(r)) for r in evaluated)
    algos: dict[tuple, set] = {}
    steps: dict[tuple, int] = {}
    for r in evaluated:
        key = (r.task, r.backend, _setting(r))
        algos.setdefault(key, set()).add(r.algo)
        steps[key] = max(steps.get(key, 0), r.env_steps)
    chosen: dict[tuple[str, str], tuple] = {}
    for (task, backend, setting), n in counts.items():
        key = (task, backend, setting)
        score = (n, len(algos[key]), -steps[key])
        best = chosen.get((task, backend))
        if best is None or score > best[1]:
            chosen[(task, backend)] = (setting, score)
    return {key: setting for key, (setting, _) in sorted(chosen.items())}


def _describe(task: str, setting: tuple) -> str:
    num_envs, epochs, horizon = setting
    return f"{task} N {num_envs}, {epochs} epochs, h {horizon}"


def normalised_scores(runs: list[RunRecord]) -> dict[str, dict[str, dict[str, np.ndarray]]]:
    """backend -> algo -> task -> the normalised final returns of its seeds (module docstring)."""
    settings = headline_settings(runs)
    out: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    for (task, backend), setting in settings.items():
        members = [
            r for r in runs if r.evaluation is not None and (r.task, r.backend, _setting(r)) == (task, backend, setting)
        ]
        finals: dict[str, np.ndarray] = {}
        for r in members:
            finals.setdefault(r.algo, []).append(r.final_return)
        finals = {a: np.asarray(v, dtype=float) for a, v in finals.items()}
        low = float(np.mean([r.initial_return for r in members]))
        high = max(iqm(v) for v in finals.values())
        if not high > low:  # no algorithm improved on the untrained policy: nothing to normalise by
            continue
        for algo, values in finals.items():
            out.setdefault(backend, {}).setdefault(algo, {})[task] = (values - low) / (high - low)
    return out


def aggregate_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Per backend and algorithm: the tasks it has, the aggregate IQM of its normalised scores with the
    stratified-bootstrap CI, and its probability of improvement over its base algorithm across the tasks
    both have (rliable's average over tasks), with CI."""
    settings = headline_settings(runs)
    rows = []
    for backend, by_algo in normalised_scores(runs).items():
        for algo in sorted(by_algo, key=rank):
            tasks = sorted(by_algo[algo])
            point, low, high = aggregate_iqm_with_ci([by_algo[algo][t] for t in tasks])
            base = base_algo(algo)
            shared = [t for t in tasks if t in by_algo.get(base, {})] if base != algo else []
            better = (
                probability_of_improvement_with_ci(
                    [by_algo[algo][t] for t in shared], [by_algo[base][t] for t in shared]
                )
                if shared
                else (math.nan,) * 3
            )
            rows.append(
                {
                    "backend": backend,
                    "algo": algo,
                    "tasks": ", ".join(tasks),
                    "settings": "; ".join(_describe(t, settings[(t, backend)]) for t in tasks),
                    "seeds": value_or_range(len(by_algo[algo][t]) for t in tasks),
                    "iqm_normalised": point,
                    "iqm_ci_low": low,
                    "iqm_ci_high": high,
                    "base": base if base != algo else None,
                    "base_tasks": ", ".join(shared),
                    "p_improvement": better[0],
                    "p_improvement_ci_low": better[1],
                    "p_improvement_ci_high": better[2],
                }
            )
    return pd.DataFrame(rows, columns=_COLUMNS)


_COLUMNS = [
    "backend",
    "algo",
    "tasks",
    "settings",
    "seeds",
    "iqm_normalised",
    "iqm_ci_low",
    "iqm_ci_high",
    "base",
    "base_tasks",
    "p_improvement",
    "p_improvement_ci_low",
    "p_improvement_ci_high",
]


def performance_profile_frame(scores: dict[str, dict[str, dict[str, np.ndarray]]]) -> pd.DataFrame:
    """Per backend and algorithm, the performance profile (fraction of runs above each threshold tau of
    normalised score, averaged over tasks) with its 95% band, on one threshold grid per backend, from
    :func:`normalised_scores`."""
    rows = []
    for backend, by_algo in scores.items():
        every = np.concatenate([s for per_task in by_algo.values() for s in per_task.values()])
        taus = np.linspace(min(0.0, float(every.min())), max(1.0, float(every.max())), PROFILE_POINTS)
        for algo in sorted(by_algo, key=rank):
            point, low, high = performance_profile_with_ci(list(by_algo[algo].values()), taus)
            rows += [
                {"backend": backend, "algo": algo, "tau": t, "fraction": p, "low": lo, "high": hi}
                for t, p, lo, hi in zip(taus, point, low, high, strict=True)
            ]
    return pd.DataFrame(rows, columns=["backend", "algo", "tau", "fraction", "low", "high"])


def plot_performance_profiles(runs: list[RunRecord], path):
    """One panel per backend: each algorithm's performance profile with its 95% band."""
    from harness.figures import NoPlotData, pyplot, save_figure
    from harness.report.plots import _algo_palette

    scores = normalised_scores(runs)
    frame = performance_profile_frame(scores)
    if frame.empty:
        raise NoPlotData("no task has evaluated runs that improved on the untrained policy")
    plt, _ = pyplot()
    backends = list(dict.fromkeys(frame["backend"]))
    palette = _algo_palette(frame["algo"])
    fig, axes = plt.subplots(1, len(backends), figsize=(5.2 * len(backends), 3.8), squeeze=False)
    for ax, backend in zip(axes[0], backends, strict=True):
        for algo, curve in frame[frame["backend"] == backend].groupby("algo", sort=False):
            ax.plot(curve["tau"], curve["fraction"], color=palette[algo], label=algo)
            ax.fill_between(curve["tau"], curve["low"], curve["high"], color=palette[algo], alpha=0.15, lw=0)
        tasks = sorted({t for s in scores[backend].values() for t in s})
        ax.set_title(f"{backend} ({', '.join(tasks)})")
        ax.set_xlabel("normalised score tau")
        ax.set_ylabel("fraction of runs with score > tau")
        ax.legend(fontsize=8)
    fig.suptitle(
        "Performance profiles (rliable): mean over tasks, stratified-bootstrap 95% bands\n"
        "normalised score per task: 0 the untrained policy, 1 the best algorithm's IQM",
        y=1.0,
        va="bottom",
    )
    return save_figure(fig, path)
