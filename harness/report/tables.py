"""The bench report's tables as pure functions of the records (:mod:`harness.report.records`): one
``pandas.DataFrame`` per table, every number from :mod:`harness.report.stats`. Nothing here writes a file;
:mod:`harness.report.documents` turns the frames into Markdown and CSV."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from harness.report.records import (
    SIM_TO_SIM_PREFIXES,
    CheckRecord,
    RunRecord,
    backend_label,
    base_algo,
    by_group,
    group_runs,
    metric_column,
    rank,
    value_or_range,
)
from harness.report.stats import (
    EFFECTS,
    epoch_median,
    geometric_mean_with_ci,
    iqm,
    iqm_with_ci,
    paired_minimum_detectable_difference,
    pooled_std,
    probability_of_improvement,
    ratio_of_geometric_means_with_ci,
    sample_std,
    seeds_needed,
)
from harness.run.folder import EVALUATION

TIME_PARTS = (  # (column stem, label, metrics field)
    ("sim_forward", "sim forward", "sim_forward_s"),
    ("backward", "backward", "backward_s"),
    ("actor_update", "actor update", "actor_update_s"),
    ("critic_update", "critic update", "critic_update_s"),
    ("lambda_update", "lambda update", "lambda_update_s"),
    ("update_unsplit", "update (not split)", "update_s"),
    ("other", "other", None),
)


# -- tables (pure functions of the records) -------------------------------------------------------
def returns_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Final evaluation return per (task, backend, num_envs, planned epochs, horizon, algo) over training seeds;
    runs without eval.json are left out. ``improvement_*``: IQM(algo) - IQM(base algo) in the same group but
    for the algorithm. ``forward_velocity_*``: over the ``forward_velocity_seeds`` training seeds whose
    evaluation recorded the velocity."""
    groups = by_group(r for r in runs if r.evaluation is not None)
    finals = {key: np.array([r.final_return for r in members], dtype=float) for key, members in groups.items()}
    rows = []
    for (task, backend, num_envs, planned, horizon, algo), members in groups.items():
        final = finals[(task, backend, num_envs, planned, horizon, algo)]
        point, low, high = iqm_with_ci(final)
        base = base_algo(algo)
        base_final = finals.get((task, backend, num_envs, planned, horizon, base)) if base != algo else None
        # descriptive beside the claims table's verdicts: no interval (docs/statistics.md)
        gain = iqm(final) - iqm(base_final) if base_final is not None else math.nan
        better = probability_of_improvement([final], [base_final]) if base_final is not None else math.nan
        velocity = np.array([r.final_forward_velocity for r in members], dtype=float)
        velocity = velocity[np.isfinite(velocity)]  # evaluations made before it was recorded have none
        velocity_iqm = iqm_with_ci(velocity) if velocity.size else (math.nan,) * 3
        mde = _paired_mde(members, groups.get((task, backend, num_envs, planned, horizon, base)), algo, base)
        rows.append(
            {
                "task": task,
                "backend": backend,
                "algo": algo,
                "horizon": horizon,
                "num_envs": num_envs,
                "seeds": len(members),
                "epochs": value_or_range(r.epochs for r in members),
                "env_steps": value_or_range(r.env_steps for r in members),
                "eval_seeds": value_or_range(r.evaluation.get("seeds") for r in members),
                "eval_num_envs": value_or_range(r.evaluation.get("num_envs") for r in members),
                "iqm_final": point,
                "iqm_ci_low": low,
                "iqm_ci_high": high,
                "mean_final": float(final.mean()),
                "std_final": sample_std(final),
                "mean_initial": float(np.mean([r.initial_return for r in members])),
                "base": base if base != algo else None,
                "base_seeds": len(base_final) if base_final is not None else None,
                "improvement_iqm": gain,
                "p_improvement": better,
                "mde_80": mde,
                "forward_velocity_seeds": velocity.size,
                "forward_velocity_iqm": velocity_iqm[0],
                "forward_velocity_ci_low": velocity_iqm[1],
                "forward_velocity_ci_high": velocity_iqm[2],
            }
        )
    return pd.DataFrame(rows, columns=_RETURNS_COLUMNS)


