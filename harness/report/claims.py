"""The paper's claims of improvement (final return, the Go2's forward velocity), each judged against the
runs that test it, its claim that the learned lambda falls over training (:func:`lambda_course_table`),
and its claims of which policies move forward at all (:func:`locomotion_table`).

A claim says a TD-lambda variant beats its base by about a given share of the base's mean at the paper's
budget (ARE, Section V: Fig. 5 for the Ant, Fig. 9 and the abstract for the Go2), in final return or, for
the Go2, whose SHAC the paper says acquires no forward locomotion, in forward velocity. A setting tests
it when both algorithms have evaluated runs there, and it is judged on the seeds both have (the design
pairs them) by the pre-registered analysis of :mod:`harness.report.sequential` (docs/statistics.md), so a
budget or a seed count that cannot decide says "undecided" rather than a point estimate's guess, and a
budget below the paper's never contradicts it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from harness.report.records import RunRecord, by_group, metric_column, value_or_range
from harness.report.sequential import (
    CONFIRMED,
    CONTRADICTED,
    NOT_CONFIRMED,
    UNDECIDED,
    at_paper_protocol,
    judge,
    judge_mean,
)
from harness.report.stats import (
    CONFIDENCE,
    iqm,
    mean_with_t_ci,
    paired_ratio_ci,
    probability_of_improvement,
    sample_std,
    sign_flip_p_value,
)


@dataclass(frozen=True)
class Claim:
    """``algo`` beats ``base`` on ``task`` by about ``change`` of the base's mean ``metric``, as ``source``
    in the paper says."""

    task: str
    algo: str
    base: str
    change: float  # the claimed relative change of the mean, 0.5 = +50%
    source: str
    metric: str = "return"  # or "forward velocity" (the final policy's, m/s)

    def value(self, run: RunRecord) -> float:
        return run.final_return if self.metric == "return" else run.final_forward_velocity


PAPER_CLAIMS = (
    Claim("ant", "shac-tdfixed", "shac", 0.25, "Fig. 5"),
    Claim("ant", "shac-tdadpt", "shac", 0.50, "Fig. 5"),
    Claim("ant", "sapo-tdfixed", "sapo", 0.40, "Fig. 5"),
    Claim("ant", "sapo-tdadpt", "sapo", 0.50, "Fig. 5"),
    Claim("go2", "shac-tdadpt", "shac", 1.00, 'abstract, Fig. 9 ("almost 100%")'),
    Claim("go2", "sapo-tdfixed", "sapo", 0.25, "Fig. 9"),
    Claim("go2", "sapo-tdadpt", "sapo", 0.25, "Fig. 9"),
    Claim(
        "go2", "shac-tdadpt", "shac", 1.00, "Fig. 9's text (SHAC: no forward locomotion), abstract", "forward velocity"
    ),
)


@dataclass(frozen=True)
class LocomotionClaim:
    """The paper says ``algo`` on ``task`` does (``moves``) or does not acquire forward locomotion."""

    task: str
    algo: str
    moves: bool
    source: str


# A policy moves forward when its mean forward velocity reaches this (m/s): a slow walk for a legged robot
# of the Go2's or the Ant's size, and above the drift of a policy that stands still or falls over.
LOCOMOTION_SPEED = 0.25

PAPER_LOCOMOTION = (
    LocomotionClaim("go2", "shac", False, 'Sec. V-E ("fails to acquire meaningful forward locomotion")'),
    LocomotionClaim("go2", "shac-tdadpt", True, "Sec. V-E (a significant improvement over that SHAC)"),
)


def _setting(task: str, backend: str, num_envs: int | None, planned: int | None, horizon: int) -> dict:
    """A table row's setting columns, from a run group's key."""
    return {"task": task, "backend": backend, "num_envs": num_envs, "epochs": planned, "horizon": horizon}


def _paired(variant: list[RunRecord], base: list[RunRecord], claim: Claim) -> tuple[list[int], np.ndarray, np.ndarray]:
    """The seeds both algorithms have evaluated with a finite value, in seed order, and their values: the pairs
    of the design (a seed one side lacks is not a pair)."""
    v = {r.seed: claim.value(r) for r in variant}
    b = {r.seed: claim.value(r) for r in base}
    seeds = sorted(s for s in v.keys() & b.keys() if math.isfinite(v[s]) and math.isfinite(b[s]))
    return seeds, np.array([v[s] for s in seeds], dtype=float), np.array([b[s] for s in seeds], dtype=float)


def _spent(members: list[RunRecord]) -> tuple[int, float]:
    """(env steps, core-hours of training wall time) of the runs a look read."""
    steps = sum(r.env_steps for r in members)
    hours = sum(r.wall_s for r in members if math.isfinite(r.wall_s)) / 3600.0
    return int(steps), float(hours)


def claims_table(runs: list[RunRecord], claims=PAPER_CLAIMS) -> pd.DataFrame:
    """One row per claim and setting (task, backend, N, planned epochs, h) where both of its algorithms
    have evaluated runs, judged by the pre-registered design (:mod:`harness.report.sequential`): the seed
    pairs, the look, the relative change of the mean with its paired interval at that look's level, the
    verdict and the design's state; beside them, descriptive only, each side's IQM, rliable's probability of
    improvement (no interval: its bootstrap interval under-covers at these seeds) and the exact sign-flip
    p-value of the paired differences; and the compute the look's runs took."""
    groups = by_group(r for r in runs if r.evaluation is not None)
    rows = []
    for claim in claims:
        for key, variant_runs in groups.items():
            task, backend, num_envs, planned, horizon, algo = key
            base_runs = groups.get((*key[:-1], claim.base))
            if task != claim.task or algo != claim.algo or base_runs is None:
                continue
            seeds, variant, base = _paired(variant_runs, base_runs, claim)
            if not seeds:
                continue  # evaluations made before the metric was recorded, or no common seed
            look = judge(variant, base, claim.change, at_paper_protocol(num_envs, planned, horizon))
            said = look.verdict if base.mean() > 0.0 else f"no ratio: the base's mean is {base.mean():.3g}"
            read = {s for s in seeds[: look.used]}
            steps, hours = _spent([r for r in variant_runs + base_runs if r.seed in read])
            rows.append(
                _setting(task, backend, num_envs, planned, horizon)
                | {
                    "env_steps": value_or_range(r.env_steps for r in variant_runs),
                    "metric": claim.metric,
                    "algo": algo,
                    "base": claim.base,
                    "pairs": look.pairs,
                    "look": "" if look.look is None else f"{look.used} pairs",
                    "claimed_change": claim.change,
                    "measured_change": look.estimate,
                    "confidence": look.confidence,
                    "change_ci_low": look.low,
                    "change_ci_high": look.high,
                    "verdict": said,
                    "design": look.state,
                    "seeds_wanted": look.seeds_wanted,
                    "iqm_algo": iqm(variant),
                    "iqm_base": iqm(base),
                    "p_improvement": probability_of_improvement([variant], [base]),
                    "sign_flip_p": sign_flip_p_value(variant - base),
                    "spent_env_steps": steps,
                    "spent_core_hours": hours,
                    "source": claim.source,
                }
            )
    return pd.DataFrame(rows, columns=CLAIMS_COLUMNS)


