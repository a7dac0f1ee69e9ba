"""The pre-registered analysis of the paper's claims of improvement (docs/statistics.md): estimand,
interval, decision rule and verdict words, applied at fixed looks as seeds arrive, and how many seeds
each comparison still wants (which the protocol's planner reads, ``harness/suite/bench.py``).

The design is paired: seed s gives every algorithm the same initial policy and the same environments, so
a claim is judged on seed pairs (variant_s, base_s). The estimand is the paper's: the relative change of
the mean final return, theta = E[variant] / E[base] - 1 (Fig. 5 normalises by the base's mean). Its
interval is the paired Fieller interval (:func:`harness.report.stats.paired_ratio_ci`). Seeds are added
in a group-sequential design with two looks, at 5 and at the paper's 10 pairs; the 0.05 error is split
evenly between them (Bonferroni), so the looks' repeated confidence intervals hold the true change
together with probability at least 0.95 whatever the correlation between looks, and a verdict read at
either look keeps that level. A comparison stops at the first look that decides it; it also stops,
undecided, when it is futile (:func:`futile`); the futility rule is non-binding (it only ever stops
seeds), so it cannot raise an error rate.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from harness.report.stats import mean_with_t_ci, paired_ratio_bounds, paired_ratio_ci

#: the looks: seed pairs at which a claim is judged (the second is the paper's 10 seeds)
LOOKS = (5, 10)
#: the two-sided error spent at each look (Bonferroni: they sum to 0.05)
LOOK_ALPHAS = (0.025, 0.025)
#: the paper's training protocol (ARE Sec. IV): N = 64 envs, h = 32, 2000 epochs, on every task
PAPER_NUM_ENVS, PAPER_HORIZON, PAPER_EPOCHS = 64, 32, 2000

UNDECIDED = "undecided"
CONFIRMED = "confirmed"
CONTRADICTED = "contradicted"
NOT_CONFIRMED = "not confirmed at this budget"


def at_paper_protocol(num_envs: int | None, planned_epochs: int | None, horizon: int | None) -> bool:
    """Whether a setting is the paper's training protocol (N, h and at least its epochs): only there can a
    claim be contradicted; below it a claim is at most not confirmed at this budget."""
    return num_envs == PAPER_NUM_ENVS and horizon == PAPER_HORIZON and (planned_epochs or 0) >= PAPER_EPOCHS


def verdict(low: float, high: float, claimed: float, paper_protocol: bool) -> str:
    """The verdict a look's interval [low, high] of theta gives a claimed improvement ``claimed`` > 0.

    confirmed: the interval lies above 0 and does not exclude the claimed size from above (it holds it, or
    lies above it). Claimed size excluded from above (high < claimed): contradicted at the paper's protocol,
    not confirmed at this budget elsewhere (a smaller budget or another setting cannot speak for the
    paper's). undecided: the interval holds both 0 and the claimed size. A qualifier in parentheses says
    which side: larger than claimed, an improvement smaller than claimed, below the base."""
    if math.isnan(low) or math.isnan(high):
        return f"{UNDECIDED} (no interval)"
    if low > 0.0 and high >= claimed:
        return f"{CONFIRMED} (larger than claimed)" if low > claimed else CONFIRMED
    if high < claimed:
        word = CONTRADICTED if paper_protocol else NOT_CONFIRMED
        if low > 0.0:
            return f"{word} (an improvement, smaller than claimed)"
        return f"{word} (below the base)" if high < 0.0 else f"{word} (claimed size excluded)"
    return UNDECIDED


#: a comparison undecided at a look stops when its conditional power is below this (a common threshold)
FUTILITY_POWER = 0.10
#: the draws of :func:`conditional_power` (a fixed generator: the planner's decision is reproducible)
FUTILITY_DRAWS = 2000


def conditional_power(variant: np.ndarray, base: np.ndarray, claimed: float, look: int, paper_protocol: bool) -> float:
    """The chance that the next look decides a claim undecided at look ``look``, were the seeds to come from
    what this look's pairs show: the next look's new pairs drawn from a bivariate normal with these pairs'
    means and sample covariance (``FUTILITY_DRAWS`` draws, a fixed generator), each completed sample judged
    by the next look's own interval and :func:`verdict`."""
    n_next, confidence = LOOKS[look + 1], 1.0 - LOOK_ALPHAS[look + 1]
    pairs = np.column_stack([variant, base])
    mean, cov = pairs.mean(axis=0), np.cov(pairs, rowvar=False, ddof=1)
    rng = np.random.default_rng(0)
    new = rng.multivariate_normal(mean, cov, size=(FUTILITY_DRAWS, n_next - len(pairs)), method="svd")
    samples = np.concatenate([np.broadcast_to(pairs, (FUTILITY_DRAWS, *pairs.shape)), new], axis=1)
    low, high = paired_ratio_bounds(samples[..., 0], samples[..., 1], confidence)
    decided = [
        not verdict(lo, hi, claimed, paper_protocol).startswith(UNDECIDED) for lo, hi in zip(low, high, strict=True)
    ]
    return float(np.mean(decided))


def futile(variant: np.ndarray, base: np.ndarray, claimed: float, look: int, paper_protocol: bool) -> bool:
    """Whether a comparison undecided at look ``look`` (not the last) stops anyway: its conditional power
    (:func:`conditional_power`) is below ``FUTILITY_POWER``. Non-binding: it only ever withholds seeds, and
    each look's interval keeps its level whether or not later looks happen, so the design's error rates
    hold with or without it."""
    return conditional_power(variant, base, claimed, look, paper_protocol) < FUTILITY_POWER


@dataclass(frozen=True)
class Look:
    """A claim judged at one look of the design: the pairs it read, its estimate and interval, the verdict,
    and what the design does next (``state``)."""

    pairs: int  # seed pairs available (both algorithms evaluated), or seeds for one algorithm's mean
    look: int | None  # index into LOOKS of the look judged; None before the first
    used: int  # pairs the look read (its own count: pairs beyond it wait for the next look)
    estimate: float  # the estimand at the look: the relative change of the mean, or a mean
    low: float
    high: float
    confidence: float
    verdict: str
    state: str  # "before first look", "decided", "futile", "continue", "last look"

    @property
    def seeds_wanted(self) -> int:
        """The seeds per algorithm this comparison asks for: the next look's when it continues, the look's own
        otherwise (the first look's before it)."""
        if self.look is None:
            return LOOKS[0]
        return LOOKS[self.look + 1] if self.state == "continue" else LOOKS[self.look]


def judge(variant: np.ndarray, base: np.ndarray, claimed: float, paper_protocol: bool) -> Look:
    """Apply the design to seed-paired values (``variant[i]``, ``base[i]`` of the i-th common seed, in seed
    order): judge at the last look reached, on that look's first pairs only."""
    variant, base = np.asarray(variant, dtype=float), np.asarray(base, dtype=float)
    pairs = variant.size
    reached = [k for k, n in enumerate(LOOKS) if pairs >= n]
    if not reached:
        change, low, high = paired_ratio_ci(variant, base) if pairs else (math.nan,) * 3
        return Look(
            pairs, None, pairs, change, low, high, 0.95, f"{UNDECIDED} (before the first look)", "before first look"
        )
    for k in reached:  # a claim decided at an earlier look keeps that look's verdict
        n, confidence = LOOKS[k], 1.0 - LOOK_ALPHAS[k]
        change, low, high = paired_ratio_ci(variant[:n], base[:n], confidence)
        said = verdict(low, high, claimed, paper_protocol)
        if not said.startswith(UNDECIDED):
            return Look(pairs, k, n, change, low, high, confidence, said, "decided")
    if k == len(LOOKS) - 1:
        return Look(pairs, k, n, change, low, high, confidence, said, "last look")
    if futile(variant[:n], base[:n], claimed, k, paper_protocol):
        return Look(pairs, k, n, change, low, high, confidence, f"{UNDECIDED} (futile)", "futile")
    return Look(pairs, k, n, change, low, high, confidence, said, "continue")


def judge_mean(values: np.ndarray, verdict_of: Callable[[float, float], str]) -> Look:
    """The same looks for a claim about one algorithm's mean (the forward-locomotion verdict, docs/statistics.md):
    at each look reached, the one-sample t interval of the look's first values (seed order) at the look's level,
    read by ``verdict_of(low, high)`` (any word but one starting "undecided" decides); a verdict reached keeps
    its look. No futility stop. Before the first look: the 95% interval of every value, for description only."""
    values = np.asarray(values, dtype=float)
    reached = [k for k, n in enumerate(LOOKS) if values.size >= n]
    if not reached:
        mean, low, high = mean_with_t_ci(values)
        return Look(
            values.size,
            None,
            values.size,
            mean,
            low,
            high,
            0.95,
            f"{UNDECIDED} (before the first look)",
            "before first look",
        )
    for k in reached:
        n, confidence = LOOKS[k], 1.0 - LOOK_ALPHAS[k]
        mean, low, high = mean_with_t_ci(values[:n], confidence)
        said = verdict_of(low, high)
        if not said.startswith(UNDECIDED):
            return Look(values.size, k, n, mean, low, high, confidence, said, "decided")
    state = "last look" if k == len(LOOKS) - 1 else "continue"
    return Look(values.size, k, n, mean, low, high, confidence, said, state)
