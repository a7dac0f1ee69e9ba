"""Tables (Markdown and CSV) and seaborn plots of the benchmark suite (``python -m harness bench``).

:func:`write_bench_report` reads the suite's run directories and check files and writes into one folder:

Tables, each as ``NAME.md`` (title, provenance paragraph, what the numbers rest on, notes, table) and
``NAME.csv`` (plain comma-separated values, one header line, no comment lines, so any CSV reader takes it
as it is) with a sibling ``NAME.provenance.json``: ``{"table", "csv", "markdown", "title", "rests_on",
"notes", "columns", "input_commits", "provenance"}`` where ``provenance`` is the ``header`` given to
:func:`write_bench_report` (command, commit, UTC time, packages, machine, profile). A table with a second
part writes it as ``NAME_PART.csv`` (with its own ``.provenance.json``) and as a second section of ``NAME.md``.

* ``returns``: final evaluation return per (task, backend, algo, horizon): IQM over training seeds with a
  95% percentile-bootstrap CI, mean and std, initial return, and the IQM improvement over the base algorithm
  (``shac-tdadpt`` -> ``shac``) with a two-sample bootstrap CI (:func:`returns_table`);
* ``grad_variance_vs_h`` (+ ``_growth``): the actor-gradient variance against the horizon;
* ``wall_time``: the time split of every run; ``throughput``: env-steps/s of the throughput checks;
* ``backends``: one algorithm x task x horizon on every backend side by side;
* ``sim_to_sim`` (+ ``_mean``): a policy evaluated on another backend than it trained on;
* ``landscape``: the roughness of the h-step and TD-lambda actor losses (``harness/landscape.py``);
* ``checks``: every check file (gradcheck, throughput, crosscheck) in one line each.

Plots (PNG, matplotlib's Agg backend, one figure per file): ``learning_curves_steps``,
``learning_curves_wall``, ``grad_variance_vs_h``, ``lambda_alpha``, ``wall_time``, ``throughput`` and one
``landscape_*.png`` per landscape (``harness.landscape.plot_landscape``, when that module imports).
A plot without data is skipped (and a stale file of that name removed); ``index.md`` lists what was
written and what was skipped, and why.

Statistics. The interquartile mean (IQM) is ``scipy.stats.trim_mean(x, 0.25)``, the definition of
rliable (Agarwal et al. 2021). Its 95% CI is scipy's percentile bootstrap over training seeds with 2000
resamples. rliable's stratified bootstrap resamples seeds within each task; every row here is one task
and one backend, i.e. one stratum, so the stratified bootstrap is the plain bootstrap over seeds
(rliable 1.2.0 itself does not import with this project's pandas 3.1, hence scipy's implementation).
Every CI uses a fresh ``np.random.default_rng(0)``, so a row's CI depends on its own data only and the
tables are reproducible.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from harness.results import RunError, atomic_write_text, read_metrics, write_json

ALGO_ORDER = ("shac", "shac-tdfixed", "shac-tdadpt", "sapo", "sapo-tdfixed", "sapo-tdadpt")
VARIANT_SUFFIXES = ("-tdfixed", "-tdadpt")
BACKEND_ORDER = ("newton", "mujoco_warp")
IQM_TRIM = 0.25  # cut 25% at each end: the mean of the middle half (rliable's IQM)
BOOTSTRAP_RESAMPLES = 2000
CONFIDENCE = 0.95
BOOTSTRAP_SEED = 0
CURVE_POINTS = 100  # points of the common x grid of a learning curve; also the most epochs a lambda curve shows
CURVE_BOOTSTRAP = 200  # seaborn's resamples for a curve's band: a picture, not a table, and 2 CPU cores
SIM_TO_SIM_PREFIXES = ("eval_on_", "sim2sim_on_")  # `harness eval --backend` and the suite's sim-to-sim jobs

TIME_PARTS = (  # (column stem, label, metrics field)
    ("sim_forward", "sim forward", "sim_forward_s"),
    ("backward", "backward", "backward_s"),
    ("actor_update", "actor update", "actor_update_s"),
    ("critic_update", "critic update", "critic_update_s"),
    ("lambda_update", "lambda update", "lambda_update_s"),
    ("update_unsplit", "update (not split)", "update_s"),
    ("other", "other", None),
)


class NoPlotData(Exception):
    """A plot has nothing to show; the message says why."""


# -- inputs ---------------------------------------------------------------------------------------
@dataclass
class RunRecord:
    """What the report needs of one run directory."""

    path: Path
    task: str
    backend: str
    algo: str
    horizon: int
    seed: int
    num_envs: int | None
    metrics: pd.DataFrame
    evaluation: dict | None  # eval.json, None when missing (an unfinished run)
    cross_evaluations: dict[str, dict] = field(default_factory=dict)  # file name -> eval_on_*/sim2sim_on_* payload
    landscape: dict | None = None
    commit: str | None = None  # the commit the run was trained at (config.json's provenance)
    planned_epochs: int | None = None  # config.json's epochs: what the run was asked for (``epochs``: what it did)

    @property
    def base(self) -> str:
        return base_algo(self.algo)

    @property
    def group(self) -> tuple:
        """What a table row pools seeds over, in table order: the same task, backend, setting (envs, planned
        epochs), horizon and algorithm, so a 30-epoch h-sweep run never counts as a seed of a 100-epoch
        headline run."""
        return (self.task, self.backend, self.num_envs, self.planned_epochs, self.horizon, self.algo)

    @property
    def epochs(self) -> int:
        """Epochs completed (rows of metrics.jsonl)."""
        return len(self.metrics)

    @property
    def env_steps(self) -> int:
        return int(self.metrics["env_steps"].iloc[-1]) if self.epochs and "env_steps" in self.metrics else 0

    @property
    def wall_s(self) -> float:
        """Training wall time: the last row's cumulative ``wall_s`` (the sum of ``epoch_s`` where it is absent)."""
        if not self.epochs:
            return math.nan
        wall = _column(self.metrics, "wall_s")
        return float(wall.iloc[-1]) if np.isfinite(wall.iloc[-1]) else float(_column(self.metrics, "epoch_s").sum())

    @property
    def final_return(self) -> float | None:
        return self.evaluation["final"]["mean_return"] if self.evaluation else None

    @property
    def initial_return(self) -> float | None:
        return self.evaluation["initial"]["mean_return"] if self.evaluation else None


def base_algo(algo: str) -> str:
    """The algorithm a TD-lambda variant modifies: ``shac-tdadpt`` -> ``shac``; a base is its own base."""
    for suffix in VARIANT_SUFFIXES:
        if algo.endswith(suffix):
            return algo[: -len(suffix)]
    return algo


def collect_runs(root: Path) -> list[Path]:
    """Every directory under ``root`` (``root`` included) that holds a ``config.json``, sorted."""
    return sorted({p.parent for p in Path(root).rglob("config.json") if p.is_file()})


def _say(stream, message: str) -> None:
    print(f"[bench report] {message}", file=stream, flush=True)


def _read_json(path: Path, stream=sys.stdout) -> dict | None:
    """A JSON object file, or None when it is missing or unreadable (said on ``stream``)."""
    if not path.is_file():
        return None
    try:
        payload = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        _say(stream, f"ignored {path}: {exc}")
        return None
    if not isinstance(payload, dict):
        _say(stream, f"ignored {path}: not a JSON object")
        return None
    return payload


def _has_returns(payload: dict | None) -> bool:
    """An evaluation payload with a number for the initial and the final policy."""
    try:
        return all(isinstance(payload[k]["mean_return"], int | float) for k in ("initial", "final"))
    except (KeyError, TypeError):
        return False


def _column(frame: pd.DataFrame, name: str) -> pd.Series:
    """A metrics column as floats (null -> NaN); all NaN when the column is absent (older runs)."""
    if name not in frame:
        return pd.Series(np.nan, index=frame.index, dtype=float)
    return pd.to_numeric(frame[name], errors="coerce").astype(float)


def _task_label(task: str, config: dict) -> str:
    """The task as tables name it: ``ant`` on the task's default physics preset, ``ant.rewarped`` on
    another (as the suite names its run folders), so runs of two physics never pool as seeds of one row."""
    import tasks
    from simcore import UnknownNameError

    preset = (config.get("physics_record") or {}).get("preset")
    try:
        default = tasks.task_class(task).default_preset
    except UnknownNameError:  # a task this installation does not have: its name as recorded
        return task
    return task if preset in (None, default) else f"{task}.{preset}"


def load_run(run_dir: Path, stream=sys.stdout) -> RunRecord | None:
    """Read one run directory; None (said on ``stream``) when its config.json is missing or unusable."""
    run_dir = Path(run_dir)
    config = _read_json(run_dir / "config.json", stream)
    try:
        algo_cfg = config["algo"]
        task, backend, algo = str(config["task"]), str(config["backend"]), str(algo_cfg["algo"])
        horizon, seed = int(algo_cfg.get("horizon", 0)), int(config.get("seed", 0))
    except (KeyError, TypeError, ValueError):
        _say(stream, f"skipped {run_dir}: no usable config.json (task, backend, seed, algo.algo, algo.horizon)")
        return None
    try:
        rows = read_metrics(run_dir / "metrics.jsonl")
    except RunError as exc:
        _say(stream, f"{run_dir}: metrics ignored: {exc}")
        rows = []
    metrics = pd.DataFrame(rows)
    if "epoch" in metrics:
        # a resumed run may repeat the epochs after its last checkpoint: the later rows are the ones that count
        metrics = metrics.drop_duplicates("epoch", keep="last").sort_values("epoch").reset_index(drop=True)
    evaluation = _read_json(run_dir / "eval.json", stream)
    if evaluation is not None and not _has_returns(evaluation):
        _say(stream, f"{run_dir}/eval.json has no initial/final mean_return: counted as not evaluated")
        evaluation = None
    cross = {}
    for prefix in SIM_TO_SIM_PREFIXES:
        for path in sorted(run_dir.glob(f"{prefix}*.json")):
            payload = _read_json(path, stream)
            if _has_returns(payload):
                payload.setdefault("backend", path.stem[len(prefix) :])
                payload.setdefault("trained_on", backend)
                cross[path.name] = payload
    landscape = _read_json(run_dir / "landscape.json", stream)
    return RunRecord(
        path=run_dir,
        task=_task_label(task, config),
        backend=backend,
        algo=algo,
        horizon=horizon,
        seed=seed,
        num_envs=algo_cfg.get("num_envs"),
        metrics=metrics,
        evaluation=evaluation,
        cross_evaluations=cross,
        landscape=landscape,
        commit=(config.get("provenance") or {}).get("git_commit"),
        planned_epochs=_int_or_none(config.get("epochs", algo_cfg.get("max_epochs"))),
    )