_RETURNS_COLUMNS = [
    "task",
    "backend",
    "algo",
    "horizon",
    "num_envs",
    "seeds",
    "epochs",
    "env_steps",
    "eval_seeds",
    "eval_num_envs",
    "iqm_final",
    "iqm_ci_low",
    "iqm_ci_high",
    "mean_final",
    "std_final",
    "mean_initial",
    "base",
    "base_seeds",
    "improvement_iqm",
    "p_improvement",
    "mde_80",
    "forward_velocity_seeds",
    "forward_velocity_iqm",
    "forward_velocity_ci_low",
    "forward_velocity_ci_high",
]


def _paired_mde(members: list[RunRecord], base_members: list[RunRecord] | None, algo: str, base: str) -> float:
    """The smallest difference of mean final returns the paired t-test detects at 80% power over the seeds
    the algorithm and its base share (:func:`paired_minimum_detectable_difference`); NaN for a base or
    under 2 pairs."""
    if base == algo or not base_members:
        return math.nan
    mine = {r.seed: r.final_return for r in members}
    theirs = {r.seed: r.final_return for r in base_members}
    differences = np.array([mine[s] - theirs[s] for s in sorted(mine.keys() & theirs.keys())], dtype=float)
    if differences.size < 2:
        return math.nan
    return paired_minimum_detectable_difference(sample_std(differences), differences.size)


def power_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Per (task, backend, num_envs, planned epochs, horizon) and algorithm family (a base with its
    TD-lambda variants: the claims compare within a family) with evaluated runs: the between-seed spread
    of the final return pooled over the family's algorithms, the base's mean return, and the seeds per
    algorithm a two-sample test needs to detect each relative improvement in EFFECTS at POWER (a planning
    figure; the claims' paired test needs fewer where the seeds correlate positively, more where
    negatively)."""
    groups = by_group(r for r in runs if r.evaluation is not None)
    settings: dict[tuple, dict[str, np.ndarray]] = {}
    for (task, backend, num_envs, planned, horizon, algo), members in groups.items():
        finals = np.array([r.final_return for r in members], dtype=float)
        settings.setdefault((task, backend, num_envs, planned, horizon, base_algo(algo)), {})[algo] = finals
    rows = []
    for (task, backend, num_envs, planned, horizon, family), by_algo in settings.items():
        spread = pooled_std(by_algo.values())
        base = by_algo.get(family)
        base_mean = float(np.mean(base)) if base is not None else math.nan
        row = {"task": task, "backend": backend, "num_envs": num_envs, "epochs": planned, "horizon": horizon}
        row |= {"family": family, "algos": len(by_algo), "seeds": value_or_range(x.size for x in by_algo.values())}
        row |= {"pooled_std": spread, "base_mean": base_mean}
        row["cv"] = spread / abs(base_mean) if base_mean else math.nan
        for effect in EFFECTS:
            row[f"seeds_for_{round(effect * 100)}pct"] = seeds_needed(spread, effect * abs(base_mean))
        rows.append(row)
    columns = ["task", "backend", "num_envs", "epochs", "horizon", "family", "algos", "seeds", "pooled_std"]
    columns += ["base_mean", "cv"] + [f"seeds_for_{round(e * 100)}pct" for e in EFFECTS]
    return pd.DataFrame(rows, columns=columns)


#: the two gradient statistics every variance table and plot shows (algorithms/grad_variance.py):
#: (metric logged per epoch, column stem, label)
GRAD_STATISTICS = (
    ("actor_grad_var", "var", "raw variance Var_K (scales with the loss squared)"),
    ("actor_grad_nsr", "nsr", "noise-to-signal Var_K / S (scale-free)"),
)


def seed_medians(members: list[RunRecord], metric: str) -> np.ndarray:
    """Each run's median of ``metric`` over its epochs (NaN epochs, skipped updates, dropped; +inf kept);
    runs that never logged it (from before the statistic existed) are left out."""
    medians = []
    for run in members:
        column = metric_column(run.metrics, metric).to_numpy(dtype=float)
        if not np.isnan(column).all():
            medians.append(epoch_median(column))
    return np.asarray(medians, dtype=float)


def grad_variance_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Per group and gradient statistic (GRAD_STATISTICS): the median and quartiles of every epoch of
    every seed pooled (finite values), and the geometric mean over seeds of each seed's median with its
    95% bootstrap CI (``{stem}_seeds``: how many seeds logged the statistic)."""
    rows = []
    for (task, backend, num_envs, planned, horizon, algo), members in by_group(r for r in runs if r.epochs).items():
        row = {
            "task": task,
            "backend": backend,
            "algo": algo,
            "num_envs": num_envs,
            "epochs": planned,
            "horizon": horizon,
            "seeds": len(members),
            "skipped_pct": skipped_pct(members),
        }
        for metric, stem, _ in GRAD_STATISTICS:
            pooled = np.concatenate([metric_column(r.metrics, metric).to_numpy(dtype=float) for r in members])
            pooled = pooled[np.isfinite(pooled)]
            q1, median, q3 = np.percentile(pooled, [25, 50, 75]) if pooled.size else (math.nan,) * 3
            per_seed = seed_medians(members, metric)
            gmean, low, high = geometric_mean_with_ci(per_seed)
            prefix = "" if stem == "var" else f"{stem}_"
            row |= {f"{prefix}values": int(pooled.size), f"{prefix}median": float(median)}
            row |= {f"{prefix}q1": float(q1), f"{prefix}q3": float(q3)}
            row |= {f"{stem}_seeds": int(per_seed.size), f"{stem}_gmean": gmean}
            row |= {f"{stem}_ci_low": low, f"{stem}_ci_high": high}
        rows.append(row)
    columns = ["task", "backend", "algo", "num_envs", "epochs", "horizon", "seeds", "skipped_pct"]
    for _, stem, _ in GRAD_STATISTICS:
        prefix = "" if stem == "var" else f"{stem}_"
        columns += [f"{prefix}{c}" for c in ("values", "median", "q1", "q3")]
        columns += [f"{stem}_{c}" for c in ("seeds", "gmean", "ci_low", "ci_high")]
    return pd.DataFrame(rows, columns=columns)


