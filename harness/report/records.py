"""What the bench report reads: run directories (:class:`RunRecord`, :func:`load_run`) and check files
(:class:`CheckRecord`, :func:`load_check`), the order tables list them in, and how runs are grouped into
the rows of a table (:func:`by_group`)."""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from algorithms.config import ALGORITHMS
from harness.envs import engine_rank
from harness.results import RunError, read_metrics
from harness.run.folder import (
    CONFIG,
    EVALUATION,
    LANDSCAPE,
    METRICS,
    OLDER_ON_ENGINE,
    ON_ENGINE,
    STEP_GAIN,
    engine_evaluations,
)

ALGO_ORDER = ALGORITHMS  # the order tables and plots list algorithms in
VARIANT_SUFFIXES = ("-tdfixed", "-tdadpt")
SIM_TO_SIM_PREFIXES = (ON_ENGINE, *OLDER_ON_ENGINE)  # evaluations on a named engine, older names included


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
    step_gain: dict | None = None  # step_gain.json (Proposition 1's B_f along the final policy)
    commit: str | None = None  # the commit the run was trained at (config.json's provenance)
    planned_epochs: int | None = None  # config.json's epochs: what the run was asked for (``epochs``: what it did)
    device: str = "cpu"  # where the run trained (config.json's device: cpu, cuda[:N])

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
        wall = metric_column(self.metrics, "wall_s")
        return (
            float(wall.iloc[-1]) if np.isfinite(wall.iloc[-1]) else float(metric_column(self.metrics, "epoch_s").sum())
        )

    @property
    def final_return(self) -> float | None:
        return self.evaluation["final"]["mean_return"] if self.evaluation else None

    @property
    def final_forward_velocity(self) -> float:
        """The final policy's mean forward velocity (m/s; eval.json's ``mean_forward_velocity``), NaN where
        the evaluation did not record one."""
        value = self.evaluation["final"].get("mean_forward_velocity") if self.evaluation else None
        return math.nan if value is None else float(value)

    @property
    def initial_return(self) -> float | None:
        return self.evaluation["initial"]["mean_return"] if self.evaluation else None


#: AlgoConfig fields an ablation varies, with the paper's values (Fig. 6: b_lambda, m_lambda): a run that
#: differs in one is labelled apart (:func:`algo_label`), so it never pools as a seed of the algorithm's own row
ABLATION_FIELDS = (("lambda_batches", "b_lambda", 1), ("lambda_iterations", "m_lambda", 1.0))


def algo_label(algo: str, algo_cfg: dict) -> str:
    """The algorithm as tables name it: ``sapo-tdadpt``, or ``sapo-tdadpt (b_lambda 4, m_lambda 2)`` for a run
    of an ablation setting (:data:`ABLATION_FIELDS`; a field a run's config does not record has the paper's
    value)."""
    changed = [
        f"{symbol} {algo_cfg[field]:g}"
        for field, symbol, paper in ABLATION_FIELDS
        if isinstance(algo_cfg.get(field), int | float) and float(algo_cfg[field]) != paper
    ]
    return f"{algo} ({', '.join(changed)})" if changed else algo


def base_algo(algo: str) -> str:
    """The algorithm a TD-lambda variant modifies: ``shac-tdadpt`` -> ``shac``; a base is its own base; an
    ablation's label (:func:`algo_label`) has its algorithm's base."""
    algo = algo.split(" (", 1)[0]
    for suffix in VARIANT_SUFFIXES:
        if algo.endswith(suffix):
            return algo[: -len(suffix)]
    return algo


def collect_runs(root: Path) -> list[Path]:
    """Every directory under ``root`` (``root`` included) that holds a ``config.json``, sorted."""
    return sorted({p.parent for p in Path(root).rglob(CONFIG) if p.is_file()})


def say(stream, message: str) -> None:
    """One line of the report's log on ``stream``; None: standard output as it is now (not as it was at import,
    which a test's captured output may have replaced and closed since)."""
    print(f"[bench report] {message}", file=stream or sys.stdout, flush=True)


def _read_json(path: Path, stream=None) -> dict | None:
    """A JSON object file, or None when it is missing or unreadable (said on ``stream``)."""
    if not path.is_file():
        return None
    try:
        payload = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        say(stream, f"ignored {path}: {exc}")
        return None
    if not isinstance(payload, dict):
        say(stream, f"ignored {path}: not a JSON object")
        return None
    return payload


def _has_returns(payload: dict | None) -> bool:
    """An evaluation payload with a number for the initial and the final policy."""
    try:
        return all(isinstance(payload[k]["mean_return"], int | float) for k in ("initial", "final"))
    except (KeyError, TypeError):
        return False


def metric_column(frame: pd.DataFrame, name: str) -> pd.Series:
    """A metrics column as floats (null -> NaN); all NaN when the column is absent (older runs)."""
    if name not in frame:
        return pd.Series(np.nan, index=frame.index, dtype=float)
    return pd.to_numeric(frame[name], errors="coerce").astype(float)


def task_label(task: str, config: dict) -> str:
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


def backend_label(backend: str, config: dict) -> str:
    """The backend as tables name it: ``mujoco_warp``, or ``mujoco_warp+fd_scheme=one_sided`` for a run
    built with explicit adapter options, so runs of two gradient settings never pool as seeds of one row."""
    options = config.get("backend_options") or {}
    return "+".join([backend, *(f"{k}={v}" for k, v in sorted(options.items()))])