def _int_or_none(value) -> int | None:
    try:
        return int(value)
    except (TypeError, ValueError):
        return None


@dataclass
class CheckRecord:
    """One check file: ``{"result": {...}, "provenance": {...}}`` (a crosscheck keeps its result at top level)."""

    path: Path
    kind: str
    result: dict
    provenance: dict


def _check_kind(name: str, result: dict) -> str:
    """gradcheck / throughput / crosscheck / forward-crosscheck from the result's keys, else the file's prefix."""
    if "max_rel_error" in result or "action_rel_error" in result:
        return "gradcheck"
    if "forward_steps_per_s" in result:
        return "throughput"
    if "segments" in result:
        return "crosscheck"
    if "gaps" in result and "holds" in result:
        return "parity"
    if "control_lifted" in result:
        return "contact-jacobians"
    if "skip_threshold" in result and "summary" in result:
        return "grad-paths"
    if "com" in result and "pairs" in result:
        return "forward-crosscheck"
    return name.split("_", 1)[0] if "_" in name else "unknown"


def load_check(path: Path, stream=sys.stdout) -> CheckRecord | None:
    payload = _read_json(Path(path), stream)
    if payload is None:
        if not Path(path).is_file():
            _say(stream, f"skipped check {path}: no such file")
        return None
    result = payload["result"] if isinstance(payload.get("result"), dict) else payload
    result = {k: v for k, v in result.items() if k != "provenance"}
    provenance = payload.get("provenance") if isinstance(payload.get("provenance"), dict) else {}
    return CheckRecord(path=Path(path), kind=_check_kind(Path(path).name, result), result=result, provenance=provenance)


# -- statistics -----------------------------------------------------------------------------------
def iqm(values: Iterable[float]) -> float:
    """Interquartile mean: the mean of the middle half (``scipy.stats.trim_mean(x, 0.25)``, as rliable)."""
    x = np.asarray(list(values), dtype=float)
    return float(stats.trim_mean(x, IQM_TRIM)) if x.size else math.nan


def _iqm_along(sample: np.ndarray, axis: int = -1) -> np.ndarray:
    return stats.trim_mean(sample, IQM_TRIM, axis=axis)


def _percentile_ci(samples: tuple[np.ndarray, ...], statistic) -> tuple[float, float]:
    """The 95% percentile-bootstrap interval of ``statistic`` (vectorised, ``axis``) over ``samples``,
    each resampled on its own (unpaired), with the report's fixed resamples and seed."""
    ci = stats.bootstrap(
        samples,
        statistic,
        vectorized=True,
        paired=False,
        n_resamples=BOOTSTRAP_RESAMPLES,
        confidence_level=CONFIDENCE,
        method="percentile",
        rng=np.random.default_rng(BOOTSTRAP_SEED),
    ).confidence_interval
    return float(ci.low), float(ci.high)


def iqm_with_ci(values: Iterable[float]) -> tuple[float, float, float]:
    """(IQM, CI low, CI high): 95% percentile bootstrap over the values (seeds); NaN bounds under 2 values."""
    x = np.asarray(list(values), dtype=float)
    point = iqm(x)
    if x.size < 2:
        return point, math.nan, math.nan
    return point, *_percentile_ci((x,), _iqm_along)


def iqm_difference_with_ci(variant: Iterable[float], base: Iterable[float]) -> tuple[float, float, float]:
    """IQM(variant) - IQM(base) with a 95% CI from a two-sample (unpaired) percentile bootstrap.

    Unpaired: seed s of a variant and seed s of its base share nothing but the number, so each sample is
    resampled on its own. NaN bounds when either side has fewer than 2 seeds.
    """
    v, b = np.asarray(list(variant), dtype=float), np.asarray(list(base), dtype=float)
    point = iqm(v) - iqm(b)
    if v.size < 2 or b.size < 2:
        return point, math.nan, math.nan
    return point, *_percentile_ci((v, b), lambda x, y, axis=-1: _iqm_along(x, axis) - _iqm_along(y, axis))


# -- grouping helpers -----------------------------------------------------------------------------
def _rank(name: str) -> tuple[int, str]:
    """Sort key of a name: algorithms in ALGO_ORDER, backends in BACKEND_ORDER (the reference engine
    first), anything else (tasks, unknown names) alphabetically after them."""
    known = ALGO_ORDER + BACKEND_ORDER
    return (known.index(name), "") if name in known else (len(known), name)


def _group_runs(runs: Iterable[RunRecord], key: Callable[[RunRecord], tuple]) -> dict[tuple, list[RunRecord]]:
    """Runs grouped by ``key``, groups in a stable order (algorithms in ALGO_ORDER), members by seed."""
    groups: dict[tuple, list[RunRecord]] = {}
    for run in runs:
        groups.setdefault(key(run), []).append(run)
    # element-wise: numbers (horizons, seeds) by value, names by _rank
    ordered = sorted(groups, key=lambda k: tuple((x, "") if isinstance(x, int) else _rank(str(x)) for x in k))
    return {k: sorted(groups[k], key=lambda r: (r.seed, str(r.path))) for k in ordered}


def _by_group(runs: Iterable[RunRecord]) -> dict[tuple, list[RunRecord]]:
    """Runs by :attr:`RunRecord.group`, ordered for tables."""
    return _group_runs(runs, lambda r: r.group)


def _value_or_range(values: Iterable) -> int | str | None:
    """The one value all members share, else ``"min-max"``."""
    distinct = sorted(set(values))
    if not distinct:
        return None
    return distinct[0] if len(distinct) == 1 else f"{distinct[0]}-{distinct[-1]}"


def _std(values: np.ndarray) -> float:
    return float(np.std(values, ddof=1)) if values.size > 1 else math.nan


