"""The report's intervals and tests on synthetic seeds: how often each holds the truth, measured by
simulation at the seed counts the reports use, rather than assumed (docs/statistics.md).

Each scenario draws seed-paired outcomes (variant_s, base_s) from a known distribution whose true value of
the interval's estimand is known: normal pairs (correlated either way, since pairing can), a mixture in
which a seed fails outright (a fifth of the seeds return about a quarter of the rest, as the Ant's SHAC
seed 4 did), and lognormal (right-skewed). Procedures:

- ``paired_fieller``: the claims' interval of mean(variant) / mean(base) - 1 at one look (95%; 97.5% for
  Fig. 6's two judged ablation settings, at their 3 pairs);
- ``sequential``: the design's two looks (5 and 10 pairs, 97.5% each), counted as covering only when both
  looks hold the truth, which bounds the coverage of every stopping rule, futility included;
- ``poi_percentile``: rliable's probability of improvement with its percentile bootstrap interval,
  unpaired, as the returns table showed it (truth: P(X > Y) of the two distributions);
- ``iqm_percentile``: the IQM's percentile bootstrap interval over seeds (truth: the distribution's IQM).
- ``log_ratio_t``: the free claims' interval (Fig. 2's gradient-variance levels, Fig. 3's roughness): the
  one-sample t interval of the paired log-ratios, exponentiated (truth: exp E[log variant - log base]);
  on the scenarios whose outcomes are positive (lognormal, the failed-seed mixture).
- ``sequential_mean``: the forward-locomotion verdict's looks (one algorithm's mean, a one-sample t interval
  at 5 and 10 seeds, 97.5% each), counted as covering only when both looks hold the true mean; on the
  base side of the no-effect scenarios.

``python -m harness.report.coverage OUT_DIR [REPS]`` writes the table as ``coverage.md`` and ``.csv`` with
provenance; tests/test_coverage.py asserts the claims' procedures within tolerance of nominal and that the
check fails the percentile PoI interval at 5 seeds.
"""

from __future__ import annotations

import functools
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from harness.report.sequential import LOOK_ALPHAS, LOOKS
from harness.report.stats import iqm_with_ci, mean_with_t_ci, paired_ratio_ci, probability_of_improvement_with_ci

BASE_MEAN, BASE_STD = 5000.0, 1500.0  # the scale of an Ant return; every statistic here is scale-free
FAIL_SHARE, FAIL_LEVEL = 0.2, 0.25  # a failed seed: a fifth of seeds, returning a quarter of the others


@dataclass(frozen=True)
class Scenario:
    """Seed-paired outcomes: ``draw(rng, reps, n)`` -> (variant, base), each reps x n; ``ratio``: the true
    E[variant] / E[base]; ``poi``: the true P(variant > base) for independent draws of each."""

    name: str
    draw: Callable[[np.random.Generator, int, int], tuple[np.ndarray, np.ndarray]]
    ratio: float
    poi: float


def normal_pairs(effect: float, correlation: float) -> Scenario:
    """Normal outcomes, the variant's mean (1 + effect) times the base's, equal spread, correlated."""
    cov = BASE_STD**2 * np.array([[1.0, correlation], [correlation, 1.0]])
    mean = np.array([(1.0 + effect) * BASE_MEAN, BASE_MEAN])

    def draw(rng, reps, n):
        x = rng.multivariate_normal(mean, cov, size=(reps, n), method="cholesky")
        return x[..., 0], x[..., 1]

    poi = float(stats.norm.cdf(effect * BASE_MEAN / (BASE_STD * math.sqrt(2.0))))
    return Scenario(f"normal, effect {effect:+.0%}, correlation {correlation:+.1f}", draw, 1.0 + effect, poi)


def failed_seeds(effect: float) -> Scenario:
    """Each seed of either algorithm fails on its own with probability FAIL_SHARE (a quarter of the base's
    level); the variant's successful seeds are (1 + effect) times the base's."""

    def side(rng, reps, n, level):
        ok = rng.normal(level, BASE_STD, size=(reps, n))
        return np.where(rng.random((reps, n)) < FAIL_SHARE, rng.normal(FAIL_LEVEL * BASE_MEAN, 200.0, (reps, n)), ok)

    def draw(rng, reps, n):
        return side(rng, reps, n, (1.0 + effect) * BASE_MEAN), side(rng, reps, n, BASE_MEAN)

    def mean(level):
        return (1.0 - FAIL_SHARE) * level + FAIL_SHARE * FAIL_LEVEL * BASE_MEAN

    ratio = mean((1.0 + effect) * BASE_MEAN) / mean(BASE_MEAN)
    sample = draw(np.random.default_rng(12345), 2000, 100)  # P(X > Y) of the mixture, by a large draw
    poi = float(np.mean(sample[0][:, :, None] > sample[1][:, None, :]))
    return Scenario(f"a failed seed (p {FAIL_SHARE}), effect {effect:+.0%}", draw, ratio, poi)