CLAIMS_COLUMNS = [
    *("task", "backend", "num_envs", "epochs", "horizon", "env_steps", "metric", "algo", "base", "pairs", "look"),
    *("claimed_change", "measured_change", "confidence", "change_ci_low", "change_ci_high", "verdict", "design"),
    *("seeds_wanted", "iqm_algo", "iqm_base", "p_improvement", "sign_flip_p", "spent_env_steps", "spent_core_hours"),
    "source",
]


def lambda_course_verdict(low: float, high: float, paper_protocol: bool = True) -> str:
    """What a 95% CI [low, high] of the learned lambda's change over training says of the paper's Fig. 4b
    (lambda "gradually decreases over time"): a rise contradicts it only at the paper's training protocol;
    below it, it is not confirmed at this budget."""
    if math.isnan(low) or math.isnan(high):
        return "undecided (under 2 seeds)"
    if high < 0.0:
        return "confirmed (falls)"
    if low > 0.0:
        return f"{CONTRADICTED if paper_protocol else NOT_CONFIRMED} (rises)"
    return UNDECIDED


def _lambda_course(run: RunRecord) -> np.ndarray:
    """The run's lambda after each epoch it logged, in order (empty for runs from before lambda was logged)."""
    course = metric_column(run.metrics, "lam").to_numpy(dtype=float)
    return course[np.isfinite(course)]