def grad_variance_growth_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Per (task, backend, algo, num_envs, planned epochs) swept over h: the growth of each statistic from
    the shortest h (and from h 32, when the sweep holds it strictly inside) to the longest. ``growth_factor``
    is the ratio of the pooled medians; ``{stem}_growth`` the ratio of the geometric means of the seeds'
    medians, with a 95% CI (unpaired bootstrap over seeds). Runs of another setting never stand in."""
    groups = by_group(r for r in runs if r.epochs)
    settings: dict[tuple, dict[int, list[RunRecord]]] = {}
    for (task, backend, num_envs, planned, horizon, algo), members in groups.items():
        settings.setdefault((task, backend, algo, num_envs, planned), {})[int(horizon)] = members
    rows = []
    for (task, backend, algo, num_envs, planned), by_h in settings.items():
        horizons = sorted(by_h)
        if len(horizons) < 2:
            continue
        top = horizons[-1]
        bases = [horizons[0]] + ([32] if 32 in horizons[1:-1] else [])
        for base in bases:
            row = {"task": task, "backend": backend, "algo": algo, "num_envs": num_envs, "epochs": planned}
            row |= {"h_min": base, "h_max": top}
            for metric, stem, _ in GRAD_STATISTICS:
                lo = np.concatenate([metric_column(r.metrics, metric).to_numpy(dtype=float) for r in by_h[base]])
                hi = np.concatenate([metric_column(r.metrics, metric).to_numpy(dtype=float) for r in by_h[top]])
                lo, hi = lo[np.isfinite(lo)], hi[np.isfinite(hi)]
                med_lo = float(np.median(lo)) if lo.size else math.nan
                med_hi = float(np.median(hi)) if hi.size else math.nan
                if stem == "var":
                    row |= {"median_h_min": med_lo, "median_h_max": med_hi}
                    row["growth_factor"] = med_hi / med_lo if med_lo else math.nan
                point, low, high = ratio_of_geometric_means_with_ci(
                    seed_medians(by_h[top], metric), seed_medians(by_h[base], metric)
                )
                row |= {f"{stem}_growth": point, f"{stem}_growth_ci_low": low, f"{stem}_growth_ci_high": high}
            rows.append(row)
    columns = [
        *("task", "backend", "algo", "num_envs", "epochs"),
        *("h_min", "h_max", "median_h_min", "median_h_max", "growth_factor"),
    ]
    columns += [f"{stem}_growth{c}" for _, stem, _ in GRAD_STATISTICS for c in ("", "_ci_low", "_ci_high")]
    return pd.DataFrame(rows, columns=columns)


BUDGET_TOLERANCE = 0.02  # planned env steps per run this close count as one budget (epochs are whole numbers)


def _budget_clusters(budgets: list[int]) -> list[list[int]]:
    """Distinct budgets merged into clusters whose neighbours differ by at most BUDGET_TOLERANCE."""
    clusters: list[list[int]] = []
    for budget in sorted(set(budgets)):
        if clusters and budget <= clusters[-1][-1] * (1 + BUDGET_TOLERANCE):
            clusters[-1].append(budget)
        else:
            clusters.append([budget])
    return clusters


def returns_vs_h_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Final eval return against h at one budget (the paper's Fig. 7, right): per (task, backend, algo, N),
    the horizons whose planned env steps per run (N x h x planned epochs) agree within BUDGET_TOLERANCE,
    where there are at least two. IQM with its 95% CI over training seeds, mean wall minutes per run and
    the share of actor updates skipped."""
    evaluated = [r for r in runs if r.evaluation is not None and r.epochs and r.planned_epochs and r.num_envs]
    settings = group_runs(evaluated, lambda r: (r.task, r.backend, r.algo, r.num_envs))
    rows = []
    for (task, backend, algo, num_envs), members in settings.items():
        budget_of = {id(r): num_envs * r.horizon * r.planned_epochs for r in members}
        for cluster in _budget_clusters(list(budget_of.values())):
            inside = [r for r in members if budget_of[id(r)] in cluster]
            by_h = {key[0]: at for key, at in group_runs(inside, lambda r: (r.horizon,)).items()}
            if len(by_h) < 2:
                continue
            for horizon in sorted(by_h):
                at_h = by_h[horizon]
                final = np.array([r.final_return for r in at_h], dtype=float)
                point, low, high = iqm_with_ci(final)
                rows.append(
                    {
                        "task": task,
                        "backend": backend,
                        "algo": algo,
                        "num_envs": num_envs,
                        "budget": value_or_range(cluster),
                        "horizon": horizon,
                        "epochs": value_or_range(r.planned_epochs for r in at_h),
                        "seeds": len(at_h),
                        "iqm_final": point,
                        "iqm_ci_low": low,
                        "iqm_ci_high": high,
                        "mean_final": float(final.mean()),
                        "std_final": sample_std(final),
                        "wall_min_mean": float(np.mean([r.wall_s for r in at_h])) / 60.0,
                        "skipped_pct": skipped_pct(at_h),
                    }
                )
    columns = [
        *("task", "backend", "algo", "num_envs", "budget", "horizon", "epochs", "seeds"),
        *("iqm_final", "iqm_ci_low", "iqm_ci_high", "mean_final", "std_final", "wall_min_mean", "skipped_pct"),
    ]
    return pd.DataFrame(rows, columns=columns)