def lognormal(effect: float, sigma: float = 0.5) -> Scenario:
    """Independent lognormal outcomes (right-skewed), the variant's scaled by 1 + effect."""

    def draw(rng, reps, n):
        scale = BASE_MEAN * np.exp(-0.5 * sigma**2)
        return (1.0 + effect) * scale * rng.lognormal(0.0, sigma, (reps, n)), scale * rng.lognormal(
            0.0, sigma, (reps, n)
        )

    poi = float(stats.norm.cdf(math.log1p(effect) / (sigma * math.sqrt(2.0))))
    return Scenario(f"lognormal (sigma {sigma}), effect {effect:+.0%}", draw, 1.0 + effect, poi)


def scenarios() -> list[Scenario]:
    """The report's scenarios: no effect and the paper's +50%, under each shape."""
    out = []
    for effect in (0.0, 0.5):
        out += [normal_pairs(effect, 0.5), normal_pairs(effect, -0.5), failed_seeds(effect), lognormal(effect)]
    return out


def fieller_covers(variant: np.ndarray, base: np.ndarray, ratio: float, confidence: float = 0.95) -> bool:
    """Whether the paired Fieller interval at ``confidence`` holds the true ratio."""
    _, low, high = paired_ratio_ci(variant, base, confidence)
    return bool(low <= ratio - 1.0 <= high)


def sequential_covers(variant: np.ndarray, base: np.ndarray, ratio: float) -> bool:
    """Whether every look of the design (its first LOOKS[k] pairs at 1 - LOOK_ALPHAS[k]) holds the truth."""
    return all(
        fieller_covers(variant[:n], base[:n], ratio, 1.0 - alpha) for n, alpha in zip(LOOKS, LOOK_ALPHAS, strict=True)
    )


def poi_covers(variant: np.ndarray, base: np.ndarray, poi: float) -> bool:
    """Whether rliable's probability of improvement's percentile bootstrap interval holds the true P."""
    _, low, high = probability_of_improvement_with_ci([variant], [base])
    return bool(low <= poi <= high)


def iqm_covers(values: np.ndarray, truth: float) -> bool:
    """Whether the IQM's percentile bootstrap interval holds the distribution's IQM."""
    _, low, high = iqm_with_ci(values)
    return bool(low <= truth <= high)


def log_ratio_covers(variant: np.ndarray, base: np.ndarray, truth: float, confidence: float = 0.95) -> bool:
    """Whether the t interval of the mean paired log-ratio holds the true one (``truth``, a log)."""
    logs = np.log(variant) - np.log(base)
    margin = float(stats.t.ppf(0.5 + confidence / 2.0, logs.size - 1)) * float(logs.std(ddof=1)) / math.sqrt(logs.size)
    return bool(abs(float(logs.mean()) - truth) <= margin)


def true_log_ratio(scenario: Scenario) -> float:
    """E[log variant - log base] of the scenario, by a large draw."""
    variant, base = scenario.draw(np.random.default_rng(54321), 1, 400_000)
    return float(np.mean(np.log(variant[0])) - np.mean(np.log(base[0])))


def rough_outliers(effect: float, share: float = 0.2, jump: float = 1.5, sigma: float = 0.5) -> Scenario:
    """Lognormal outcomes whose log-ratio is right-skewed: in a ``share`` of pairs the variant's outcome is
    ``exp(jump)`` times larger (one policy whose surface is far rougher than the rest), else scaled by
    1 + effect. Only the log-ratio interval reads it (``ratio`` and ``poi`` are not used)."""

    def draw(rng, reps, n):
        base = BASE_MEAN * rng.lognormal(0.0, sigma, (reps, n))
        shift = np.where(rng.random((reps, n)) < share, jump, 0.0)
        return (1.0 + effect) * base * np.exp(shift) * rng.lognormal(0.0, sigma, (reps, n)), base

    return Scenario(f"lognormal, a fifth of the log-ratios +{jump}, effect {effect:+.0%}", draw, math.nan, math.nan)


def log_scenarios() -> list[Scenario]:
    """The log-ratio interval's scenarios (positive outcomes): lognormal and right-skewed log-ratios."""
    return [make(effect) for effect in (0.0, 0.5) for make in (lognormal, rough_outliers)]


@functools.lru_cache(maxsize=32)
def _large_base_draw(scenario: Scenario) -> np.ndarray:
    """400,000 draws of the base side (a fixed generator), from which its true statistics are read; made
    once per scenario (a frozen, hashable value) however many statistics and seed counts read it."""
    _, base = scenario.draw(np.random.default_rng(54321), 1, 400_000)
    draw = base[0].copy()
    draw.flags.writeable = False
    return draw


def true_iqm(scenario: Scenario) -> float:
    """The base distribution's interquartile mean, by a large draw."""
    return float(stats.trim_mean(_large_base_draw(scenario), 0.25))


def true_mean(scenario: Scenario) -> float:
    """The base distribution's mean, by a large draw."""
    return float(_large_base_draw(scenario).mean())


def sequential_mean_covers(values: np.ndarray, truth: float) -> bool:
    """Whether both looks' one-sample t intervals (each on its first LOOKS[k] values, at 1 - LOOK_ALPHAS[k])
    hold the true mean: the event that bounds the locomotion verdict's error at any true mean."""
    for n, alpha in zip(LOOKS, LOOK_ALPHAS, strict=True):
        _, low, high = mean_with_t_ci(values[:n], 1.0 - alpha)
        if not low <= truth <= high:
            return False
    return True