def lambda_course_table(runs: list[RunRecord]) -> pd.DataFrame:
    """The paper's Fig. 4b for every setting with finished (evaluated) runs of an adaptive-lambda algorithm:
    lambda after the first and the last epoch, the change between them per seed (mean, 95% t CI over seeds),
    the share of epochs in which lambda fell (how gradual the course is), and the verdict."""
    groups = by_group(r for r in runs if r.evaluation is not None and r.algo.split(" (")[0].endswith("-tdadpt"))
    rows = []
    for (task, backend, num_envs, planned, horizon, algo), members in groups.items():
        courses = [_lambda_course(r) for r in members]
        if not all(c.size > 1 for c in courses):
            continue  # runs from before lambda was logged
        first = np.array([c[0] for c in courses])
        last = np.array([c[-1] for c in courses])
        change, low, high = mean_with_t_ci(last - first)
        rows.append(
            _setting(task, backend, num_envs, planned, horizon)
            | {
                "env_steps": value_or_range(r.env_steps for r in members),
                "algo": algo,
                "seeds": len(members),
                "lambda_first": float(first.mean()),
                "lambda_final_mean": float(last.mean()),
                "lambda_final_std": sample_std(last),
                "change": change,
                "change_ci_low": low,
                "change_ci_high": high,
                "falling_share": float(np.mean([np.mean(np.diff(c) < 0.0) for c in courses])),
                "verdict": lambda_course_verdict(low, high, at_paper_protocol(num_envs, planned, horizon)),
                "source": "Fig. 4b",
            }
        )
    columns = ["task", "backend", "num_envs", "epochs", "horizon", "env_steps", "algo", "seeds", "lambda_first"]
    columns += ["lambda_final_mean", "lambda_final_std", "change", "change_ci_low", "change_ci_high"]
    return pd.DataFrame(rows, columns=columns + ["falling_share", "verdict", "source"])


#: Fig. 6's settings of SAPO-TDAdpt's lambda update that the paper says lower the return, (b_lambda, m_lambda) =
#: (4, 2) and (4, 3), as :func:`~harness.report.records.algo_label` names them; the other settings are
#: described, not judged
ABLATION_JUDGED = ("sapo-tdadpt (b_lambda 4, m_lambda 2)", "sapo-tdadpt (b_lambda 4, m_lambda 3)")
ABLATION_CONFIDENCE = 1.0 - (1.0 - CONFIDENCE) / len(ABLATION_JUDGED)  # Bonferroni over the judged settings
COLLAPSE_SHARE = 0.5  # the paper's "plummets", per seed: a final return under half of its pair's


def ablation_verdict(pairs: int, low: float, high: float, judged: bool, paper_protocol: bool = True) -> str:
    """Fig. 6's verdict on one setting against its algorithm's own (docs/statistics.md): the direction only,
    the paper giving no size; a setting the paper does not say degrades is described, never judged."""
    if not judged:
        return "descriptive"
    if pairs < 2:
        return f"{UNDECIDED} (under 2 pairs)"
    if high < 0.0:
        return f"{CONFIRMED} (lowers the return)"
    if low > 0.0:
        return f"{CONTRADICTED if paper_protocol else NOT_CONFIRMED} (raises the return)"
    return UNDECIDED


def _final_lambda(members: list[RunRecord]) -> float:
    """The mean over runs of lambda after the last epoch (NaN where no run logged it)."""
    finals = [course[-1] for course in map(_lambda_course, members) if course.size]
    return float(np.mean(finals)) if finals else math.nan