# -- tables (pure functions of the records) -------------------------------------------------------
def returns_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Final evaluation return per (task, backend, num_envs, planned epochs, horizon, algo) over training seeds;
    runs without eval.json are left out. ``improvement_*``: IQM(algo) - IQM(base algo) in the same group but
    for the algorithm."""
    groups = _by_group(r for r in runs if r.evaluation is not None)
    finals = {key: np.array([r.final_return for r in members], dtype=float) for key, members in groups.items()}
    rows = []
    for (task, backend, num_envs, planned, horizon, algo), members in groups.items():
        final = finals[(task, backend, num_envs, planned, horizon, algo)]
        point, low, high = iqm_with_ci(final)
        base = base_algo(algo)
        base_final = finals.get((task, backend, num_envs, planned, horizon, base)) if base != algo else None
        gain = iqm_difference_with_ci(final, base_final) if base_final is not None else (math.nan,) * 3
        if base_final is not None and final.size + base_final.size > 2:
            spread = pooled_std([final, base_final])
            mde = minimum_detectable_difference(spread, final.size, base_final.size)
        else:
            mde = math.nan
        rows.append(
            {
                "task": task,
                "backend": backend,
                "algo": algo,
                "horizon": horizon,
                "num_envs": num_envs,
                "seeds": len(members),
                "epochs": _value_or_range(r.epochs for r in members),
                "env_steps": _value_or_range(r.env_steps for r in members),
                "eval_seeds": _value_or_range(r.evaluation.get("seeds") for r in members),
                "eval_num_envs": _value_or_range(r.evaluation.get("num_envs") for r in members),
                "iqm_final": point,
                "iqm_ci_low": low,
                "iqm_ci_high": high,
                "mean_final": float(final.mean()),
                "std_final": _std(final),
                "mean_initial": float(np.mean([r.initial_return for r in members])),
                "base": base if base != algo else None,
                "base_seeds": len(base_final) if base_final is not None else None,
                "improvement_iqm": gain[0],
                "improvement_ci_low": gain[1],
                "improvement_ci_high": gain[2],
                "mde_80": mde,
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
    "improvement_ci_low",
    "improvement_ci_high",
    "mde_80",
]


# -- statistical power ------------------------------------------------------------------------------
POWER = 0.8
ALPHA = 0.05
#: relative improvements over the base algorithm the paper reports (Ant +25-50%, Go2 about +100%)
EFFECTS = (0.25, 0.5, 1.0)


def pooled_std(samples: Iterable[np.ndarray]) -> float:
    """The within-sample standard deviation pooled over samples (each weighted by its n - 1)."""
    samples = [np.asarray(x, dtype=float) for x in samples]
    dof = sum(x.size - 1 for x in samples if x.size > 1)
    if dof < 1:
        return math.nan
    return math.sqrt(sum(((x - x.mean()) ** 2).sum() for x in samples if x.size > 1) / dof)


def minimum_detectable_difference(spread: float, n1: int, n2: int) -> float:
    """The smallest true difference of means a two-sided two-sample t-test (level ALPHA) detects with
    probability POWER, for seeds of standard deviation ``spread``: (t_(1-a/2) + t_power) s sqrt(1/n1 + 1/n2)
    at n1 + n2 - 2 degrees of freedom (the usual normal-shift approximation of the t-test's power)."""
    dof = n1 + n2 - 2
    if dof < 1 or not math.isfinite(spread):
        return math.nan
    t = stats.t.ppf(1 - ALPHA / 2, dof) + stats.t.ppf(POWER, dof)
    return float(t * spread * math.sqrt(1 / n1 + 1 / n2))


def seeds_needed(spread: float, difference: float, limit: int = 10_000) -> int | None:
    """Seeds per algorithm for :func:`minimum_detectable_difference` to reach ``difference``; None when
    the spread is unknown or more than ``limit`` would be needed."""
    if not (math.isfinite(spread) and math.isfinite(difference) and difference > 0):
        return None
    for n in range(2, limit + 1):
        if minimum_detectable_difference(spread, n, n) <= difference:
            return n
    return None


def power_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Per (task, backend, num_envs, planned epochs, horizon) with evaluated runs: the between-seed spread
    of the final return pooled over its algorithms, the base algorithms' mean return, and the seeds per
    algorithm a two-sample test needs to detect each relative improvement in EFFECTS at POWER."""
    groups = _by_group(r for r in runs if r.evaluation is not None)
    settings: dict[tuple, dict[str, np.ndarray]] = {}
    for (task, backend, num_envs, planned, horizon, algo), members in groups.items():
        finals = np.array([r.final_return for r in members], dtype=float)
        settings.setdefault((task, backend, num_envs, planned, horizon), {})[algo] = finals
    rows = []
    for (task, backend, num_envs, planned, horizon), by_algo in settings.items():
        spread = pooled_std(by_algo.values())
        bases = [x for a, x in by_algo.items() if base_algo(a) == a]
        base_mean = float(np.mean(np.concatenate(bases))) if bases else math.nan
        row = {"task": task, "backend": backend, "num_envs": num_envs, "epochs": planned, "horizon": horizon}
        row |= {"algos": len(by_algo), "seeds": _value_or_range(x.size for x in by_algo.values())}
        row |= {"pooled_std": spread, "base_mean": base_mean}
        row["cv"] = spread / abs(base_mean) if base_mean else math.nan
        for effect in EFFECTS:
            row[f"seeds_for_{round(effect * 100)}pct"] = seeds_needed(spread, effect * abs(base_mean))
        rows.append(row)
    columns = ["task", "backend", "num_envs", "epochs", "horizon", "algos", "seeds", "pooled_std", "base_mean", "cv"]
    columns += [f"seeds_for_{round(e * 100)}pct" for e in EFFECTS]
    return pd.DataFrame(rows, columns=columns)


#: the two gradient statistics every variance table and plot shows (algorithms/grad_variance.py):
#: (metric logged per epoch, column stem, label)
GRAD_STATISTICS = (
    ("actor_grad_var", "var", "raw variance Var_K (scales with the loss squared)"),
    ("actor_grad_nsr", "nsr", "noise-to-signal Var_K / S (scale-free)"),
)


def geometric_mean_with_ci(values: Iterable[float]) -> tuple[float, float, float]:
    """(geometric mean, CI low, CI high): 95% percentile bootstrap of the mean of log values over seeds.
    A zero or +inf value makes the mean 0 or +inf (a statistic some seed did not resolve); NaN bounds
    under 2 values."""
    x = np.asarray(list(values), dtype=float)
    if not x.size:
        return math.nan, math.nan, math.nan
    with np.errstate(divide="ignore"):
        logs = np.log(x)
    point = float(np.exp(logs.mean()))
    if x.size < 2 or not np.isfinite(logs).all():
        return point, math.nan, math.nan
    low, high = _percentile_ci((logs,), np.mean)
    return point, math.exp(low), math.exp(high)


def ratio_of_geometric_means_with_ci(high: Iterable[float], low: Iterable[float]) -> tuple[float, float, float]:
    """gmean(high) / gmean(low) with a 95% CI from a two-sample (unpaired) percentile bootstrap of the
    difference of mean logs; NaN bounds when a side has fewer than 2 finite positive values."""
    h, lo = np.asarray(list(high), dtype=float), np.asarray(list(low), dtype=float)
    if not (h.size and lo.size):
        return math.nan, math.nan, math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        lh, ll = np.log(h), np.log(lo)
        point = float(np.exp(lh.mean() - ll.mean()))
    if h.size < 2 or lo.size < 2 or not (np.isfinite(lh).all() and np.isfinite(ll).all()):
        return point, math.nan, math.nan
    low, high = _percentile_ci((lh, ll), lambda x, y, axis=-1: np.mean(x, axis=axis) - np.mean(y, axis=axis))
    return point, math.exp(low), math.exp(high)


def _seed_medians(members: list[RunRecord], metric: str) -> np.ndarray:
    """Each run's median of ``metric`` over its epochs (NaN epochs, skipped updates, dropped; +inf kept);
    runs that never logged it (from before the statistic existed) are left out."""
    medians = []
    for run in members:
        column = _column(run.metrics, metric).to_numpy(dtype=float)
        column = column[~np.isnan(column)]
        if column.size:
            medians.append(float(np.median(column)))
    return np.asarray(medians, dtype=float)


def grad_variance_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Per group and gradient statistic (GRAD_STATISTICS): the median and quartiles of every epoch of
    every seed pooled (finite values), and the geometric mean over seeds of each seed's median with its
    95% bootstrap CI (``{stem}_seeds``: how many seeds logged the statistic)."""
    rows = []
    for (task, backend, num_envs, planned, horizon, algo), members in _by_group(r for r in runs if r.epochs).items():
        row = {
            "task": task,
            "backend": backend,
            "algo": algo,
            "num_envs": num_envs,
            "epochs": planned,
            "horizon": horizon,
            "seeds": len(members),
        }
        for metric, stem, _ in GRAD_STATISTICS:
            pooled = np.concatenate([_column(r.metrics, metric).to_numpy(dtype=float) for r in members])
            pooled = pooled[np.isfinite(pooled)]
            q1, median, q3 = np.percentile(pooled, [25, 50, 75]) if pooled.size else (math.nan,) * 3
            per_seed = _seed_medians(members, metric)
            gmean, low, high = geometric_mean_with_ci(per_seed)
            prefix = "" if stem == "var" else f"{stem}_"
            row |= {f"{prefix}values": int(pooled.size), f"{prefix}median": float(median)}
            row |= {f"{prefix}q1": float(q1), f"{prefix}q3": float(q3)}
            row |= {f"{stem}_seeds": int(per_seed.size), f"{stem}_gmean": gmean}
            row |= {f"{stem}_ci_low": low, f"{stem}_ci_high": high}
        rows.append(row)
    columns = ["task", "backend", "algo", "num_envs", "epochs", "horizon", "seeds"]
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
    groups = _by_group(r for r in runs if r.epochs)
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
                lo = np.concatenate([_column(r.metrics, metric).to_numpy(dtype=float) for r in by_h[base]])
                hi = np.concatenate([_column(r.metrics, metric).to_numpy(dtype=float) for r in by_h[top]])
                lo, hi = lo[np.isfinite(lo)], hi[np.isfinite(hi)]
                med_lo = float(np.median(lo)) if lo.size else math.nan
                med_hi = float(np.median(hi)) if hi.size else math.nan
                if stem == "var":
                    row |= {"median_h_min": med_lo, "median_h_max": med_hi}
                    row["growth_factor"] = med_hi / med_lo if med_lo else math.nan
                point, low, high = ratio_of_geometric_means_with_ci(
                    _seed_medians(by_h[top], metric), _seed_medians(by_h[base], metric)
                )
                row |= {f"{stem}_growth": point, f"{stem}_growth_ci_low": low, f"{stem}_growth_ci_high": high}
            rows.append(row)
    columns = [
        *("task", "backend", "algo", "num_envs", "epochs"),
        *("h_min", "h_max", "median_h_min", "median_h_max", "growth_factor"),
    ]
    columns += [f"{stem}_growth{c}" for _, stem, _ in GRAD_STATISTICS for c in ("", "_ci_low", "_ci_high")]
    return pd.DataFrame(rows, columns=columns)


def time_split(run: RunRecord) -> dict[str, float]:
    """Seconds of each TIME_PARTS stem summed over the run's epochs.

    Epochs that logged actor/critic/lambda update times count them; epochs that did not (runs from before
    the split was logged) count their whole ``update_s`` as ``update_unsplit``. ``other`` is the rest of
    the wall time (rollout bookkeeping, logging, checkpoints).
    """
    m = run.metrics
    split = _column(m, "actor_update_s").notna()
    seconds = {
        "sim_forward": float(_column(m, "sim_forward_s").sum()),
        "backward": float(_column(m, "backward_s").sum()),
        "actor_update": float(_column(m, "actor_update_s")[split].sum()),
        "critic_update": float(_column(m, "critic_update_s")[split].sum()),
        "lambda_update": float(_column(m, "lambda_update_s")[split].sum()),
        "update_unsplit": float(_column(m, "update_s")[~split].sum()),
    }
    seconds["other"] = max(run.wall_s - sum(seconds.values()), 0.0) if np.isfinite(run.wall_s) else math.nan
    return seconds


def wall_time_table(runs: list[RunRecord]) -> pd.DataFrame:
    """Per run: wall minutes, seconds per epoch and the split of the wall time, in minutes and fractions."""
    rows = []
    for members in _by_group(r for r in runs if r.epochs).values():
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
    """Per throughput check file: env-steps/s forward, forward+backward, and of the bare engine."""
    rows = []
    for check in checks:
        if check.kind != "throughput":
            continue
        r = check.result
        measured = r.get("forward_backward_steps_per_s")
        estimated = r.get("forward_backward_steps_per_s_estimated")  # `throughput --grad-cost-only`
        rows.append(
            {
                "file": check.path.name,
                "backend": r.get("backend"),
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
            }
        )
    columns = [
        "file",
        "backend",
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
    ]
    rows.sort(key=lambda r: (_rank(str(r["task"])), _rank(str(r["backend"])), r["num_envs"] or 0, r["file"]))
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
    column = _column(run.metrics, "actor_update_skipped")
    return float(column.astype(float).mean()) if len(column) and column.notna().all() else math.nan


def backends_table(runs: list[RunRecord]) -> pd.DataFrame:
    """One row per (task, algo, horizon, num_envs, planned epochs) trained on at least 2 backends, columns
    ``BACKEND_MEASURE`` per backend.

    ``seeds`` counts every run (wall time is known without an evaluation); ``iqm_final`` rests on the
    evaluated ones.
    """
    long_rows = []
    for (task, num_envs, planned, horizon, algo, backend), members in _group_runs(
        (r for r in runs if r.epochs), lambda r: (r.task, r.num_envs, r.planned_epochs, r.horizon, r.algo, r.backend)
    ).items():
        evaluated = [r.final_return for r in members if r.evaluation is not None]
        gains = [r.final_return - r.initial_return for r in members if r.evaluation is not None]
        norms = _seed_medians(members, "actor_grad_norm")
        long_rows.append(
            {
                "task": task,
                "algo": algo,
                "horizon": horizon,
                "num_envs": num_envs,
                "planned_epochs": planned,
                "backend": backend,
                "seeds": len(members),
                "epochs": _value_or_range(r.epochs for r in members),
                "env_steps": _value_or_range(r.env_steps for r in members),
                "iqm_final": iqm(evaluated),
                "gain_mean": float(np.mean(gains)) if gains else math.nan,
                "skipped_pct": 100.0 * float(np.nanmean([_skipped_fraction(r) for r in members])),
                "grad_norm_median": float(np.median(norms)) if norms.size else math.nan,
                "wall_min_mean": float(np.mean([r.wall_s for r in members])) / 60.0,
                "s_per_epoch_mean": float(np.mean([r.wall_s / r.epochs for r in members])),
            }
        )
    keys = ["task", "algo", "horizon", "num_envs", "planned_epochs"]
    long = pd.DataFrame(long_rows, columns=[*keys, "backend", *BACKEND_MEASURES])
    backends = sorted(long["backend"].unique(), key=_rank)
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
    for run in sorted(runs, key=lambda r: (r.task, _rank(r.algo), r.horizon, r.seed, r.backend)):
        for name, other in run.cross_evaluations.items():
            evaluated_on, trained_on = other["backend"], other.get("trained_on", run.backend)
            if evaluated_on == trained_on:
                continue  # the same-protocol evaluation on the training backend: a reference, not a row
            prefix = next(p for p in SIM_TO_SIM_PREFIXES if name.startswith(p))
            own_name = f"{prefix}{trained_on}.json"
            if own_name in run.cross_evaluations:
                own, own_source = run.cross_evaluations[own_name], own_name
            elif run.evaluation is not None:
                own, own_source = run.evaluation, "eval.json"
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
    for run in sorted(runs, key=lambda r: (r.task, r.backend, _rank(r.algo), r.horizon, r.seed)):
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


def _pairs_summary(pairs: dict, fields: tuple[str, str]) -> tuple[float | None, float | None]:
    """(min of fields[0], max of fields[1]) over every comparison nested in ``pairs``."""
    cosines, diffs = [], []

    def walk(node):
        if isinstance(node, dict):
            if fields[0] in node and isinstance(node[fields[0]], int | float):
                cosines.append(node[fields[0]])
            if fields[1] in node and isinstance(node[fields[1]], int | float):
                diffs.append(node[fields[1]])
            for value in node.values():
                walk(value)

    walk(pairs)
    return (min(cosines) if cosines else None), (max(diffs) if diffs else None)


_GRADCHECK_FIELDS = (
    ("tolerance", "tolerance"),
    ("action_rel_error", "actions"),
    ("state_rel_error", "initial state"),
    ("steps", "steps"),
    ("segment", "segment"),
)


def check_summary(check: CheckRecord) -> str:
    """One line of a check's key numbers."""
    r = check.result
    if check.kind == "gradcheck":
        parts = [f"max rel. error {_fmt(r.get('max_rel_error'))}"]
        parts += [f"{label} {_fmt(r[key])}" for key, label in _GRADCHECK_FIELDS if r.get(key) is not None]
        return ", ".join(parts)
    if check.kind == "throughput":
        fb = r.get("forward_backward_steps_per_s", r.get("forward_backward_steps_per_s_estimated"))
        return f"{_fmt(r.get('forward_steps_per_s'))} env-steps/s forward, {_fmt(fb)} with gradients"
    if check.kind == "crosscheck":
        cosine, rel_diff = _pairs_summary(r.get("segments", {}), ("cosine", "rel_diff"))
        return f"gradients across backends: min cosine {_fmt(cosine)}, max rel. difference {_fmt(rel_diff)}"
    if check.kind == "parity":
        g = r.get("gaps", {})
        return (
            f"engines: settle height gap {_fmt(g.get('settle_height_m'))} m, joint gap "
            f"{_fmt(g.get('settle_joint_rad'))} rad, first-episode length gap {_fmt(g.get('episode_length_rel'))} "
            "(relative)"
        )
    if check.kind == "contact-jacobians":
        a, c = r.get("all", {}), r.get("control_lifted", {})
        return (
            f"Jacobians at {a.get('states')} states in contact: median rel. error {_fmt(a.get('median_rel_error'))}, "
            f"{_pct(a.get('within_20pct'))} within 20%; lifted control {_fmt(c.get('median_rel_error'))}"
            + (f"; median state gain {_fmt(a['median_state_gain'])}" if "median_state_gain" in a else "")
        )
    if check.kind == "grad-paths":
        s = r.get("summary", {})
        parts = [
            f"{label} {_fmt(v.get('median_norm'))} ({v.get('above_skip_threshold')} skipped)" for label, v in s.items()
        ]
        return f"{r.get('algo')} actor-gradient norms, median over {r.get('epochs')} epochs: " + ", ".join(parts)
    if check.kind == "forward-crosscheck":
        _, gap = _pairs_summary(r.get("pairs", {}), ("", "com_distance_max"))
        return f"forward rollouts across backends: max centre-of-mass distance {_fmt(gap)} m, {r.get('steps')} steps"
    return "result keys: " + ", ".join(sorted(r)[:8])


def _check_backends(check: CheckRecord) -> str | None:
    r = check.result
    if r.get("backend"):
        return str(r["backend"])
    if r.get("backends"):
        return ", ".join(r["backends"])
    pairs = r.get("pairs") or next(iter((r.get("segments") or {}).values()), {}).get("pairs", {})
    names = sorted({name for pair in pairs for name in pair.split(" vs ")})
    return ", ".join(names) or None


def checks_table(checks: list[CheckRecord]) -> pd.DataFrame:
    """Every check file in one line: kind, task, backend(s), pass/fail where the check decides one, key numbers."""
    rows = []
    for check in sorted(checks, key=lambda c: (c.kind, str(c.result.get("task")), c.path.name)):
        passed = check.result.get("passed", check.result.get("ok"))
        rows.append(
            {
                "file": check.path.name,
                "kind": check.kind,
                "task": check.result.get("task"),
                "backend": _check_backends(check),
                "passed": passed if isinstance(passed, bool) else None,
                "summary": check_summary(check),
                "created_utc": check.provenance.get("created_utc"),
                "commit": check.provenance.get("git_commit"),
            }
        )
    columns = ["file", "kind", "task", "backend", "passed", "summary", "created_utc", "commit"]
    return pd.DataFrame(rows, columns=columns)


# -- Markdown and CSV -----------------------------------------------------------------------------
def _is_missing(value) -> bool:
    """None, NaN (any float type), pd.NA or NaT."""
    try:
        return value is None or bool(pd.isna(value))
    except (TypeError, ValueError):  # a list or array cell
        return False


def _fmt(value) -> str:
    """A table cell: n/a for missing, yes/no for booleans, about 4 significant digits for floats."""
    if _is_missing(value):
        return "n/a"
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        magnitude = abs(float(value))
        if magnitude == 0.0:
            return "0"
        if magnitude >= 1e6 or magnitude < 1e-3:
            return f"{value:.3g}"
        return f"{value:.1f}" if magnitude >= 100 else f"{value:.3g}" if magnitude < 1 else f"{value:.2f}"
    return str(value)


def _ci(low, high) -> str:
    return "n/a" if _is_missing(low) or _is_missing(high) else f"[{_fmt(low)}, {_fmt(high)}]"


def _verdict(passed) -> str:
    return "n/a" if _is_missing(passed) else ("PASS" if passed else "FAIL")


def _base_cell(row: pd.Series) -> str:
    if not isinstance(row["base"], str):
        return "-"
    return row["base"] if not _is_missing(row["base_seeds"]) else f"{row['base']} (no runs)"


def _pct(value) -> str:
    return "n/a" if _is_missing(value) else f"{100.0 * value:.0f}%"


ColumnSpec = list[tuple[str, str | Callable[[pd.Series], str]]]  # (header, column name or row -> cell)


@dataclass
class Section:
    """One table: its rows, how the Markdown shows them, and the suffix of its CSV (``""``: ``NAME.csv``)."""

    frame: pd.DataFrame
    columns: ColumnSpec
    heading: str | None = None
    csv_suffix: str = ""
    empty: str = "none"


@dataclass
class Table:
    name: str
    title: str
    rests_on: str
    sections: list[Section]
    notes: list[str] = field(default_factory=list)
    input_commits: list[str] = field(default_factory=list)


def markdown_rows(frame: pd.DataFrame, columns: ColumnSpec) -> list[str]:
    """A Markdown table of ``frame`` as ``columns`` say."""
    lines = ["| " + " | ".join(h for h, _ in columns) + " |", "|" + "---|" * len(columns)]
    for _, row in frame.iterrows():
        cells = [how(row) if callable(how) else _fmt(row[how]) for _, how in columns]
        lines.append("| " + " | ".join(cell.replace("|", "/") for cell in cells) + " |")
    return lines


def header_lines(header: dict) -> list[str]:
    """The provenance paragraph of every Markdown table: command, commit, UTC time, packages, machine."""
    commit = header.get("commit") or header.get("git_commit") or "unknown"
    profile = f" (profile `{header['profile']}`)" if header.get("profile") else ""
    spec = f" from `{header['spec']}`" if header.get("spec") else ""
    lines = [
        f"Made by: `{header.get('command', 'unknown')}`{profile}{spec}, commit `{commit}`, "
        f"{header.get('created_utc', 'time unknown')}."
    ]
    packages = header.get("packages") or {}
    listed = ", ".join(f"{name} {version or '(not installed)'}" for name, version in packages.items())
    python = f"; Python {header['python']}" if header.get("python") else ""
    lines.append(f"Packages: {listed or 'not recorded'}{python}.")
    lines.append(f"Machine: {machine_text(header.get('machine') or {})}.")
    return lines


def machine_text(machine: dict) -> str:
    if not machine:
        return "not recorded"
    parts = [str(machine.get("cpu_model", "CPU unknown"))]
    if machine.get("cpu_count") is not None:
        parts.append(f"{machine['cpu_count']} CPUs")
    if machine.get("platform"):
        parts.append(str(machine["platform"]))
    if machine.get("torch_num_threads") is not None:
        parts.append(f"torch threads {machine['torch_num_threads']}")
    parts.append(f"OMP_NUM_THREADS={machine.get('OMP_NUM_THREADS')}")
    parts.append("GPUs: " + (", ".join(machine.get("gpus") or []) or "none"))
    return ", ".join(parts)


def _commits(values: Iterable[str | None]) -> list[str]:
    counts = Counter(v or "unknown" for v in values)
    return [f"{commit} ({n})" for commit, n in counts.most_common()]


def markdown_document(table: Table, header: dict) -> str:
    lines = [f"# {table.title}", "", *header_lines(header), "", table.rests_on]
    if table.input_commits:
        lines[-1] += f" Inputs made at commit(s), with how many files: {', '.join(table.input_commits)}."
    for note in table.notes:
        lines += ["", note]
    for section in table.sections:
        lines.append("")
        if section.heading:
            lines += [f"## {section.heading}", ""]
        if section.frame.empty:
            lines.append(f"No rows: {section.empty}.")
        else:
            lines += markdown_rows(section.frame, section.columns)
    return "\n".join(lines) + "\n"


def write_table(table: Table, out_dir: Path, header: dict) -> list[Path]:
    """``NAME.md``, and per section ``NAME[SUFFIX].csv`` with ``NAME[SUFFIX].provenance.json`` beside it."""
    written = [atomic_write_text(out_dir / f"{table.name}.md", markdown_document(table, header))]
    for section in table.sections:
        stem = f"{table.name}{section.csv_suffix}"
        csv_text = section.frame.to_csv(index=False, lineterminator="\n")
        written.append(atomic_write_text(out_dir / f"{stem}.csv", csv_text))
        sidecar = {
            "table": stem,
            "csv": f"{stem}.csv",
            "markdown": f"{table.name}.md",
            "title": table.title + (f": {section.heading}" if section.heading else ""),
            "rests_on": table.rests_on,
            "notes": table.notes,
            "columns": list(section.frame.columns),
            "input_commits": table.input_commits,
            "provenance": header,
        }
        written.append(write_json(out_dir / f"{stem}.provenance.json", sidecar))
    return written


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _range_text(values: Iterable) -> str:
    distinct = sorted(set(values))
    if not distinct:
        return "n/a"
    return f"{distinct[0]:,}" if len(distinct) == 1 else f"{distinct[0]:,}-{distinct[-1]:,}"


def rests_on_runs(runs: list[RunRecord], what: str = "training runs") -> str:
    """The sentence saying what a table's numbers rest on: runs, groups, seeds, epochs, env steps."""
    if not runs:
        return f"Rests on no {what}."
    seeds_per_group = Counter(r.group for r in runs).values()
    return (
        f"Rests on {len(runs)} {what} in {len(seeds_per_group)} (task, backend, algo, h, N, planned epochs) groups "
        f"with {_range_text(seeds_per_group)} training seeds each, {_range_text(r.epochs for r in runs)} epochs and "
        f"{_range_text(r.env_steps for r in runs)} env steps per run."
    )


# -- the tables as documents ----------------------------------------------------------------------
def _key_columns(*names: str) -> ColumnSpec:
    labels = {"horizon": "h", "env_steps": "env steps per run", "num_envs": "N"}
    return [(labels.get(n, n), n) for n in names]


def _run_commits(runs: Iterable[RunRecord]) -> list[str]:
    return _commits(r.commit for r in runs)


def _whole(column: str):
    """A cell of whole numbers from a column that pandas holds as floats (it has missing values)."""
    return lambda r: "n/a" if _is_missing(r[column]) else str(int(r[column]))


def returns_document(runs: list[RunRecord]) -> Table:
    """Final evaluation returns: IQM, CI and improvement over the base algorithm."""
    evaluated = [r for r in runs if r.evaluation is not None]
    returns = returns_table(runs)
    eval_protocol = ""
    if evaluated:
        eval_protocol = (
            f" Each run's final (and initial) policy is evaluated deterministically over "
            f"{_range_text(r.evaluation.get('seeds') or 0 for r in evaluated)} eval seeds x "
            f"{_range_text(r.evaluation.get('num_envs') or 0 for r in evaluated)} envs, first episode of each env."
        )
    return Table(
        "returns",
        "Final evaluation return per algorithm",
        rests_on_runs(evaluated, "evaluated training runs") + eval_protocol,
        [
            Section(
                returns,
                _key_columns("task", "backend", "algo", "horizon", "num_envs", "seeds", "epochs", "env_steps")
                + [
                    ("IQM final", "iqm_final"),
                    ("95% CI", lambda r: _ci(r["iqm_ci_low"], r["iqm_ci_high"])),
                    ("mean ± std", lambda r: f"{_fmt(r['mean_final'])} ± {_fmt(r['std_final'])}"),
                    ("initial (mean)", "mean_initial"),
                    ("vs base", _base_cell),
                    ("IQM improvement", "improvement_iqm"),
                    ("improvement 95% CI", lambda r: _ci(r["improvement_ci_low"], r["improvement_ci_high"])),
                    ("detectable at 80% power", "mde_80"),
                ],
                empty="no run has an eval.json",
            ),
            Section(
                power_table(runs),
                _key_columns("task", "backend", "num_envs", "epochs", "horizon", "algos", "seeds")
                + [
                    ("between-seed std (pooled)", "pooled_std"),
                    ("base algorithms' mean", "base_mean"),
                    ("std / base mean", "cv"),
                ]
                + [(f"seeds for +{round(e * 100)}%", _whole(f"seeds_for_{round(e * 100)}pct")) for e in EFFECTS],
                heading="Statistical power: seeds per algorithm needed to detect an improvement",
                csv_suffix="_power",
                empty="no run has an eval.json",
            ),
        ],
        [
            "IQM: interquartile mean over training seeds (`scipy.stats.trim_mean(x, 0.25)`, rliable's "
            "definition), each seed contributing its eval.json final mean return; under 4 seeds it trims "
            "nothing and is the mean. 95% CI: percentile bootstrap over seeds, "
            f"{BOOTSTRAP_RESAMPLES} resamples, `np.random.default_rng({BOOTSTRAP_SEED})` "
            "(`scipy.stats.bootstrap`; one task and backend per row is one stratum, so rliable's stratified "
            "bootstrap is this plain one). n/a under 2 seeds. mean ± std: sample std (n - 1).",
            "IQM improvement: IQM(algo) - IQM(base) at the same task, backend, h, N and epochs (base of shac-tdfixed "
            "and shac-tdadpt is shac, of sapo-tdfixed and sapo-tdadpt sapo), 95% CI from a two-sample unpaired "
            "percentile bootstrap (each algorithm's seeds resampled on their own), n/a under 2 seeds on a side.",
            "Detectable at 80% power: the smallest true difference of mean final returns between the algorithm "
            "and its base that a two-sided two-sample t-test at level 0.05 detects with probability 0.8 at the "
            "seeds they have, (t_0.975 + t_0.8) s sqrt(1/n1 + 1/n2), s the pair's pooled between-seed std; an "
            "improvement below it is not evidence either way. Power table: the std pooled over every algorithm "
            "of a setting, and the seeds per algorithm at which that test detects +25%, +50% and +100% of the base "
            "algorithms' (shac, sapo) mean return (blank: over 10,000).",
            "Runs without eval.json (unfinished) are left out of this table.",
        ],
        _run_commits(evaluated),
    )


def grad_variance_document(runs: list[RunRecord]) -> Table:
    """Both actor-gradient statistics per horizon, and their growth from the shortest horizon to the longest."""
    trained = [r for r in runs if r.epochs]
    per_h = grad_variance_table(runs)

    def with_ci(stem):
        return lambda r: f"{_fmt(r[stem + '_gmean'])} [{_fmt(r[stem + '_ci_low'])}, {_fmt(r[stem + '_ci_high'])}]"

    def growth(stem):
        return lambda r: (
            f"{_fmt(r[stem + '_growth'])} [{_fmt(r[stem + '_growth_ci_low'])}, {_fmt(r[stem + '_growth_ci_high'])}]"
        )

    return Table(
        "grad_variance_vs_h",
        "Actor-gradient variance against the horizon h: raw and scale-free",
        rests_on_runs(trained),
        [
            Section(
                per_h,
                _key_columns("task", "backend", "algo", "num_envs", "epochs", "horizon", "seeds")
                + [
                    ("raw: seeds' gmean [95% CI]", with_ci("var")),
                    ("raw: pooled median", "median"),
                    ("raw: Q1", "q1"),
                    ("raw: Q3", "q3"),
                    ("NSR: seeds", "nsr_seeds"),
                    ("NSR: seeds' gmean [95% CI]", with_ci("nsr")),
                    ("NSR: pooled median", "nsr_median"),
                ],
                empty="no run has metrics",
            ),
            Section(
                grad_variance_growth_table(runs),
                _key_columns("task", "backend", "algo", "num_envs", "epochs")
                + [
                    ("from h", "h_min"),
                    ("to h", "h_max"),
                    ("raw growth [95% CI]", growth("var")),
                    ("raw growth, pooled medians", "growth_factor"),
                    ("NSR growth [95% CI]", growth("nsr")),
                ],
                heading="Growth from the shortest horizon (and from h 32) to the longest",
                csv_suffix="_growth",
                empty="no algorithm has runs at more than one horizon",
            ),
        ],
        [
            "raw: actor_grad_var, the trace of the K group gradients' covariance; it scales with the square of "
            "the loss, so it also measures the loss's size (actor_reward_weight). NSR: actor_grad_nsr, that "
            "variance over the bias-corrected squared norm of the mean gradient; unchanged by the loss's scale "
            "(docs/gradient-statistics.md). Seeds' gmean: the geometric mean over training seeds of each seed's "
            "median over epochs, with a 95% percentile bootstrap CI over seeds; inf when a seed's median NSR is "
            "unresolved (inf). Pooled median, Q1, Q3: every finite epoch of every seed. Growth: the ratio of "
            "the seeds' geometric means at the longest h to the shortest (and to h 32), with an unpaired "
            "bootstrap CI; 'pooled medians' is the same ratio of pooled medians. A row pools only runs of one "
            "setting (N envs, planned epochs). Runs from before the scale-free statistic have no NSR "
            "(NSR: seeds counts the runs that logged it)."
        ],
        _run_commits(trained),
    )


def wall_time_document(runs: list[RunRecord]) -> Table:
    """Wall time per run and its split."""
    trained = [r for r in runs if r.epochs]
    wall = wall_time_table(runs)
    split_columns = [
        (label, lambda r, s=stem: f"{_fmt(r[s + '_min'])} ({_pct(r[s + '_frac'])})") for stem, label, _ in TIME_PARTS
    ]
    return Table(
        "wall_time",
        "Wall time of every training run and where it goes",
        rests_on_runs(trained),
        [
            Section(
                wall,
                _key_columns("run", "task", "backend", "algo", "horizon", "num_envs", "seed", "epochs")
                + [("wall min", "wall_min"), ("s / epoch", "s_per_epoch")]
                + split_columns,
                empty="no run has metrics",
            )
        ],
        [
            "Minutes summed over epochs (share of the wall time in brackets). Actor update includes gradient "
            "clipping, the variance estimate and SAPO's temperature step. Epochs logged before the update "
            "was split count their whole update as 'update (not split)'. Other: the rest of the wall time "
            "(rollout bookkeeping, logging, checkpoints). Evaluation is not part of the wall time."
        ],
        _run_commits(trained),
    )


def throughput_document(checks: list[CheckRecord]) -> Table:
    """env-steps/s of the throughput checks."""
    throughput_checks = [c for c in checks if c.kind == "throughput"]
    return Table(
        "throughput",
        "Simulation throughput per backend and task",
        f"Rests on {_count(len(throughput_checks), 'throughput check file')}.",
        [
            Section(
                throughput_table(checks),
                _key_columns("task", "backend", "num_envs", "horizon", "windows", "file")
                + [
                    ("forward env-steps/s", "forward_steps_per_s"),
                    (
                        "forward+backward env-steps/s",
                        lambda r: (
                            _fmt(r["forward_backward_steps_per_s"])
                            + (" (estimated)" if r["forward_backward_estimated"] else "")
                        ),
                    ),
                    ("bare engine forward", "bare_forward_steps_per_s"),
                    ("bare engine forward+backward", "bare_engine_steps_per_s"),
                    ("adapter/bare time, forward", "forward_overhead_ratio"),
                    ("adapter/bare time, forward+backward", "overhead_ratio"),
                    ("gradient cost factor", "gradient_cost_factor"),
                ],
                empty="no throughput check",
            )
        ],
        [
            "env-steps/s = envs x steps / seconds, best of the timed windows (harness/throughput.py). "
            "adapter/bare: time through this project's adapter over the engine's own loop (1.0 = no overhead). "
            "Estimated: `throughput --grad-cost-only` (finite-difference worlds timed, not a full step)."
        ],
        _commits(c.provenance.get("git_commit") for c in throughput_checks),
    )


def backends_document(runs: list[RunRecord]) -> Table:
    """One algorithm, task and horizon on every backend side by side."""
    trained = [r for r in runs if r.epochs]
    wide = backends_table(runs)
    last = "_" + BACKEND_MEASURES[-1]
    backend_names = [c[: -len(last)] for c in wide.columns if c.endswith(last)]
    by_backend: ColumnSpec = []
    for b in backend_names:
        by_backend += [
            (f"{b} seeds", f"{b}_seeds"),
            (f"{b} epochs", f"{b}_epochs"),
            (f"{b} env steps", f"{b}_env_steps"),
            (f"{b} IQM final", f"{b}_iqm_final"),
            (f"{b} gain over untrained", f"{b}_gain_mean"),
            (f"{b} updates skipped %", f"{b}_skipped_pct"),
            (f"{b} median grad norm", f"{b}_grad_norm_median"),
            (f"{b} wall min", f"{b}_wall_min_mean"),
            (f"{b} s / epoch", f"{b}_s_per_epoch_mean"),
        ]
    return Table(
        "backends",
        "The same algorithm, task and horizon on every backend",
        rests_on_runs(trained),
        [
            Section(
                wide,
                _key_columns("task", "algo", "horizon", "num_envs") + by_backend,
                empty="no (task, algo, horizon) has runs on two or more backends",
            )
        ],
        [
            "Per backend: training seeds (runs), epochs and env steps per run, IQM of the final eval return "
            "over the evaluated seeds, the mean gain of the final policy's eval return over the untrained "
            "policy's (same protocol), the share of actor updates skipped as exploding or non-finite (all seeds' "
            "epochs), the median over seeds of each run's median actor-gradient norm (before clipping), mean "
            "wall minutes per run and mean seconds per epoch."
        ],
        _run_commits(trained),
    )


def sim_to_sim_document(runs: list[RunRecord]) -> Table:
    """Policies evaluated on another backend than they trained on."""
    s2s = sim_to_sim_table(runs)
    s2s_runs = [r for r in runs if any(e["backend"] != e["trained_on"] for e in r.cross_evaluations.values())]
    return Table(
        "sim_to_sim",
        "Sim-to-sim: policies evaluated on another backend than they trained on",
        rests_on_runs(s2s_runs) + f" {_count(len(s2s), 'cross-backend evaluation')}.",
        [
            Section(
                s2s,
                _key_columns("task", "algo", "horizon", "num_envs", "epochs", "seed", "trained_on", "evaluated_on")
                + [
                    ("return where trained", "own_return"),
                    ("return on other", "other_return"),
                    ("gap (other - own)", "gap"),
                    ("own from", "own_source"),
                    ("same protocol", "same_protocol"),
                ],
                empty="no run has an eval_on_*.json or sim2sim_on_*.json",
            ),
            Section(
                sim_to_sim_mean_table(s2s),
                _key_columns("task", "algo", "horizon", "num_envs", "epochs", "trained_on", "evaluated_on", "seeds")
                + [
                    ("mean return where trained", "own_return_mean"),
                    ("mean return on other", "other_return_mean"),
                    ("mean gap", "gap_mean"),
                    ("gap std", "gap_std"),
                ],
                heading="Mean over seeds",
                csv_suffix="_mean",
                empty="no cross-backend evaluation",
            ),
        ],
        [
            "Return of the final policy (deterministic). Where trained: from the evaluation written with the "
            "same protocol on the training backend when there is one (sim2sim_on_<training backend>.json), "
            "else eval.json; 'same protocol' says whether both used the same eval seeds, envs and step cap."
        ],
        _commits(e.get("provenance", {}).get("git_commit") for r in runs for e in r.cross_evaluations.values()),
    )


def landscape_document(runs: list[RunRecord]) -> Table:
    """Roughness of the h-step and TD-lambda actor losses."""
    landscapes = [r for r in runs if r.landscape is not None]
    return Table(
        "landscape",
        "Roughness of the actor-loss landscapes: h-step vs TD-lambda return",
        rests_on_runs(landscapes, "runs with a landscape.json"),
        [
            Section(
                landscape_table(runs),
                _key_columns("task", "backend", "algo", "horizon", "seed", "grid", "span", "lambda")
                + [
                    ("roughness h-step", "roughness_h_step"),
                    ("roughness TD-lambda", "roughness_td_lambda"),
                    ("ratio", "ratio_h_step_over_td_lambda"),
                ],
                empty="no run has a landscape.json",
            )
        ],
        [
            "Roughness: total variation of the loss surface per grid line over its range (harness/landscape.py; "
            "0.5 for a plane, >> 1 for a jagged surface). Ratio: h-step / TD-lambda (> 1: TD-lambda smoother)."
        ],
        _commits((r.landscape.get("provenance") or {}).get("git_commit") for r in landscapes),
    )


def checks_document(checks: list[CheckRecord]) -> Table:
    """Every check file in one line."""
    return Table(
        "checks",
        "Checks: gradients, cross-backend agreement, throughput",
        f"Rests on {_count(len(checks), 'check file')}.",
        [
            Section(
                checks_table(checks),
                [
                    ("file", "file"),
                    ("kind", "kind"),
                    ("task", "task"),
                    ("backend", "backend"),
                    ("passed", lambda r: _verdict(r["passed"])),
                    ("key numbers", "summary"),
                    ("made (UTC)", "created_utc"),
                ],
                empty="no check file",
            )
        ],
        [
            "passed: the check's own verdict where it gives one (gradcheck against its tolerance); crosschecks "
            "report agreement numbers without a verdict (n/a)."
        ],
        _commits(c.provenance.get("git_commit") for c in checks),
    )


def build_tables(runs: list[RunRecord], checks: list[CheckRecord]) -> list[Table]:
    """Every table of the report, computed (nothing written), in the order index.md lists them."""
    return [
        returns_document(runs),
        grad_variance_document(runs),
        wall_time_document(runs),
        throughput_document(checks),
        backends_document(runs),
        sim_to_sim_document(runs),
        landscape_document(runs),
        checks_document(checks),
    ]


# -- plots ----------------------------------------------------------------------------------------
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt
    import seaborn as sns

    sns.set_theme(style="whitegrid", context="notebook")
    return plt, sns


def _save_figure(fig, path: Path) -> Path:
    """Write a PNG through a temporary file and a rename, so an interruption never leaves half an image."""
    plt, _ = _pyplot()
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".png")
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=100, bbox_inches="tight")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    finally:
        plt.close(fig)
    return path