def time_split(run: RunRecord) -> dict[str, float]:
    """Seconds of each TIME_PARTS stem summed over the run's epochs.

    Epochs that logged actor/critic/lambda update times count them; epochs that did not (runs from before
    the split was logged) count their whole ``update_s`` as ``update_unsplit``. ``other`` is the rest of
    the wall time (rollout bookkeeping, logging, checkpoints).
    """
    m = run.metrics
    split = metric_column(m, "actor_update_s").notna()
    seconds = {
        "sim_forward": float(metric_column(m, "sim_forward_s").sum()),
        "backward": float(metric_column(m, "backward_s").sum()),
        "actor_update": float(metric_column(m, "actor_update_s")[split].sum()),
        "critic_update": float(metric_column(m, "critic_update_s")[split].sum()),
        "lambda_update": float(metric_column(m, "lambda_update_s")[split].sum()),
        "update_unsplit": float(metric_column(m, "update_s")[~split].sum()),
    }
    seconds["other"] = max(run.wall_s - sum(seconds.values()), 0.0) if np.isfinite(run.wall_s) else math.nan
    return seconds


def wall_time_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Per run: wall minutes, seconds per epoch and the split of the wall time, in minutes and fractions."""
    rows = []
    for members in by_group(r for r in runs if r.epochs).values():
        for run in members:
            seconds = time_split(run)
            row = {
                "run": run.path.name,
                "task": run.task,
                "backend": run.backend,
                "algo": run.algo,
                "horizon": run.horizon,
                "num_envs": run.num_envs,
                "seed": run.seed,
                "epochs": run.epochs,
                "env_steps": run.env_steps,
                "wall_min": run.wall_s / 60.0,
                "s_per_epoch": run.wall_s / run.epochs,
            }
            row.update({f"{stem}_min": seconds[stem] / 60.0 for stem, _, _ in TIME_PARTS})
            row.update(
                {f"{stem}_frac": seconds[stem] / run.wall_s if run.wall_s else math.nan for stem, _, _ in TIME_PARTS}
            )
            rows.append(row)
    columns = [
        *("run", "task", "backend", "algo", "horizon", "num_envs", "seed"),
        *("epochs", "env_steps", "wall_min", "s_per_epoch"),
    ]
    columns += [f"{stem}_{unit}" for unit in ("min", "frac") for stem, _, _ in TIME_PARTS]
    return pd.DataFrame(rows, columns=columns)


def throughput_table(checks: list[CheckRecord]) -> pd.DataFrame:
    """Per throughput check file: env-steps/s forward, forward+backward, and of the bare engine; a peer
    simulator's (``peer`` checks) beside them, its backend named ``PEER (peer)``."""
    rows = []
    for check in checks:
        if check.kind not in ("throughput", "peer"):
            continue
        r = check.result
        measured = r.get("forward_backward_steps_per_s")
        estimated = r.get("forward_backward_steps_per_s_estimated")  # `throughput --grad-cost-only`
        peer = check.kind == "peer"
        against = r.get("against") or {}
        rows.append(
            {
                "file": check.path.name,
                "backend": f"{r.get('peer')} (peer)" if peer else backend_label(str(r.get("backend")), r),
                "integrator": r.get("integrator"),
                "task": r.get("task"),
                "num_envs": r.get("num_envs"),
                "horizon": r.get("horizon"),
                "windows": r.get("windows"),
                "forward_steps_per_s": r.get("forward_steps_per_s"),
                "forward_backward_steps_per_s": measured if measured is not None else estimated,
                "forward_backward_estimated": measured is None and estimated is not None,
                "bare_forward_steps_per_s": r.get("bare_forward_steps_per_s"),
                "bare_engine_steps_per_s": r.get("bare_engine_steps_per_s"),
                "forward_overhead_ratio": r.get("forward_overhead_ratio"),
                "overhead_ratio": r.get("overhead_ratio"),
                "gradient_cost_factor": r.get("gradient_cost_factor"),
                "against": against.get("backend"),
                "speed_ratio": against.get("speed_ratio"),
                "speed_ratio_min": against.get("speed_ratio_min"),
                "speed_ratio_max": against.get("speed_ratio_max"),
            }
        )
    columns = [
        "file",
        "backend",
        "integrator",
        "task",
        "num_envs",
        "horizon",
        "windows",
        "forward_steps_per_s",
        "forward_backward_steps_per_s",
        "forward_backward_estimated",
        "bare_forward_steps_per_s",
        "bare_engine_steps_per_s",
        "forward_overhead_ratio",
        "overhead_ratio",
        "gradient_cost_factor",
        "against",
        "speed_ratio",
        "speed_ratio_min",
        "speed_ratio_max",
    ]
    rows.sort(key=lambda r: (rank(str(r["task"])), rank(str(r["backend"])), r["num_envs"] or 0, r["file"]))
    return pd.DataFrame(rows, columns=columns)