def ablation_table(runs: list[RunRecord]) -> pd.DataFrame:
    """The paper's Fig. 6: every ablation setting (a run group whose label names changed hyperparameters, e.g.
    ``sapo-tdadpt (b_lambda 4, m_lambda 2)``) against its algorithm's own runs at the same setting, on the seeds
    both have evaluated (seed s gives both the same initial policy and environments): the relative change of
    the mean final return with its paired Fieller interval, at 97.5% for the settings the paper says degrade
    (:data:`ABLATION_JUDGED`, judged) and 95% for the rest (descriptive); each side's seeds, mean and final
    lambda; and the pairs whose setting's return fell under half of its pair's."""
    groups = by_group(r for r in runs if r.evaluation is not None)
    rows = []
    for key, members in groups.items():
        task, backend, num_envs, planned, horizon, label = key
        reference = label.split(" (", 1)[0]
        own = groups.get((*key[:-1], reference))
        if reference == label or own is None:
            continue
        judged = label in ABLATION_JUDGED
        confidence = ABLATION_CONFIDENCE if judged else CONFIDENCE
        seeds, setting, baseline = _paired(members, own, Claim(task, label, reference, 0.0, "Fig. 6"))
        change, low, high = paired_ratio_ci(setting, baseline, confidence)
        paper_protocol = at_paper_protocol(num_envs, planned, horizon)
        rows.append(
            _setting(task, backend, num_envs, planned, horizon)
            | {
                "env_steps": value_or_range(r.env_steps for r in members),
                "algo": label,
                "reference": reference,
                "seeds": len(members),
                "mean_final": float(np.mean([r.final_return for r in members])),
                "iqm_final": iqm([r.final_return for r in members]),
                "lambda_final": _final_lambda(members),
                "reference_lambda_final": _final_lambda(own),
                "pairs": len(seeds),
                "measured_change": change,
                "confidence": confidence,
                "change_ci_low": low,
                "change_ci_high": high,
                "verdict": ablation_verdict(len(seeds), low, high, judged, paper_protocol),
                "collapsed_pairs": int(np.sum(setting < COLLAPSE_SHARE * baseline)),
                "source": "Fig. 6",
            }
        )
    columns = ["task", "backend", "num_envs", "epochs", "horizon", "env_steps", "algo", "reference", "seeds"]
    columns += ["mean_final", "iqm_final", "lambda_final", "reference_lambda_final", "pairs", "measured_change"]
    columns += ["confidence", "change_ci_low", "change_ci_high", "verdict", "collapsed_pairs", "source"]
    return pd.DataFrame(rows, columns=columns)


def locomotion_verdict(low: float, high: float, speed: float = LOCOMOTION_SPEED) -> str:
    """What a look's CI [low, high] of the seeds' mean forward velocity says: the policies move forward when
    it lies above ``speed``, do not when it lies below, and it is undecided when it holds ``speed``."""
    if math.isnan(low) or math.isnan(high):
        return "undecided (under 2 seeds)"
    if low > speed:
        return "moves forward"
    return "does not move forward" if high < speed else "undecided"


def _paper_locomotion_verdict(claim: LocomotionClaim | None, verdict: str, paper_protocol: bool) -> str:
    """The paper's claim (if it makes one for the row) read against the row's verdict: a disagreement
    contradicts it only at the paper's training protocol; below it the claim is not confirmed at this budget."""
    if claim is None:
        return ""
    if verdict not in ("moves forward", "does not move forward"):
        return UNDECIDED
    if (verdict == "moves forward") == claim.moves:
        return CONFIRMED
    return CONTRADICTED if paper_protocol else NOT_CONFIRMED