def coverage(scenario: Scenario, procedure: str, n: int, reps: int, seed: int = 0, nominal: float = 0.95) -> float:
    """The share of ``reps`` synthetic experiments of ``n`` seed pairs whose interval holds the truth;
    ``nominal`` is the level ``paired_fieller`` is computed at (the other procedures have their own)."""
    variant, base = scenario.draw(np.random.default_rng(seed), reps, max(n, LOOKS[-1]))
    if procedure == "paired_fieller":
        hits = [fieller_covers(v[:n], b[:n], scenario.ratio, nominal) for v, b in zip(variant, base, strict=True)]
    elif procedure == "sequential":
        hits = [sequential_covers(v, b, scenario.ratio) for v, b in zip(variant, base, strict=True)]
    elif procedure == "poi_percentile":
        hits = [poi_covers(v[:n], b[:n], scenario.poi) for v, b in zip(variant, base, strict=True)]
    elif procedure == "iqm_percentile":
        truth = true_iqm(scenario)
        hits = [iqm_covers(b[:n], truth) for b in base]
    elif procedure == "sequential_mean":
        truth = true_mean(scenario)
        hits = [sequential_mean_covers(b, truth) for b in base]
    elif procedure == "log_ratio_t":
        truth = true_log_ratio(scenario)
        hits = [log_ratio_covers(v[:n], b[:n], truth) for v, b in zip(variant, base, strict=True)]
    else:
        raise ValueError(f"unknown procedure {procedure!r}")
    return float(np.mean(hits))


def coverage_table(reps: int = 2000) -> pd.DataFrame:
    """Every procedure's coverage under every scenario at the seed counts the reports use (the sequential
    design's at its own looks), with the Monte-Carlo standard error of each share."""
    rows = []
    plan = [(scenario, "paired_fieller", (3, *LOOKS), 0.95) for scenario in scenarios()]
    plan += [(scenario, "paired_fieller", (3,), 0.975) for scenario in scenarios()]  # Fig. 6's judged settings
    plan += [(scenario, "sequential", (LOOKS[-1],), 1.0 - sum(LOOK_ALPHAS)) for scenario in scenarios()]
    plan += [(scenario, "poi_percentile", LOOKS, 0.95) for scenario in scenarios()]
    # the IQM's interval reads one side: the no-effect scenarios cover it
    plan += [(scenario, "iqm_percentile", LOOKS, 0.95) for scenario in scenarios() if scenario.ratio == 1.0]
    plan += [(scenario, "log_ratio_t", (3, *LOOKS), 0.95) for scenario in log_scenarios()]
    no_effect = [scenario for scenario in scenarios() if scenario.ratio == 1.0]
    plan += [(scenario, "sequential_mean", (LOOKS[-1],), 1.0 - sum(LOOK_ALPHAS)) for scenario in no_effect]
    for scenario, procedure, counts, nominal in plan:
        for n in counts:
            share = coverage(scenario, procedure, n, reps, nominal=nominal)
            rows.append(
                {
                    "scenario": scenario.name,
                    "procedure": procedure,
                    "seeds": n,
                    "nominal": nominal,
                    "coverage": share,
                    "mc_se": math.sqrt(share * (1.0 - share) / reps),
                    "reps": reps,
                }
            )
    return pd.DataFrame(rows)


_COLUMNS = [
    ("scenario", "scenario"),
    ("procedure", "procedure"),
    ("seeds", "seeds"),
    ("nominal", lambda r: f"{r['nominal']:.3f}"),
    ("coverage", lambda r: f"{r['coverage']:.3f} ± {r['mc_se']:.3f}"),
]


def main(argv: list[str]) -> int:
    """``python -m harness.report.coverage OUT_DIR [REPS]``: write coverage.md and coverage.csv."""
    from harness.report.documents import Section, Table, write_table
    from harness.results import path_problem, provenance

    if len(argv) not in (1, 2) or (len(argv) == 2 and not argv[1].isdigit()):
        print("usage: python -m harness.report.coverage OUT_DIR [REPS]", file=sys.stderr)
        return 2
    reps = int(argv[1]) if len(argv) == 2 else 2000
    if not 100 <= reps <= 100_000:
        print(f"REPS must be in [100, 100000], got {reps}", file=sys.stderr)
        return 2
    out = Path(argv[0])
    problem = path_problem(out / "coverage.provenance.json")
    if problem:
        print(f"cannot write under {out}: {problem}", file=sys.stderr)
        return 2
    table = Table(
        "coverage",
        "Coverage of the report's intervals on synthetic seeds",
        f"{reps} synthetic experiments per row (harness/report/coverage.py)",
        [Section(coverage_table(reps), _COLUMNS)],
        [__doc__.split("\n\n")[1].replace("\n", " ")],
    )
    out.mkdir(parents=True, exist_ok=True)
    command = "python -m harness.report.coverage " + " ".join(argv)
    for path in write_table(table, out, provenance(command)):
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
