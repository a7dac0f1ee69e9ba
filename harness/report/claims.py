"""The paper's claims of improvement (final return, the Go2's forward velocity), each judged against the
runs that test it, its claim that the learned lambda falls over training (:func:`lambda_course_table`),
and its claims of which policies move forward at all (:func:`locomotion_table`).

A claim says a TD-lambda variant beats its base by about a given share of the base's mean at the paper's
budget (ARE, Section V: Fig. 5 for the Ant, Fig. 9 and the abstract for the Go2), in final return or, for
the Go2, whose SHAC the paper says acquires no forward locomotion, in forward velocity. A setting tests
it when both algorithms have evaluated runs there; the verdict reads the 95% CI of the measured relative
change of the mean (:func:`claim_verdict`), so a budget or a seed count that cannot decide says
"undecided" rather than a point estimate's guess.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from harness.report.records import RunRecord, by_group, metric_column, value_or_range
from harness.report.stats import mean_with_t_ci, relative_mean_change_with_ci, sample_std


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


def claim_verdict(low: float, high: float, claimed: float) -> str:
    """What a 95% CI [low, high] of the relative change says of a claimed improvement ``claimed`` > 0:
    confirmed when the CI lies above 0 and holds the claimed size; contradicted when it excludes the
    claimed size from below and does not show an improvement; undecided when it holds both 0 and the
    claimed size (or there is no CI)."""
    if math.isnan(low) or math.isnan(high):
        return "undecided (under 2 seeds a side)"
    if high < 0.0:
        return "contradicted (below the base)"
    if low > claimed:
        return "confirmed, larger than claimed"
    if low > 0.0:
        return "confirmed" if high >= claimed else "improvement confirmed, smaller than claimed"
    return "undecided" if high >= claimed else "contradicted (claimed size excluded)"


def claims_table(runs: list[RunRecord], claims=PAPER_CLAIMS) -> pd.DataFrame:
    """One row per claim and setting (task, backend, N, planned epochs, h) where both of its algorithms
    have evaluated runs: the seeds, the measured relative change of the mean with its CI, the verdict."""
    groups = by_group(r for r in runs if r.evaluation is not None)
    env_steps = {key: value_or_range(r.env_steps for r in members) for key, members in groups.items()}
    rows = []
    for claim in claims:
        values = {key: np.array([claim.value(r) for r in members], dtype=float) for key, members in groups.items()}
        for (task, backend, num_envs, planned, horizon, algo), variant in values.items():
            base = values.get((task, backend, num_envs, planned, horizon, claim.base))
            if task != claim.task or algo != claim.algo or base is None:
                continue
            if not (np.isfinite(variant).all() and np.isfinite(base).all()):
                continue  # evaluations made before the metric was recorded
            change, low, high = relative_mean_change_with_ci(variant, base)
            verdict = claim_verdict(low, high, claim.change)
            if not base.mean() > 0.0:
                verdict = f"no ratio: the base's mean is {base.mean():.3g}"
            rows.append(
                _setting(task, backend, num_envs, planned, horizon)
                | {
                    "env_steps": env_steps[(task, backend, num_envs, planned, horizon, algo)],
                    "metric": claim.metric,
                    "algo": algo,
                    "base": claim.base,
                    "seeds": variant.size,
                    "base_seeds": base.size,
                    "claimed_change": claim.change,
                    "measured_change": change,
                    "change_ci_low": low,
                    "change_ci_high": high,
                    "verdict": verdict,
                    "source": claim.source,
                }
            )
    columns = ["task", "backend", "num_envs", "epochs", "horizon", "env_steps", "metric", "algo", "base", "seeds"]
    columns += ["base_seeds", "claimed_change", "measured_change", "change_ci_low", "change_ci_high", "verdict"]
    return pd.DataFrame(rows, columns=columns + ["source"])


def lambda_course_verdict(low: float, high: float) -> str:
    """What a 95% CI [low, high] of the learned lambda's change over training says of the paper's Fig. 4b
    (lambda "gradually decreases over time")."""
    if math.isnan(low) or math.isnan(high):
        return "undecided (under 2 seeds)"
    if high < 0.0:
        return "confirmed (falls)"
    return "contradicted (rises)" if low > 0.0 else "undecided"


def lambda_course_table(runs: list[RunRecord]) -> pd.DataFrame:
    """The paper's Fig. 4b for every setting with finished (evaluated) runs of an adaptive-lambda algorithm:
    lambda after the first and the last epoch, the change between them per seed (mean, 95% t CI over seeds),
    the share of epochs in which lambda fell (how gradual the course is), and the verdict."""
    groups = by_group(r for r in runs if r.evaluation is not None and r.algo.endswith("-tdadpt"))
    rows = []
    for (task, backend, num_envs, planned, horizon, algo), members in groups.items():
        courses = [metric_column(r.metrics, "lam").to_numpy(dtype=float) for r in members]
        courses = [c[np.isfinite(c)] for c in courses]
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
                "verdict": lambda_course_verdict(low, high),
                "source": "Fig. 4b",
            }
        )
    columns = ["task", "backend", "num_envs", "epochs", "horizon", "env_steps", "algo", "seeds", "lambda_first"]
    columns += ["lambda_final_mean", "lambda_final_std", "change", "change_ci_low", "change_ci_high"]
    return pd.DataFrame(rows, columns=columns + ["falling_share", "verdict", "source"])


def locomotion_verdict(low: float, high: float, speed: float = LOCOMOTION_SPEED) -> str:
    """What a 95% CI [low, high] of the seeds' mean forward velocity says: the policies move forward when
    it lies above ``speed``, do not when it lies below, and it is undecided when it holds ``speed``."""
    if math.isnan(low) or math.isnan(high):
        return "undecided (under 2 seeds)"
    if low > speed:
        return "moves forward"
    return "does not move forward" if high < speed else "undecided"


def _paper_locomotion_verdict(claim: LocomotionClaim | None, verdict: str) -> str:
    """The paper's claim (if it makes one for the row) read against the row's verdict."""
    if claim is None:
        return ""
    if verdict not in ("moves forward", "does not move forward"):
        return "undecided"
    return "confirmed" if (verdict == "moves forward") == claim.moves else "contradicted"


def locomotion_table(runs: list[RunRecord], claims=PAPER_LOCOMOTION) -> pd.DataFrame:
    """Whether each algorithm's final policies move forward: per setting and algorithm, over the evaluated
    runs that recorded a forward velocity, the untrained and the final policies' mean velocity (mean over
    seeds, the final one with its 95% t CI), how many seeds reach :data:`LOCOMOTION_SPEED`, the verdict
    (:func:`locomotion_verdict`) and, where the paper says whether the algorithm acquires forward
    locomotion on the task, that claim's verdict."""
    recorded = [r for r in runs if r.evaluation is not None and math.isfinite(r.final_forward_velocity)]
    said = {(c.task, c.algo): c for c in claims}
    rows = []
    for (task, backend, num_envs, planned, horizon, algo), members in by_group(recorded).items():
        final = np.array([r.final_forward_velocity for r in members], dtype=float)
        untrained = np.array([r.evaluation["initial"].get("mean_forward_velocity", math.nan) for r in members])
        mean, low, high = mean_with_t_ci(final)
        verdict = locomotion_verdict(low, high)
        claim = said.get((task, algo))
        rows.append(
            _setting(task, backend, num_envs, planned, horizon)
            | {
                "env_steps": value_or_range(r.env_steps for r in members),
                "algo": algo,
                "seeds": final.size,
                "untrained_velocity": float(np.mean(untrained)),
                "final_velocity": mean,
                "final_velocity_ci_low": low,
                "final_velocity_ci_high": high,
                "seeds_moving": int(np.sum(final >= LOCOMOTION_SPEED)),
                "verdict": verdict,
                "paper_says": "" if claim is None else ("moves" if claim.moves else "does not move"),
                "paper_verdict": _paper_locomotion_verdict(claim, verdict),
                "source": "" if claim is None else claim.source,
            }
        )
    columns = ["task", "backend", "num_envs", "epochs", "horizon", "env_steps", "algo", "seeds"]
    columns += ["untrained_velocity", "final_velocity", "final_velocity_ci_low", "final_velocity_ci_high"]
    return pd.DataFrame(rows, columns=columns + ["seeds_moving", "verdict", "paper_says", "paper_verdict", "source"])