def _algo_palette(algos: Iterable[str]) -> dict[str, tuple]:
    """The same colour for an algorithm in every plot."""
    _, sns = _pyplot()
    colours = sns.color_palette("tab10", 10)
    fixed = {"shac": colours[0], "shac-tdfixed": colours[9], "shac-tdadpt": colours[2]}
    fixed |= {"sapo": colours[1], "sapo-tdfixed": colours[3], "sapo-tdadpt": colours[4]}
    spare = iter(colours[5:9] * 10)
    return {algo: fixed.get(algo) or next(spare) for algo in sorted(set(algos), key=_rank)}


def _curve_setting(run: RunRecord) -> tuple:
    return (run.horizon, run.num_envs or 0, run.planned_epochs or 0)


def curve_settings(runs: list[RunRecord]) -> dict[tuple[str, str], tuple]:
    """Per (task, backend) the (horizon, num_envs, planned epochs) with the most runs (on a tie the shortest h,
    then the fewest envs and epochs): the one curves show, so a band never mixes runs of different settings."""
    counts = Counter((r.task, r.backend, _curve_setting(r)) for r in runs if r.epochs)
    chosen: dict[tuple[str, str], tuple[tuple, int]] = {}
    for (task, backend, setting), n in counts.items():
        best = chosen.get((task, backend))
        if best is None or (n, [-x for x in setting]) > (best[1], [-x for x in best[0]]):
            chosen[(task, backend)] = (setting, n)
    return {key: setting for key, (setting, _) in sorted(chosen.items())}