def load_run(run_dir: Path, stream=None) -> RunRecord | None:
    """Read one run directory; None (said on ``stream``) when its config.json is missing or unusable."""
    run_dir = Path(run_dir)
    config = _read_json(run_dir / CONFIG, stream)
    try:
        algo_cfg = config["algo"]
        task, backend, algo = str(config["task"]), str(config["backend"]), str(algo_cfg["algo"])
        horizon, seed = int(algo_cfg.get("horizon", 0)), int(config.get("seed", 0))
    except (KeyError, TypeError, ValueError):
        say(stream, f"skipped {run_dir}: no usable config.json (task, backend, seed, algo.algo, algo.horizon)")
        return None
    try:
        rows = read_metrics(run_dir / METRICS)
    except RunError as exc:
        say(stream, f"{run_dir}: metrics ignored: {exc}")
        rows = []
    metrics = pd.DataFrame(rows)
    if "epoch" in metrics:
        # a resumed run may repeat the epochs after its last checkpoint: the later rows are the ones that count
        metrics = metrics.drop_duplicates("epoch", keep="last").sort_values("epoch").reset_index(drop=True)
    evaluation = _read_json(run_dir / EVALUATION, stream)
    if evaluation is not None and not _has_returns(evaluation):
        say(stream, f"{run_dir}/eval.json has no initial/final mean_return: counted as not evaluated")
        evaluation = None
    trained = len(metrics.get("epoch", ()))
    if evaluation is not None and int(evaluation.get("policy_epoch", trained)) < trained:
        say(
            stream, f"{run_dir}/eval.json evaluates epoch {evaluation['policy_epoch']} of {trained}: stale, not counted"
        )
        evaluation = None
    cross = {}
    for _, engine, path in engine_evaluations(run_dir):
        payload = _read_json(path, stream)
        if _has_returns(payload):
            payload.setdefault("backend", engine)
            payload.setdefault("trained_on", backend)
            cross[path.name] = payload
    landscape = _read_json(run_dir / LANDSCAPE, stream)
    step_gain = _read_json(run_dir / STEP_GAIN, stream)
    return RunRecord(
        path=run_dir,
        task=task_label(task, config),
        backend=backend_label(backend, config),
        algo=algo_label(algo, algo_cfg),
        horizon=horizon,
        seed=seed,
        num_envs=algo_cfg.get("num_envs"),
        metrics=metrics,
        evaluation=evaluation,
        cross_evaluations=cross,
        landscape=landscape,
        step_gain=step_gain,
        commit=(config.get("provenance") or {}).get("git_commit"),
        planned_epochs=_int_or_none(config.get("epochs", algo_cfg.get("max_epochs"))),
        device=str(config.get("device", "cpu")),
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


def load_check(path: Path, stream=None) -> CheckRecord | None:
    """A check file (:func:`harness.results.write_check`: ``{"kind", "result", "provenance"}``), or None
    with one line when it is missing, damaged or not a check file of a known kind."""
    from harness.results import CHECK_RESULT_KINDS

    payload = _read_json(Path(path), stream)
    if payload is None:
        if not Path(path).is_file():
            say(stream, f"skipped check {path}: no such file")
        return None
    kind = payload.get("kind")
    if kind not in CHECK_RESULT_KINDS or not isinstance(payload.get("result"), dict):
        say(stream, f"skipped check {path}: not a check file (no known kind and result); re-make it")
        return None
    provenance = payload.get("provenance") if isinstance(payload.get("provenance"), dict) else {}
    return CheckRecord(path=Path(path), kind=kind, result=payload["result"], provenance=provenance)


# -- grouping helpers -----------------------------------------------------------------------------
def rank(name: str) -> tuple[int, str]:
    """Sort key of a name: algorithms in ALGO_ORDER, then engines by their adapters' ``table_rank`` (the
    reference engine first), then anything else (tasks, unknown names) alphabetically."""
    if name in ALGO_ORDER:
        return (ALGO_ORDER.index(name), "")
    engine = engine_rank(name)
    if engine is not None:
        return (len(ALGO_ORDER) + engine, name)
    return (10**6, name)


def group_runs(runs: Iterable[RunRecord], key: Callable[[RunRecord], tuple]) -> dict[tuple, list[RunRecord]]:
    """Runs grouped by ``key``, groups in a stable order (algorithms in ALGO_ORDER), members by seed."""
    groups: dict[tuple, list[RunRecord]] = {}
    for run in runs:
        groups.setdefault(key(run), []).append(run)
    # element-wise: numbers (horizons, seeds) by value, names by rank
    ordered = sorted(groups, key=lambda k: tuple((x, "") if isinstance(x, int) else rank(str(x)) for x in k))
    return {k: sorted(groups[k], key=lambda r: (r.seed, str(r.path))) for k in ordered}


def by_group(runs: Iterable[RunRecord]) -> dict[tuple, list[RunRecord]]:
    """Runs by :attr:`RunRecord.group`, ordered for tables."""
    return group_runs(runs, lambda r: r.group)


def value_or_range(values: Iterable) -> int | str | None:
    """The one value all members share, else ``"min-max"``."""
    distinct = sorted(set(values))
    if not distinct:
        return None
    return distinct[0] if len(distinct) == 1 else f"{distinct[0]}-{distinct[-1]}"
