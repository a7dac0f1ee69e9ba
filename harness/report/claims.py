"""The paper's claims about final returns, each judged against the runs that test it.

A claim says a TD-lambda variant beats its base by about a given share of the base's mean return at the
paper's budget (ARE, Section V: Fig. 5 for the Ant, Fig. 9 and the abstract for the Go2). A setting
tests it when both algorithms have evaluated runs there; the verdict reads the 95% CI of the measured
relative change of the mean (:func:`claim_verdict`), so a budget or a seed count that cannot decide
says "undecided" rather than a point estimate's guess.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from harness.report.records import RunRecord, by_group, value_or_range
from harness.report.stats import relative_mean_change_with_ci


@dataclass(frozen=True)
class Claim:
    task: str
    algo: str
    base: str
    change: float  # the claimed relative change of the mean final return, 0.5 = +50%
    source: str


PAPER_CLAIMS = (
    Claim("ant", "shac-tdfixed", "shac", 0.25, "Fig. 5"),
    Claim("ant", "shac-tdadpt", "shac", 0.50, "Fig. 5"),
    Claim("ant", "sapo-tdfixed", "sapo", 0.40, "Fig. 5"),
    Claim("ant", "sapo-tdadpt", "sapo", 0.50, "Fig. 5"),
    Claim("go2", "shac-tdadpt", "shac", 1.00, 'abstract, Fig. 9 ("almost 100%")'),
    Claim("go2", "sapo-tdfixed", "sapo", 0.25, "Fig. 9"),
    Claim("go2", "sapo-tdadpt", "sapo", 0.25, "Fig. 9"),
)


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
    finals = {key: np.array([r.final_return for r in members], dtype=float) for key, members in groups.items()}
    env_steps = {key: value_or_range(r.env_steps for r in members) for key, members in groups.items()}
    rows = []
    for claim in claims:
        for (task, backend, num_envs, planned, horizon, algo), variant in finals.items():
            base = finals.get((task, backend, num_envs, planned, horizon, claim.base))
            if task != claim.task or algo != claim.algo or base is None:
                continue
            change, low, high = relative_mean_change_with_ci(variant, base)
            rows.append(
                {
                    "task": task,
                    "backend": backend,
                    "num_envs": num_envs,
                    "epochs": planned,
                    "horizon": horizon,
                    "env_steps": env_steps[(task, backend, num_envs, planned, horizon, algo)],
                    "algo": algo,
                    "base": claim.base,
                    "seeds": variant.size,
                    "base_seeds": base.size,
                    "claimed_change": claim.change,
                    "measured_change": change,
                    "change_ci_low": low,
                    "change_ci_high": high,
                    "verdict": claim_verdict(low, high, claim.change),
                    "source": claim.source,
                }
            )
    columns = ["task", "backend", "num_envs", "epochs", "horizon", "env_steps", "algo", "base", "seeds"]
    columns += ["base_seeds", "claimed_change", "measured_change", "change_ci_low", "change_ci_high", "verdict"]
    return pd.DataFrame(rows, columns=columns + ["source"])