CURVE_MEASURES = {
    "per_step": "reward per env step (training windows)",
    "episode": "training episode return (running mean)",
}


def _training_return(metrics: pd.DataFrame) -> tuple[pd.Series, str]:
    """The mean task reward per env step of each training window where logged (every epoch has one, also
    before the first 1000-step episode ends), else (runs older than that metric) the running average of
    finished training episodes or the last finished episode's return; and which of the two it is."""
    per_step = _column(metrics, "train_reward_per_step")
    if per_step.notna().any():
        return per_step, "per_step"
    average = _column(metrics, "train_episode_return_avg")
    return (average if average.notna().any() else _column(metrics, "train_episode_return")), "episode"


def learning_curve_frame(runs: list[RunRecord], x: str) -> pd.DataFrame:
    """Training return of every run on a common x grid per (task, backend, horizon): ``x`` is ``env_steps``
    or ``wall_min``. Only the runs of :func:`curve_settings`; no extrapolation (NaN outside a run's range),
    so the end of a band rests on the runs that got there."""
    settings = curve_settings(runs)
    chosen = [r for r in runs if r.epochs and settings.get((r.task, r.backend)) == _curve_setting(r)]
    rows = []
    for (task, backend, horizon), members in _group_runs(chosen, lambda r: (r.task, r.backend, r.horizon)).items():
        series = []
        for run in members:
            xs = _column(run.metrics, "env_steps") if x == "env_steps" else _column(run.metrics, "wall_s") / 60.0
            ys, measure = _training_return(run.metrics)
            ok = (xs.notna() & ys.notna()).to_numpy()
            if ok.any():
                series.append((run, xs.to_numpy()[ok], ys.to_numpy()[ok], measure))
        if not series:
            continue
        # one measure per panel: where some runs log the per-step reward, the others (older) are left out
        measures = {m for *_, m in series}
        measure = "per_step" if "per_step" in measures else "episode"
        series = [(run, xs, ys) for run, xs, ys, m in series if m == measure]
        grid = np.linspace(0.0, max(xs.max() for _, xs, _ in series), CURVE_POINTS)
        for run, xs, ys in series:
            inside = (grid >= xs.min()) & (grid <= xs.max())
            for gx, gy in zip(grid[inside], np.interp(grid[inside], xs, ys), strict=True):
                rows.append(
                    {
                        "panel": f"{task} / {backend}, h={horizon}, N={members[0].num_envs}"
                        + ("" if measure == "per_step" else " (episode returns)"),
                        "measure": measure,
                        "task": task,
                        "backend": backend,
                        "algo": run.algo,
                        "seed": run.seed,
                        x: gx,
                        "return": gy,
                    }
                )
    return pd.DataFrame(rows, columns=["panel", "measure", "task", "backend", "algo", "seed", x, "return"])


