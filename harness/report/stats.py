"""Every statistic of the harness's reports, in one place: the bench report (``harness/report/tables.py``)
and the ``report`` verb (``harness/report/compare.py``) both compute their numbers here.

Interquartile mean (IQM): ``scipy.stats.trim_mean(x, 0.25)``, the definition of rliable (Agarwal et al.
2021). Its 95% CI is scipy's percentile bootstrap over training seeds with 2000 resamples. rliable's
stratified bootstrap resamples seeds within each task; every row of a table is one task and one backend,
i.e. one stratum, so the stratified bootstrap is the plain bootstrap over seeds. Across tasks (the
aggregate IQM, the probability of improvement, performance profiles) the point estimates are
``rliable.metrics``' own and the intervals rliable's stratified bootstrap, drawn here (last section).
Every CI uses a fresh ``np.random.default_rng(0)``, so a row's CI depends on its own data only and the
tables are reproducible.

Also here: the difference of two IQMs and the ratio of two geometric means with two-sample (unpaired)
bootstrap CIs; for the paper's claims, which the seeds pair (seed s: the same initial policy and
environments for every algorithm), the relative change of the means with its paired Fieller interval,
the paired t interval and the exact sign-flip p-value (docs/statistics.md, the analysis plan); the mean
with a one-sample t CI (the learned lambda's course), the geometric mean with its CI,
the median over a run's logged epochs, the sample std, and the statistical power of a two-sample
comparison (the smallest detectable difference, the seeds needed).
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from scipy import stats

IQM_TRIM = 0.25  # cut 25% at each end: the mean of the middle half (rliable's IQM)
BOOTSTRAP_RESAMPLES = 2000
CONFIDENCE = 0.95
BOOTSTRAP_SEED = 0


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


def _t_critical(dof: float, confidence: float = CONFIDENCE) -> float:
    """The two-sided critical value of Student's t at ``confidence`` with ``dof`` degrees of freedom."""
    return float(stats.t.ppf(1.0 - (1.0 - confidence) / 2.0, dof))


# -- the paired design (seed s of every algorithm: the same initial policy and environments) ------------
def paired_ratio_ci(variant: Iterable[float], base: Iterable[float], confidence: float = CONFIDENCE) -> tuple:
    """mean(variant) / mean(base) - 1 over seed-paired values (``variant[i]`` and ``base[i]`` share seed i),
    with the paired Fieller interval at ``confidence``: the ratios r for which the one-sample t-test of
    d_i(r) = variant_i - r base_i having mean 0 (n - 1 degrees of freedom) does not reject, minus 1.

    That set solves a quadratic in r, (mean_v - r mean_b)^2 <= (t^2 / n) var(v - r b). It is a bounded
    interval when the base's mean is told from 0 at this level (the quadratic's leading coefficient
    mean_b^2 - (t^2/n) var_b is positive); otherwise it is unbounded and reported as (-inf, inf). Paired
    because the seeds are (common random numbers): the variance of v - r b carries the seeds' covariance,
    so the interval keeps its level whatever the sign of the correlation, where an unpaired (Welch) interval
    is too narrow when the algorithms' seeds are negatively correlated and too wide when positively.
    Returns (point, low, high); NaN bounds under 2 pairs, all NaN when the base's mean is not positive."""
    v, b = np.asarray(list(variant), dtype=float), np.asarray(list(base), dtype=float)
    if v.shape != b.shape:
        raise ValueError(f"paired samples differ in size: {v.size} against {b.size}")
    if not v.size or not b.mean() > 0.0:
        return (math.nan,) * 3
    point = float(v.mean() / b.mean() - 1.0)
    if v.size < 2:
        return point, math.nan, math.nan
    low, high = paired_ratio_bounds(v, b, confidence)
    return point, float(low), float(high)