def locomotion_table(runs: list[RunRecord], claims=PAPER_LOCOMOTION) -> pd.DataFrame:
    """Whether each algorithm's final policies move forward: per setting and algorithm, over the evaluated
    runs that recorded a forward velocity (in seed order), the untrained policies' mean velocity, the
    verdict read at the design's looks (:func:`harness.report.sequential.judge_mean` with
    :func:`locomotion_verdict`: the look's mean and t interval at its level), what the design does next,
    and, descriptive only, the mean and 95% t CI over every seed and how many seeds reach
    :data:`LOCOMOTION_SPEED`; where the paper says whether the algorithm acquires forward locomotion on the
    task, that claim's verdict."""
    recorded = [r for r in runs if r.evaluation is not None and math.isfinite(r.final_forward_velocity)]
    said = {(c.task, c.algo): c for c in claims}
    rows = []
    for (task, backend, num_envs, planned, horizon, algo), members in by_group(recorded).items():
        members = sorted(members, key=lambda r: r.seed)
        final = np.array([r.final_forward_velocity for r in members], dtype=float)
        untrained = np.array([r.evaluation["initial"].get("mean_forward_velocity", math.nan) for r in members])
        look = judge_mean(final, locomotion_verdict)
        mean, low, high = mean_with_t_ci(final)
        claim = said.get((task, algo))
        rows.append(
            _setting(task, backend, num_envs, planned, horizon)
            | {
                "env_steps": value_or_range(r.env_steps for r in members),
                "algo": algo,
                "seeds": final.size,
                "untrained_velocity": float(np.mean(untrained)),
                "look": "" if look.look is None else f"{look.used} seeds",
                "confidence": look.confidence,
                "look_velocity": look.estimate,
                "look_ci_low": look.low,
                "look_ci_high": look.high,
                "verdict": look.verdict,
                "design": look.state,
                "seeds_wanted": look.seeds_wanted,
                "final_velocity": mean,
                "final_velocity_ci_low": low,
                "final_velocity_ci_high": high,
                "seeds_moving": int(np.sum(final >= LOCOMOTION_SPEED)),
                "paper_says": "" if claim is None else ("moves" if claim.moves else "does not move"),
                "paper_verdict": _paper_locomotion_verdict(
                    claim, look.verdict, at_paper_protocol(num_envs, planned, horizon)
                ),
                "source": "" if claim is None else claim.source,
            }
        )
    return pd.DataFrame(rows, columns=LOCOMOTION_COLUMNS)


LOCOMOTION_COLUMNS = [
    *("task", "backend", "num_envs", "epochs", "horizon", "env_steps", "algo", "seeds", "untrained_velocity"),
    *("look", "confidence", "look_velocity", "look_ci_low", "look_ci_high", "verdict", "design", "seeds_wanted"),
    *("final_velocity", "final_velocity_ci_low", "final_velocity_ci_high", "seeds_moving", "paper_says"),
    *("paper_verdict", "source"),
]


def seeds_wanted(runs: list[RunRecord], claims=PAPER_CLAIMS, locomotion=PAPER_LOCOMOTION) -> dict[tuple, int]:
    """The seeds per algorithm the sequential design asks for, keyed like a run's group (task, backend,
    num_envs, planned epochs, horizon, algo), for every algorithm of a claim judged on ``runs``: the most any
    of its claims asks for (a base serves several claims; it continues while any of them does), the paper's
    locomotion claims included. An algorithm none of whose claims has an evaluated run yet is absent: the
    caller plans the first look."""
    return seeds_wanted_of(claims_table(runs, claims), locomotion_table(runs, locomotion), locomotion)


def seeds_wanted_of(claims: pd.DataFrame, moving: pd.DataFrame, locomotion=PAPER_LOCOMOTION) -> dict[tuple, int]:
    """:func:`seeds_wanted` from tables already made: ``claims`` (:func:`claims_table`) and ``moving``
    (:func:`locomotion_table`, whose rows count only for the algorithms ``locomotion`` names)."""
    wanted: dict[tuple, int] = {}
    for _, row in claims.iterrows():
        setting = (row["task"], row["backend"], row["num_envs"], row["epochs"], row["horizon"])
        for algo in (row["algo"], row["base"]):
            key = (*setting, algo)
            wanted[key] = max(wanted.get(key, 0), int(row["seeds_wanted"]))
    said = {(c.task, c.algo) for c in locomotion}
    for _, row in moving.iterrows():
        if (row["task"], row["algo"]) in said:
            key = (row["task"], row["backend"], row["num_envs"], row["epochs"], row["horizon"], row["algo"])
            wanted[key] = max(wanted.get(key, 0), int(row["seeds_wanted"]))
    return wanted