def plot_learning_curves(runs: list[RunRecord], x: str, path: Path) -> Path:
    plt, sns = _pyplot()
    frame = learning_curve_frame(runs, x)
    if frame.empty:
        raise NoPlotData("no run has logged a training reward")
    panels = list(dict.fromkeys(frame["panel"]))
    palette = _algo_palette(frame["algo"])
    grid = sns.relplot(
        data=frame,
        kind="line",
        x=x,
        y="return",
        hue="algo",
        hue_order=list(palette),
        palette=palette,
        col="panel",
        col_order=panels,
        col_wrap=min(3, len(panels)),
        errorbar=("ci", 95),
        n_boot=CURVE_BOOTSTRAP,
        seed=BOOTSTRAP_SEED,
        height=3.6,
        aspect=1.35,
        facet_kws={"sharex": False, "sharey": False},
    )
    grid.set_titles("{col_name}")
    xlabel = "env steps" if x == "env_steps" else "wall-clock training time (min)"
    measures = set(frame["measure"])
    ylabel = CURVE_MEASURES[measures.pop()] if len(measures) == 1 else "training return (see panel titles)"
    grid.set_axis_labels(xlabel, ylabel)
    from matplotlib import ticker

    for ax in grid.axes.flat:
        ax.xaxis.set_major_locator(ticker.MaxNLocator(5))
        if x == "env_steps":
            ax.xaxis.set_major_formatter(ticker.EngFormatter(sep=""))  # 40k, 1M: no overlapping long numbers
    versus = "env steps" if x == "env_steps" else "wall-clock time"
    grid.figure.suptitle(
        f"Training return vs {versus}\nmean over training seeds, 95% bootstrap CI band; running average of "
        "finished episodes;\neach task / backend at its most common horizon",
        y=1.0,
        va="bottom",  # above the panels' own titles, however many lines it has
    )
    return _save_figure(grid.figure, path)