BACKEND_MEASURES = (
    "seeds",
    "epochs",
    "env_steps",
    "iqm_final",
    "gain_mean",
    "skipped_pct",
    "grad_norm_median",
    "wall_min_mean",
    "s_per_epoch_mean",
)


def _skipped_fraction(run: RunRecord) -> float:
    """The fraction of a run's actor updates skipped as exploding or non-finite."""
    column = metric_column(run.metrics, "actor_update_skipped")
    return float(column.astype(float).mean()) if len(column) and column.notna().all() else math.nan


def skipped_pct(members: list[RunRecord]) -> float:
    """The mean over runs of the percentage of actor updates skipped; NaN when no run logged it."""
    fractions = [f for f in (_skipped_fraction(r) for r in members) if not math.isnan(f)]
    return 100.0 * float(np.mean(fractions)) if fractions else math.nan


def backends_table(runs: list[RunRecord]) -> pd.DataFrame:
    """One row per (task, algo, horizon, num_envs, planned epochs) trained on at least 2 backends, columns
    ``BACKEND_MEASURE`` per backend.

    ``seeds`` counts every run (wall time is known without an evaluation); ``iqm_final`` rests on the
    evaluated ones.
    """
    long_rows = []
    for (task, num_envs, planned, horizon, algo, backend), members in group_runs(
        (r for r in runs if r.epochs), lambda r: (r.task, r.num_envs, r.planned_epochs, r.horizon, r.algo, r.backend)
    ).items():
        evaluated = [r.final_return for r in members if r.evaluation is not None]
        gains = [r.final_return - r.initial_return for r in members if r.evaluation is not None]
        norms = seed_medians(members, "actor_grad_norm")
        long_rows.append(
            {
                "task": task,
                "algo": algo,
                "horizon": horizon,
                "num_envs": num_envs,
                "planned_epochs": planned,
                "backend": backend,
                "seeds": len(members),
                "epochs": value_or_range(r.epochs for r in members),
                "env_steps": value_or_range(r.env_steps for r in members),
                "iqm_final": iqm(evaluated),
                "gain_mean": float(np.mean(gains)) if gains else math.nan,
                "skipped_pct": skipped_pct(members),
                "grad_norm_median": float(np.median(norms)) if norms.size else math.nan,
                "wall_min_mean": float(np.mean([r.wall_s for r in members])) / 60.0,
                "s_per_epoch_mean": float(np.mean([r.wall_s / r.epochs for r in members])),
            }
        )
    keys = ["task", "algo", "horizon", "num_envs", "planned_epochs"]
    long = pd.DataFrame(long_rows, columns=[*keys, "backend", *BACKEND_MEASURES])
    backends = sorted(long["backend"].unique(), key=rank)
    rows = []
    for (task, algo, horizon, num_envs, _planned), sub in long.groupby(keys, sort=False, dropna=False):
        if sub["backend"].nunique() < 2:
            continue
        row = {"task": task, "algo": algo, "horizon": horizon, "num_envs": num_envs}
        for backend in backends:
            match = sub[sub["backend"] == backend]
            for measure in BACKEND_MEASURES:
                row[f"{backend}_{measure}"] = match[measure].iloc[0] if len(match) else None
        rows.append(row)
    columns = ["task", "algo", "horizon", "num_envs"] + [f"{b}_{m}" for b in backends for m in BACKEND_MEASURES]
    return pd.DataFrame(rows, columns=columns)