def paired_ratio_bounds(variant: np.ndarray, base: np.ndarray, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """The paired Fieller bounds of mean(variant) / mean(base) - 1 along the last axis (n >= 2 pairs), for
    many samples at once (the planner's and the coverage simulations' draws): (-inf, inf) where the
    quadratic's leading coefficient is not positive. :func:`paired_ratio_ci` is the one-sample entry."""
    v, b = np.asarray(variant, dtype=float), np.asarray(base, dtype=float)
    n = v.shape[-1]
    k = float(stats.t.ppf(1.0 - (1.0 - confidence) / 2.0, n - 1)) ** 2 / n
    mv, mb = v.mean(axis=-1), b.mean(axis=-1)
    var_v, var_b = v.var(axis=-1, ddof=1), b.var(axis=-1, ddof=1)
    cov = ((v - mv[..., None]) * (b - mb[..., None])).sum(axis=-1) / (n - 1)
    a = mb**2 - k * var_b
    half_b = mv * mb - k * cov  # the quadratic a r^2 - 2 half_b r + c <= 0
    c = mv**2 - k * var_v
    root = np.sqrt(np.maximum(half_b * half_b - a * c, 0.0))  # >= 0 when a > 0: r = mv / mb solves it
    bounded = a > 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        low = np.where(bounded, (half_b - root) / a - 1.0, -np.inf)
        high = np.where(bounded, (half_b + root) / a - 1.0, np.inf)
    return low, high


def sign_flip_p_value(differences: Iterable[float]) -> float:
    """The exact two-sided sign-flip (paired permutation) p-value of the mean of paired differences: the share
    of the 2^n sign patterns whose |mean| reaches the observed one. Its smallest value is 2 / 2^n (0.0625 at
    5 pairs), which is why it cannot decide at 5 seeds and is shown beside the t-test, not instead of it."""
    d = np.asarray(list(differences), dtype=float)
    if d.size < 1 or d.size > 20:
        return math.nan
    signs = 1 - 2 * ((np.arange(2**d.size)[:, None] >> np.arange(d.size)) & 1)
    means = np.abs((signs * d).mean(axis=1))
    return float(np.mean(means >= abs(d.mean()) - 1e-12 * max(1.0, abs(d.mean()))))


def mean_with_t_ci(values: Iterable[float], confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """The mean with the CI of a one-sample t-test at ``confidence`` (95% by default), mean +- t(n - 1) s /
    sqrt(n); NaN bounds under 2 values."""
    x = np.asarray(list(values), dtype=float)
    if not x.size:
        return (math.nan,) * 3
    mean = float(x.mean())
    if x.size < 2:
        return mean, math.nan, math.nan
    margin = _t_critical(x.size - 1, confidence) * float(x.std(ddof=1)) / math.sqrt(x.size)
    return mean, mean - margin, mean + margin


def sample_std(values: Iterable[float]) -> float:
    """The sample standard deviation (n - 1); NaN under 2 values."""
    x = np.asarray(values if isinstance(values, np.ndarray) else list(values), dtype=float)
    return float(np.std(x, ddof=1)) if x.size > 1 else math.nan


def epoch_median(values: Iterable[float | None]) -> float:
    """The median over the epochs that logged a value: NaN and None (a skipped update, a run from before
    the statistic) are dropped, +inf (an unresolved noise-to-signal ratio) is kept; NaN when none is left."""
    x = np.asarray([math.nan if v is None else v for v in values], dtype=float)
    x = x[~np.isnan(x)]
    return float(np.median(x)) if x.size else math.nan


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


def paired_minimum_detectable_difference(spread: float, pairs: int) -> float:
    """The smallest true mean difference a two-sided paired t-test (level ALPHA) detects with probability
    POWER over ``pairs`` seed pairs whose differences have standard deviation ``spread``:
    (t_(1-a/2) + t_power) s / sqrt(n) at n - 1 degrees of freedom."""
    if pairs < 2 or not math.isfinite(spread):
        return math.nan
    t = stats.t.ppf(1 - ALPHA / 2, pairs - 1) + stats.t.ppf(POWER, pairs - 1)
    return float(t * spread / math.sqrt(pairs))


def seeds_needed(spread: float, difference: float, limit: int = 10_000) -> int | None:
    """Seeds per algorithm for :func:`minimum_detectable_difference` to reach ``difference``; None when
    the spread is unknown or more than ``limit`` would be needed."""
    if not (math.isfinite(spread) and math.isfinite(difference) and difference > 0):
        return None
    for n in range(2, limit + 1):
        if minimum_detectable_difference(spread, n, n) <= difference:
            return n
    return None


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


# -- the field's statistics across tasks (rliable, Agarwal et al. 2021) ----------------------------
# A score set is one array of run scores per task (the tasks may have different numbers of runs). The
# point estimates are rliable.metrics' own functions; their 95% intervals are rliable's stratified
# bootstrap (rliable.library.get_interval_estimates, percentile method): every resample draws each task's
# runs with replacement within that task, and for a comparison each algorithm's runs on their own
# (StratifiedIndependentBootstrap). rliable.library does not import with this project's pandas 3 (its
# bootstrap comes from arch < 8), so the resampling is drawn here; tests/test_report.py checks these
# intervals against rliable.library's on the same scores.
TaskScores = list[np.ndarray]


def _aggregate_iqm(scores: TaskScores) -> float:
    from rliable import metrics

    flat = np.concatenate([np.asarray(s, dtype=float) for s in scores])
    return float(metrics.aggregate_iqm(flat[:, None]))


def probability_of_improvement(x: TaskScores, y: TaskScores) -> float:
    from rliable import metrics

    per_task = [
        metrics.probability_of_improvement(np.asarray(a, float)[:, None], np.asarray(b, float)[:, None])
        for a, b in zip(x, y, strict=True)
    ]
    return float(np.mean(per_task))


def _pairwise_improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) + P(X = Y) / 2 along the last axis of resampled ``x`` (R x n) and ``y`` (R x m): the
    Mann-Whitney U statistic over n m, which is what rliable.metrics.probability_of_improvement computes."""
    greater = (x[:, :, None] > y[:, None, :]).mean(axis=(1, 2))
    ties = (x[:, :, None] == y[:, None, :]).mean(axis=(1, 2))
    return greater + 0.5 * ties


def _resample(scores: TaskScores, rng: np.random.Generator) -> list[np.ndarray]:
    """BOOTSTRAP_RESAMPLES stratified resamples: per task an array R x n_task of that task's runs."""
    out = []
    for s in scores:
        s = np.asarray(s, dtype=float)
        out.append(s[rng.integers(0, s.size, size=(BOOTSTRAP_RESAMPLES, s.size))])
    return out


def _interval(samples: np.ndarray) -> tuple[float, float]:
    tail = 100 * (1 - CONFIDENCE) / 2
    return float(np.percentile(samples, tail)), float(np.percentile(samples, 100 - tail))


def aggregate_iqm_with_ci(scores: TaskScores) -> tuple[float, float, float]:
    """rliable's aggregate IQM over every run of every task, with its stratified-bootstrap 95% CI (NaN
    bounds when no task has 2 runs)."""
    point = _aggregate_iqm(scores)
    if max(len(s) for s in scores) < 2:
        return point, math.nan, math.nan
    resampled = np.concatenate(_resample(scores, np.random.default_rng(BOOTSTRAP_SEED)), axis=1)
    return point, *_interval(_iqm_along(resampled, axis=1))


def probability_of_improvement_with_ci(x: TaskScores, y: TaskScores) -> tuple[float, float, float]:
    """rliable's probability of improvement of X over Y (P(X_m > Y_m) averaged over tasks m), with the
    95% CI of its stratified independent bootstrap; NaN bounds when a side has under 2 runs on every task."""
    point = probability_of_improvement(x, y)
    if max(len(s) for s in x) < 2 or max(len(s) for s in y) < 2:
        return point, math.nan, math.nan
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    rx, ry = _resample(x, rng), _resample(y, rng)
    samples = np.mean([_pairwise_improvement(a, b) for a, b in zip(rx, ry, strict=True)], axis=0)
    return point, *_interval(samples)


def performance_profile_with_ci(
    scores: TaskScores, thresholds: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """rliable's run-score distribution: at each threshold tau the fraction of runs scoring above tau
    (averaged over tasks), with stratified-bootstrap 95% bands (NaN bands when no task has 2 runs)."""
    thresholds = np.asarray(thresholds, dtype=float)

    def fraction(per_task: list[np.ndarray]) -> np.ndarray:  # (R x n) per task -> R x thresholds
        return np.mean([(s[..., :, None] > thresholds).mean(axis=-2) for s in per_task], axis=0)

    point = fraction([np.asarray(s, dtype=float) for s in scores])
    if max(len(s) for s in scores) < 2:
        nan = np.full_like(point, np.nan)
        return point, nan, nan
    samples = fraction(_resample(scores, np.random.default_rng(BOOTSTRAP_SEED)))
    tail = 100 * (1 - CONFIDENCE) / 2
    return point, np.percentile(samples, tail, axis=0), np.percentile(samples, 100 - tail, axis=0)