def plot_grad_variance(per_h: pd.DataFrame, path: Path) -> Path:
    """Both gradient statistics against h, log-log: per (task, backend, N, planned epochs) one panel of the
    raw variance and one of the scale-free noise-to-signal ratio, one line per algorithm; points are the
    geometric mean over seeds of each seed's median, bars its 95% bootstrap CI. Where some setting was
    swept over h, only swept settings are drawn (the others are one point each and stay in the table)."""
    plt, sns = _pyplot()
    finite = np.zeros(len(per_h), dtype=bool)
    for _, stem, _ in GRAD_STATISTICS:
        values = per_h[f"{stem}_gmean"].astype(float)
        finite |= np.isfinite(values) & (values > 0)
    data = per_h[finite]
    if data.empty:
        raise NoPlotData("no finite actor_grad_var or actor_grad_nsr")
    setting = ["task", "backend", "num_envs", "epochs"]
    swept = data.groupby(setting, dropna=False)["horizon"].transform("nunique") > 1
    if swept.any():
        data = data[swept]
    panels = list(dict.fromkeys(zip(*(data[c] for c in setting), strict=True)))
    ncols = len(GRAD_STATISTICS)
    fig, axes = plt.subplots(len(panels), ncols, figsize=(5.6 * ncols, 3.9 * len(panels)), squeeze=False)
    palette = _algo_palette(data["algo"])
    for row_axes, (task, backend, num_envs, planned) in zip(axes, panels, strict=True):
        same = (data["task"] == task) & (data["backend"] == backend)
        same &= _same(data["num_envs"], num_envs) & _same(data["epochs"], planned)
        sub = data[same]
        horizons = sorted(sub["horizon"].unique())
        algos = [a for a in palette if a in set(sub["algo"])]
        for ax, (_, stem, label) in zip(row_axes, GRAD_STATISTICS, strict=True):
            drawn = False
            for i, algo in enumerate(algos):
                line = sub[sub["algo"] == algo].sort_values("horizon")
                point = line[f"{stem}_gmean"].to_numpy(float)
                keep = np.isfinite(point) & (point > 0)
                if not keep.any():
                    continue
                low, high = line[f"{stem}_ci_low"].to_numpy(float), line[f"{stem}_ci_high"].to_numpy(float)
                spread = np.vstack([np.nan_to_num(point - low), np.nan_to_num(high - point)])[:, keep]
                # a slight horizontal offset per algorithm keeps bars at one h apart
                shift = 2.0 ** (0.05 * (i - (len(algos) - 1) / 2))
                ax.errorbar(
                    line["horizon"].to_numpy(float)[keep] * shift,
                    point[keep],
                    yerr=np.clip(spread, 0.0, None),
                    marker="o",
                    capsize=4,
                    label=algo,
                    color=palette[algo],
                )
                drawn = True
            ax.set_xscale("log", base=2)
            # half an octave of room either side: a single h would otherwise be zoomed onto the offsets
            ax.set_xlim(min(horizons) / 2**0.5, max(horizons) * 2**0.5)
            ax.set_xticks(horizons, [str(h) for h in horizons])
            ax.minorticks_off()
            ax.set_title(f"{task} / {backend}, N={_fmt(num_envs)}, {_fmt(planned)} epochs\n{label}", fontsize="medium")
            ax.set_xlabel("horizon h (steps)")
            if drawn:
                ax.set_yscale("log")
                ax.legend(fontsize="small")
            else:
                ax.text(0.5, 0.5, "not logged by these runs", ha="center", va="center", transform=ax.transAxes)
    fig.suptitle("Actor-gradient statistics vs horizon: geometric mean over seeds of each seed's median, bars = 95% CI")
    fig.tight_layout()
    return _save_figure(fig, path)


def _same(column: pd.Series, value) -> pd.Series:
    """Element-wise equality where a missing value equals a missing value (settings of old runs may lack one)."""
    return column.isna() if _is_missing(value) else column == value


def lambda_alpha_frame(runs: list[RunRecord]) -> pd.DataFrame:
    """lambda (every algorithm) and alpha (SAPO's temperature; SHAC has none) per epoch, long format, thinned to
    about CURVE_POINTS epochs per task (every k-th epoch, the same ones for every seed so they average)."""
    settings = curve_settings(runs)
    chosen = [r for r in runs if r.epochs and settings.get((r.task, r.backend)) == _curve_setting(r)]
    rows = []
    for (task,), members in _group_runs(chosen, lambda r: (r.task,)).items():
        stride = max(1, math.ceil(max(r.epochs for r in members) / CURVE_POINTS))
        for run in members:
            epochs = _column(run.metrics, "epoch")
            keep = ((epochs % stride) == 0) | (epochs == epochs.max())
            quantities = [("lambda", "lam")] + ([("alpha (SAPO temperature)", "alpha")] if run.base == "sapo" else [])
            for label, name in quantities:
                values = _column(run.metrics, name)
                for epoch, value in zip(epochs[keep], values[keep], strict=True):
                    if np.isfinite(value):
                        panel = f"{task} / {run.backend}, h={run.horizon}, N={run.num_envs}"
                        rows.append(
                            {"panel": panel, "task": task, "backend": run.backend, "algo": run.algo, "seed": run.seed}
                            | {"quantity": label, "epoch": int(epoch), "value": float(value)}
                        )
    return pd.DataFrame(rows, columns=["panel", "task", "backend", "algo", "seed", "quantity", "epoch", "value"])


def plot_lambda_alpha(runs: list[RunRecord], path: Path) -> Path:
    plt, sns = _pyplot()
    frame = lambda_alpha_frame(runs)
    if frame.empty:
        raise NoPlotData("no run has logged lambda")
    palette = _algo_palette(frame["algo"])
    several_backends = frame["backend"].nunique() > 1
    grid = sns.relplot(
        data=frame,
        kind="line",
        x="epoch",
        y="value",
        hue="algo",
        hue_order=list(palette),
        palette=palette,
        style="backend" if several_backends else None,
        row="quantity",
        row_order=[q for q in ("lambda", "alpha (SAPO temperature)") if q in set(frame["quantity"])],
        col="task",
        errorbar=("ci", 95),
        n_boot=CURVE_BOOTSTRAP,
        seed=BOOTSTRAP_SEED,
        height=3.2,
        aspect=1.4,
        facet_kws={"sharex": "col", "sharey": False},
    )
    grid.set_titles("{row_name} | {col_name}")
    for ax in grid.axes.flat:
        if not ax.lines:
            ax.text(0.5, 0.5, "no SAPO run", transform=ax.transAxes, ha="center", va="center", color="grey")
    grid.set_axis_labels("epoch", "value (dimensionless)")
    grid.figure.suptitle(
        "TD lambda and SAPO temperature alpha per epoch\nmean over training seeds, 95% bootstrap CI band;\n"
        "each task / backend at its most common horizon",
        y=1.0,
        va="bottom",
    )
    return _save_figure(grid.figure, path)


def wall_time_split_frame(wall: pd.DataFrame) -> pd.DataFrame:
    """Seconds per epoch of every time part, mean over seeds, per (task, backend, algo, horizon)."""
    if wall.empty:
        return pd.DataFrame()
    per_epoch = wall.copy()
    parts = [stem for stem, _, _ in TIME_PARTS]
    for stem in parts:
        per_epoch[stem] = per_epoch[f"{stem}_min"] * 60.0 / per_epoch["epochs"]
    return per_epoch.groupby(["task", "backend", "algo", "horizon"], sort=False)[parts].mean().reset_index()