def _protocol(payload: dict) -> tuple:
    return tuple(payload.get(k) for k in ("seeds", "num_envs", "max_steps"))


def sim_to_sim_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Per run and other backend: the final policy's return where it trained and where it was evaluated.

    The return on the training backend comes from the file written with the same protocol where there is
    one (the suite writes ``sim2sim_on_<training backend>.json`` beside ``sim2sim_on_<other>.json``: same
    eval seeds, envs and step cap), else from eval.json's final policy; ``own_source`` names it and
    ``same_protocol`` says whether the two evaluations used the same seeds, envs and step cap.
    """
    rows = []
    for run in sorted(runs, key=lambda r: (r.task, rank(r.algo), r.horizon, r.seed, r.backend)):
        for name, other in run.cross_evaluations.items():
            evaluated_on, trained_on = other["backend"], other.get("trained_on", run.backend)
            if evaluated_on == trained_on:
                continue  # the same-protocol evaluation on the training backend: a reference, not a row
            prefix = next(p for p in SIM_TO_SIM_PREFIXES if name.startswith(p))
            own_name = f"{prefix}{trained_on}.json"
            if own_name in run.cross_evaluations:
                own, own_source = run.cross_evaluations[own_name], own_name
            elif run.evaluation is not None:
                own, own_source = run.evaluation, EVALUATION
            else:
                own, own_source = None, None
            own_return = own["final"]["mean_return"] if own else math.nan
            other_return = other["final"]["mean_return"]
            rows.append(
                {
                    "run": run.path.name,
                    "task": run.task,
                    "algo": run.algo,
                    "horizon": run.horizon,
                    "num_envs": run.num_envs,
                    "epochs": run.planned_epochs,
                    "seed": run.seed,
                    "trained_on": trained_on,
                    "evaluated_on": evaluated_on,
                    "own_return": own_return,
                    "other_return": other_return,
                    "gap": other_return - own_return,
                    "own_source": own_source,
                    "other_source": name,
                    "same_protocol": _protocol(own) == _protocol(other) if own else None,
                }
            )
    columns = ["run", "task", "algo", "horizon", "num_envs", "epochs", "seed", "trained_on", "evaluated_on"]
    columns += ["own_return", "other_return", "gap", "own_source", "other_source", "same_protocol"]
    return pd.DataFrame(rows, columns=columns)


def sim_to_sim_mean_table(per_run: pd.DataFrame) -> pd.DataFrame:
    """Mean over seeds of :func:`sim_to_sim_table` per (task, algo, horizon, envs, planned epochs,
    trained_on, evaluated_on): runs of different settings are never pooled."""
    keys = ["task", "algo", "horizon", "num_envs", "epochs", "trained_on", "evaluated_on"]
    columns = [*keys, "seeds", "own_return_mean", "other_return_mean", "gap_mean", "gap_std"]
    if per_run.empty:
        return pd.DataFrame(columns=columns)
    grouped = per_run.groupby(keys, sort=False)
    frame = grouped.agg(
        seeds=("seed", "size"),
        own_return_mean=("own_return", "mean"),
        other_return_mean=("other_return", "mean"),
        gap_mean=("gap", "mean"),
        gap_std=("gap", "std"),
    ).reset_index()
    return frame[columns]


def landscape_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Per run with a landscape.json: grid, span and the roughness of both actor losses, and their ratio."""
    rows = []
    for run in sorted(runs, key=lambda r: (r.task, r.backend, rank(r.algo), r.horizon, r.seed)):
        land = run.landscape
        if land is None:
            continue
        rough = land.get("roughness") or {}
        h_step, td_lambda = rough.get("h_step"), rough.get("td_lambda")
        ratio = h_step / td_lambda if h_step is not None and td_lambda else None
        rows.append(
            {
                "run": run.path.name,
                "task": land.get("task", run.task),
                "backend": land.get("backend", run.backend),
                "algo": land.get("algo", run.algo),
                "horizon": land.get("horizon", run.horizon),
                "seed": run.seed,
                "grid": land.get("grid"),
                "span": land.get("span"),
                "lambda": land.get("lambda"),
                "roughness_h_step": h_step,
                "roughness_td_lambda": td_lambda,
                "ratio_h_step_over_td_lambda": ratio,
            }
        )
    columns = ["run", "task", "backend", "algo", "horizon", "seed", "grid", "span", "lambda"]
    columns += ["roughness_h_step", "roughness_td_lambda", "ratio_h_step_over_td_lambda"]
    return pd.DataFrame(rows, columns=columns)