def plot_wall_time(wall: pd.DataFrame, path: Path) -> Path:
    """Stacked bars: seconds per epoch of each time part per (backend, algo, h), one panel per task."""
    plt, sns = _pyplot()
    split = wall_time_split_frame(wall)
    if split.empty:
        raise NoPlotData("no run has metrics")
    parts = [(stem, label) for stem, label, _ in TIME_PARTS if (split[stem].fillna(0.0) > 0).any()]
    colours = dict(zip([s for s, _, _ in TIME_PARTS], sns.color_palette("Set2", len(TIME_PARTS)), strict=True))
    tasks = list(dict.fromkeys(split["task"]))
    widths = [max(2, (split["task"] == t).sum()) for t in tasks]
    fig, axes = plt.subplots(1, len(tasks), figsize=(1.3 * sum(widths) + 2.5, 4.6), width_ratios=widths, squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        sub = split[split["task"] == task]
        labels = [f"{a}\n{b} h{h}" for a, b, h in zip(sub["algo"], sub["backend"], sub["horizon"], strict=True)]
        bottom = np.zeros(len(sub))
        for stem, label in parts:
            values = sub[stem].fillna(0.0).to_numpy()
            ax.bar(labels, values, bottom=bottom, label=label, color=colours[stem], width=0.7)
            bottom += values
        ax.set_title(task)
        ax.set_ylabel("seconds per epoch (mean over seeds)")
        ax.tick_params(axis="x", labelsize=8)
    handles, names = axes[0][0].get_legend_handles_labels()
    fig.legend(handles[::-1], names[::-1], loc="center left", bbox_to_anchor=(1.0, 0.5), title="time part")
    fig.suptitle("Where an epoch's wall time goes (sum over epochs / epochs, mean over training seeds)")
    fig.tight_layout()
    return _save_figure(fig, path)


def _rate_label(value: float) -> str:
    return f"{value:,.0f}" if value >= 100 else f"{value:.3g}"


def throughput_setups(table: pd.DataFrame) -> list[str]:
    """An x label per throughput row: task, envs and horizon, plus what tells apart two files measuring the
    same (backend, task, envs, h) (e.g. ``central`` of ``throughput_mujoco_warp_ant_central.json``), so that
    seaborn draws them as two bars instead of averaging them."""
    labels = [f"{r['task']}\n{_fmt(r['num_envs'])} envs, h={_fmt(r['horizon'])}" for _, r in table.iterrows()]
    keys = list(zip(table["backend"], labels, strict=True))
    repeated = {k for k, n in Counter(keys).items() if n > 1}
    for i, (_, r) in enumerate(table.iterrows()):
        if keys[i] in repeated:
            words = Path(str(r["file"])).stem.split("_")
            known = {"throughput", *str(r["backend"]).split("_"), *str(r["task"]).split("_")}
            labels[i] += "\n" + ("_".join(w for w in words if w not in known) or "default")
    return labels


def plot_throughput(table: pd.DataFrame, path: Path) -> Path:
    """env-steps/s forward and forward+backward (adapter and bare engine) per backend x task, log y."""
    plt, sns = _pyplot()
    measures = [
        ("forward_steps_per_s", "forward"),
        ("forward_backward_steps_per_s", "forward+backward"),
        ("bare_forward_steps_per_s", "bare engine forward"),
        ("bare_engine_steps_per_s", "bare engine forward+backward"),
    ]
    rows = []
    setups = throughput_setups(table)
    for (_, r), setup in zip(table.iterrows(), setups, strict=True):
        for column, label in measures:
            value = pd.to_numeric(r[column], errors="coerce")
            if np.isfinite(value) and value > 0:
                estimated = column == "forward_backward_steps_per_s" and bool(r["forward_backward_estimated"])
                rows.append(
                    {"backend": r["backend"], "setup": setup, "measure": label + (" (est.)" if estimated else "")}
                    | {"env-steps/s": float(value)}
                )
    frame = pd.DataFrame(rows)
    if frame.empty:
        raise NoPlotData("no throughput check")
    widest = int(frame.groupby("backend")["setup"].nunique().max())
    grid = sns.catplot(
        data=frame,
        kind="bar",
        x="setup",
        y="env-steps/s",
        hue="measure",
        col="backend",
        col_order=sorted(frame["backend"].unique(), key=_rank),
        col_wrap=1 if widest > 3 else None,  # many setups: backends one above the other, not a strip
        sharex=False,
        height=4.2,
        aspect=max(1.3, 0.5 * widest),
        palette="muted",
    )
    # log bars start at the axis bottom: a third of the slowest rate keeps the shortest bar visible
    grid.set(yscale="log", ylim=(frame["env-steps/s"].min() / 3.0, None))
    grid.set_titles("{col_name}")
    grid.set_axis_labels("task (envs, horizon)", "env-steps per second (log scale)")
    for ax in grid.axes.flat:
        ax.tick_params(axis="x", labelsize=8)
        for container in ax.containers:
            ax.bar_label(container, labels=[_rate_label(v) for v in container.datavalues], fontsize=7, padding=1)
    grid.figure.suptitle("Throughput per backend and task (throughput checks)", y=1.0, va="bottom")
    return _save_figure(grid.figure, path)


def plot_landscapes(runs: list[RunRecord], out_dir: Path) -> tuple[list[Path], list[str]]:
    """One PNG per landscape.json through ``harness.landscape.plot_landscape`` when that module imports."""
    landscapes = [r for r in runs if r.landscape is not None]
    if not landscapes:
        return [], []
    try:
        from harness.landscape import plot_landscape
    except Exception as exc:  # written in parallel; the table does not need it
        return [], [f"landscape_*.png: harness.landscape.plot_landscape unavailable ({type(exc).__name__}: {exc})"]
    written, skipped = [], []
    for run in landscapes:
        name = f"landscape_{run.task}_{run.backend}_{run.algo}_h{run.horizon}_s{run.seed}.png"
        try:
            written.append(Path(plot_landscape(run.landscape, out_dir / name)))
        except Exception as exc:
            skipped.append(f"{name}: {type(exc).__name__}: {exc}")
    return written, skipped


# -- entry point ----------------------------------------------------------------------------------
PLOT_DESCRIPTIONS = {
    "learning_curves_steps.png": "training return vs env steps, per task x backend at its most common horizon",
    "learning_curves_wall.png": "training return vs wall-clock minutes, same runs",
    "grad_variance_vs_h.png": "raw and scale-free actor-gradient statistics vs h, seeds' 95% CIs, log-log",
    "lambda_alpha.png": "lambda and SAPO's alpha per epoch, per task",
    "wall_time.png": "seconds per epoch split into simulation, backward and updates",
    "throughput.png": "env-steps/s forward and forward+backward per backend x task, log y",
}


def write_bench_report(
    runs: list[Path], checks: list[Path], out_dir: Path, header: dict, stream=sys.stdout
) -> list[Path]:
    """Write every table (Markdown, CSV, provenance JSON) and plot of the suite into ``out_dir``.

    ``runs``: run directories (config.json, metrics.jsonl, optional eval.json, eval_on_*.json,
    sim2sim_on_*.json, landscape.json); ``checks``: check JSON files; ``header``: ``provenance()`` plus
    ``profile``. Returns the files written; skipped plots are printed on ``stream`` and listed in index.md.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    unique_runs = list(dict.fromkeys(Path(r).resolve() for r in runs))
    records = [rec for rec in (load_run(r, stream) for r in unique_runs) if rec is not None]
    check_records = [c for c in (load_check(Path(p), stream) for p in dict.fromkeys(checks)) if c is not None]
    for key, members in _by_group(records).items():
        seeds = Counter(r.seed for r in members)
        repeated = sorted(s for s, n in seeds.items() if n > 1)
        if repeated:
            _say(stream, f"group {key} has seed(s) {repeated} more than once (different run directories): all counted")

    written: list[Path] = []
    tables = build_tables(records, check_records)
    main = {table.name: table.sections[0].frame for table in tables}  # the plots draw from the tables' numbers
    for table in tables:
        written += write_table(table, out_dir, header)

    plots: list[tuple[str, Callable[[Path], Path]]] = [
        ("learning_curves_steps.png", lambda p: plot_learning_curves(records, "env_steps", p)),
        ("learning_curves_wall.png", lambda p: plot_learning_curves(records, "wall_min", p)),
        ("grad_variance_vs_h.png", lambda p: plot_grad_variance(main["grad_variance_vs_h"], p)),
        ("lambda_alpha.png", lambda p: plot_lambda_alpha(records, p)),
        ("wall_time.png", lambda p: plot_wall_time(main["wall_time"], p)),
        ("throughput.png", lambda p: plot_throughput(main["throughput"], p)),
    ]
    plotted, skipped = [], []
    for name, draw in plots:
        path = out_dir / name
        try:
            plotted.append(draw(path))
        except NoPlotData as reason:
            skipped.append(f"{name}: {reason}")
            path.unlink(missing_ok=True)  # a figure from an earlier report would pass for this one
        except Exception as exc:  # a plot must not cost the tables of a finished suite
            skipped.append(f"{name}: failed: {type(exc).__name__}: {exc}")
            path.unlink(missing_ok=True)
            _pyplot()[0].close("all")  # the half-drawn figure
    landscape_pngs, landscape_skipped = plot_landscapes(records, out_dir)
    plotted += landscape_pngs
    skipped += landscape_skipped
    for line in skipped:
        _say(stream, f"skipped plot {line}")
    written += plotted
    written.append(write_index(tables, plotted, skipped, out_dir, header))
    return written


def write_index(tables: list[Table], plotted: list[Path], skipped: list[str], out_dir: Path, header: dict) -> Path:
    """``index.md``: what the report holds, and which plots were skipped and why."""
    lines = ["# Benchmark report", "", *header_lines(header), "", "## Tables", ""]
    for table in tables:
        csvs = ", ".join(f"`{table.name}{s.csv_suffix}.csv`" for s in table.sections)
        lines.append(f"- `{table.name}.md` ({csvs}): {table.title}. {table.rests_on}")
    lines += [
        "",
        "CSV provenance: every `NAME.csv` has a `NAME.provenance.json` beside it "
        "(command, commit, time, packages, machine, what the numbers rest on).",
    ]
    lines += ["", "## Plots", ""]
    landscape = "actor-loss landscape, h-step vs TD-lambda (harness.landscape.plot_landscape)"
    lines += [f"- `{p.name}`: {PLOT_DESCRIPTIONS.get(p.name, landscape)}" for p in plotted]
    if not plotted:
        lines.append("- none")
    if skipped:
        lines += ["", "Skipped:", "", *[f"- {line}" for line in skipped]]
    return atomic_write_text(out_dir / "index.md", "\n".join(lines) + "\n")