def step_gain_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Per run with a step_gain.json: its states, lambda and the summaries of its gains."""
    rows = []
    for run in sorted(runs, key=lambda r: (r.task, r.backend, rank(r.algo), r.horizon, r.seed)):
        gain = run.step_gain
        if gain is None or "summary" not in gain:
            continue
        summary, window = gain["summary"], gain.get("window") or {}
        rows.append(
            {
                "run": run.path.name,
                "task": run.task,
                "backend": run.backend,
                "algo": run.algo,
                "horizon": run.horizon,
                "seed": run.seed,
                "states": gain.get("states"),
                "lambda": gain.get("lambda"),
                "gain_median": summary["state_gain"]["median"],
                "gain_p95": summary["state_gain"]["p95"],
                "action_gain_median": summary["action_gain"]["median"],
                "window_growth": (window.get("per_step_growth") or {}).get("median"),
            }
        )
    columns = ["run", "task", "backend", "algo", "horizon", "seed", "states", "lambda", "gain_median", "gain_p95"]
    return pd.DataFrame(rows, columns=columns + ["action_gain_median", "window_growth"])


def check_summary(check: CheckRecord) -> str:
    """One line of a check's key numbers, as the kind that wrote it sums them up
    (:data:`harness.checks.kinds.BY_FILE_KIND`)."""
    from harness.checks.kinds import BY_FILE_KIND

    if check.kind in BY_FILE_KIND:
        return BY_FILE_KIND[check.kind].summary(check.result, check.kind)
    return "result keys: " + ", ".join(sorted(check.result)[:8])


def _check_backends(check: CheckRecord) -> str | None:
    r = check.result
    if r.get("backend"):
        return str(r["backend"])
    if r.get("backends"):
        return ", ".join(r["backends"])
    pairs = r.get("pairs") or next(iter((r.get("segments") or {}).values()), {}).get("pairs", {})
    names = sorted({name for pair in pairs for name in pair.split(" vs ")})
    return ", ".join(names) or None


def check_settings(check: CheckRecord) -> str | None:
    """What the check ran at besides the defaults: its ``--preset`` and ``--backend-option``s, read from
    the command it recorded (the checks' results do not all carry them), e.g. ``preset=rewarped`` or
    ``fd_scheme=forward, fd_eps_state=2e-3``; None at the defaults."""
    import shlex

    from harness.words import physics_words

    try:
        preset, options = physics_words(shlex.split(str(check.provenance.get("command") or "")))
    except ValueError:
        return None
    named = ([f"preset={preset}"] if preset else []) + options
    return ", ".join(named) or None


def checks_table(checks: list[CheckRecord]) -> pd.DataFrame:
    """Every check file in one line: kind, task, backend(s), the settings it ran at, pass/fail where the
    check decides one, key numbers."""
    rows = []
    for check in sorted(checks, key=lambda c: (c.kind, str(c.result.get("task")), c.path.name)):
        passed = check.result.get("passed", check.result.get("ok"))
        rows.append(
            {
                "file": check.path.name,
                "kind": check.kind,
                "task": check.result.get("task"),
                "backend": _check_backends(check),
                "settings": check_settings(check),
                "passed": passed if isinstance(passed, bool) else None,
                "summary": check_summary(check),
                "created_utc": check.provenance.get("created_utc"),
                "commit": check.provenance.get("git_commit"),
            }
        )
    columns = ["file", "kind", "task", "backend", "settings", "passed", "summary", "created_utc", "commit"]
    return pd.DataFrame(rows, columns=columns)
