"""The report's intervals and the sequential design, simulated on synthetic seeds with a known truth
(harness/report/coverage.py; docs/statistics.md): their coverage and error rates are measured here and
held within a stated tolerance of nominal, and the same check fails an interval known to under-cover."""

from __future__ import annotations

import numpy as np
import pytest

from harness.report import coverage as cov
from harness.report import sequential
from harness.report.sequential import LOOK_ALPHAS, LOOKS, judge

# Tolerance: about three Monte-Carlo standard errors of a 95% coverage at REPS experiments.
REPS = 1200
TOLERANCE = 0.02


def monte_carlo_tolerance(nominal: float, reps: int = REPS) -> float:
    """Three Monte-Carlo standard errors of a coverage share whose truth is ``nominal``."""
    return 3.0 * float(np.sqrt(nominal * (1.0 - nominal) / reps))


def check_coverage(
    procedure: str, n: int, scenarios: list[cov.Scenario], nominal: float, reps: int = REPS
) -> dict[str, float]:
    """Each scenario's measured coverage; AssertionError naming those below ``nominal - TOLERANCE``."""
    measured = {s.name: cov.coverage(s, procedure, n, reps, seed=7, nominal=nominal) for s in scenarios}
    short = {name: share for name, share in measured.items() if share < nominal - TOLERANCE}
    assert not short, f"{procedure} at {n} seeds covers under {nominal} - {TOLERANCE}: {short}"
    return measured


@pytest.mark.parametrize(("n", "nominal"), [(3, 0.95), (3, 0.975), *((n, 0.95) for n in LOOKS)])
def test_the_claims_paired_interval_keeps_its_coverage_at_the_reports_seed_counts(n, nominal):
    """At the claims' looks (5 and 10 pairs, 95%) and at the Fig. 6 ablation's 3 pairs (95% described, 97.5%
    judged)."""
    measured = check_coverage("paired_fieller", n, cov.scenarios(), nominal)
    # and it is not needlessly wide: no scenario over-covers by more than the tolerance (at 97.5% skewed or failing
    # seeds make it conservative, as docs/statistics.md says, and this bound no longer binds) ...
    assert max(measured.values()) <= nominal + TOLERANCE + 0.01, measured
    # ... and where its model holds (normal pairs) it covers at its level, within three Monte-Carlo standard errors
    exact = {name: share for name, share in measured.items() if name.startswith("normal")}
    assert exact, measured
    assert all(abs(share - nominal) <= monte_carlo_tolerance(nominal) for share in exact.values()), exact


@pytest.mark.parametrize("n", (3, *LOOKS))
def test_the_free_claims_log_ratio_interval_keeps_its_coverage_when_the_log_ratios_are_normal(n):
    """Fig. 2's and Fig. 3's interval (t on paired log-ratios) at the policy counts those rows report,
    on lognormal outcomes: the model the interval assumes."""
    lognormal = [s for s in cov.log_scenarios() if s.name.startswith("lognormal (")]
    assert len(lognormal) == 2
    check_coverage("log_ratio_t", n, lognormal, 0.95)


@pytest.mark.parametrize("n", (3, *LOOKS))
def test_the_free_claims_log_ratio_interval_under_skew_falls_short_as_documented(n):
    """With a fifth of the log-ratios jumping (one policy far rougher than the rest) the t interval
    covers less than 95%: docs/statistics.md states the shortfall (about 0.93 at 3 to 10 pairs) and
    this pins it, so a change in either shows here."""
    skewed = [s for s in cov.log_scenarios() if "a fifth" in s.name]
    assert len(skewed) == 2
    measured = check_coverage("log_ratio_t", n, skewed, 0.95 - 0.04)
    assert min(measured.values()) < 0.95 - 0.005, measured


def test_the_two_looks_hold_the_truth_together_at_the_designs_level():
    """Both looks' 97.5% intervals cover at once in at least 95% of experiments: every stopping rule's
    interval (futility included) then covers at least as often."""
    assert sum(LOOK_ALPHAS) == pytest.approx(0.05)
    check_coverage("sequential", LOOKS[-1], cov.scenarios(), 1.0 - sum(LOOK_ALPHAS))


def test_the_locomotion_looks_hold_the_mean_together_unless_the_seeds_are_right_skewed():
    """The forward-locomotion verdict's two looks (one algorithm's mean, one-sample t at 97.5% each) hold the
    true mean together at 95% for normal seeds and for a failed seed's mixture; under right skew (lognormal,
    sigma 0.5) they fall short, about 0.91, with the upper bound too low: docs/statistics.md states it and
    this pins it."""
    base_sides = [s for s in cov.scenarios() if s.ratio == 1.0]
    shaped = [s for s in base_sides if not s.name.startswith("lognormal")]
    assert len(shaped) == 3
    check_coverage("sequential_mean", LOOKS[-1], shaped, 1.0 - sum(LOOK_ALPHAS))
    skewed = [s for s in base_sides if s.name.startswith("lognormal")]
    measured = check_coverage("sequential_mean", LOOKS[-1], skewed, 0.95 - 0.07)
    assert max(measured.values()) < 0.95 - 0.01, measured


def test_the_locomotion_verdict_is_read_at_the_looks_and_kept_once_reached():
    from harness.report.claims import locomotion_verdict
    from harness.report.sequential import judge_mean

    still = np.array([0.0, 0.02, -0.03, 0.01, 0.0])
    first = judge_mean(still, locomotion_verdict)
    assert (first.look, first.used, first.state, first.verdict) == (0, 5, "decided", "does not move forward")
    assert first.confidence == pytest.approx(1.0 - LOOK_ALPHAS[0]) and first.seeds_wanted == LOOKS[0]
    later = judge_mean(np.r_[still, [2.0, 2.1, 1.9, 2.2, 2.0]], locomotion_verdict)  # seeds 6-10 walk
    assert (later.look, later.used, later.verdict) == (0, 5, first.verdict)  # the first look's verdict stands
    mixed = np.array([0.0, 1.0, 0.1, 0.9, 0.5])
    open_look = judge_mean(mixed, locomotion_verdict)
    assert (open_look.state, open_look.verdict, open_look.seeds_wanted) == ("continue", "undecided", LOOKS[1])
    waiting = judge_mean(np.r_[mixed, [5.0, 5.0]], locomotion_verdict)  # 7 seeds: the next look is at 10
    assert (waiting.used, waiting.estimate) == (5, pytest.approx(mixed.mean()))
    before = judge_mean(mixed[:3], locomotion_verdict)
    assert (before.state, before.look, before.seeds_wanted) == ("before first look", None, LOOKS[0])
    assert before.verdict == "undecided (before the first look)" and before.confidence == 0.95


def test_the_check_fails_the_percentile_bootstrap_interval_of_the_probability_of_improvement():
    """The returns table's former P(algo > base) interval: unpaired percentile bootstrap at 5 seeds. With
    an effect it covers far below 95%, and the check above says so."""
    scenarios = [cov.normal_pairs(0.5, -0.5), cov.failed_seeds(0.5), cov.lognormal(0.5)]
    with pytest.raises(AssertionError, match="poi_percentile at 5 seeds covers under"):
        check_coverage("poi_percentile", 5, scenarios, 0.95, reps=400)  # it misses by far more than 400 resolve


def _design_rates(effect: float, claimed: float, reps: int, monkeypatch) -> dict[str, float]:
    """Run the whole design (looks, futility, verdicts) on ``reps`` synthetic experiments of normal pairs
    (correlation -0.5, the Ant's sign); the share of each verdict's first word and of seeds it used."""
    monkeypatch.setattr(sequential, "FUTILITY_DRAWS", 200)  # fewer draws: a noisier but still non-binding rule
    scenario = cov.normal_pairs(effect, -0.5)
    variant, base = scenario.draw(np.random.default_rng(3), reps, LOOKS[-1])
    words, seeds = [], []
    for v, b in zip(variant, base, strict=True):
        look = judge(v[: LOOKS[0]], b[: LOOKS[0]], claimed, paper_protocol=True)
        if look.state == "continue":
            look = judge(v, b, claimed, paper_protocol=True)
        words.append(look.verdict.split(" (")[0])
        seeds.append(look.used)
    words = np.array(words)
    return {w: float(np.mean(words == w)) for w in set(words)} | {"mean_seeds": float(np.mean(seeds))}


def test_the_design_confirms_no_effect_and_contradicts_a_true_claim_at_most_at_its_level(monkeypatch):
    """No true effect: 'confirmed' (an improvement read where there is none) at most 0.025 + tolerance,
    the one-sided half of the design's error. The claimed effect true: 'contradicted' likewise."""
    null = _design_rates(0.0, 0.5, 400, monkeypatch)
    assert null.get("confirmed", 0.0) <= 0.025 + TOLERANCE, null
    true_claim = _design_rates(0.5, 0.5, 400, monkeypatch)
    assert true_claim.get("contradicted", 0.0) <= 0.025 + TOLERANCE, true_claim
    # and it decides: with the claimed +50% true, most experiments confirm it within 10 seeds
    assert true_claim.get("confirmed", 0.0) > 0.5, true_claim
    assert LOOKS[0] <= true_claim["mean_seeds"] <= LOOKS[-1]


def test_the_design_stops_a_decided_claim_at_the_first_look_and_keeps_that_verdict():
    rng = np.random.default_rng(0)
    base = rng.normal(5000.0, 300.0, 10)
    variant = 2.0 * base + rng.normal(0.0, 50.0, 10)  # +100%, tight: decided at 5 pairs
    first = judge(variant[:5], base[:5], 0.5, paper_protocol=True)
    assert (first.state, first.verdict, first.used, first.seeds_wanted) == (
        "decided",
        "confirmed (larger than claimed)",
        5,
        5,
    )
    later = judge(np.r_[variant[:5], base[5:]], base, 0.5, paper_protocol=True)  # pairs 6-10 show no effect
    assert (later.verdict, later.used, later.look) == (first.verdict, 5, 0)  # the first look's verdict stands


def test_below_the_papers_protocol_a_claimed_size_excluded_is_not_confirmed_rather_than_contradicted():
    rng = np.random.default_rng(1)
    base = rng.normal(1000.0, 50.0, 5)
    variant = 0.6 * base + rng.normal(0.0, 20.0, 5)  # -40% against a claimed +100%
    at_paper = judge(variant, base, 1.0, paper_protocol=True)
    below = judge(variant, base, 1.0, paper_protocol=False)
    assert at_paper.verdict == "contradicted (below the base)"
    assert below.verdict == "not confirmed at this budget (below the base)"


def test_an_undecided_claim_continues_unless_futile():
    rng = np.random.default_rng(2)
    base = rng.normal(5000.0, 1500.0, 5)
    promising = base * 1.6 + rng.normal(0.0, 1500.0, 5)
    look = judge(promising, base, 0.5, paper_protocol=True)
    if look.state == "decided":  # the draw decided already: make it noisier, the point is the open case
        promising = base * 1.6 + rng.normal(0.0, 4000.0, 5)
        look = judge(promising, base, 0.5, paper_protocol=True)
    assert look.state in ("continue", "futile")
    power = sequential.conditional_power(promising, base, 0.5, 0, True)
    assert (look.state == "futile") == (power < sequential.FUTILITY_POWER)
    assert look.seeds_wanted == (LOOKS[1] if look.state == "continue" else LOOKS[0])
    before = judge(promising[:3], base[:3], 0.5, paper_protocol=True)
    assert (before.state, before.look, before.seeds_wanted) == ("before first look", None, LOOKS[0])


def test_the_sign_flip_p_value_counts_the_sign_patterns_exactly():
    from harness.report.stats import sign_flip_p_value

    assert sign_flip_p_value([1.0, 2.0, 3.0, 4.0, 5.0]) == pytest.approx(2 / 32)  # only all-plus and all-minus
    assert sign_flip_p_value([9.0, 9.0, 9.0, 9.0, -86.0]) == pytest.approx(1.0)
    assert sign_flip_p_value([1.0, -1.0]) == pytest.approx(1.0)
    assert sign_flip_p_value([3.0, 1.0, 2.0, -0.5]) == pytest.approx(4 / 16)  # +-(3,1,2,-.5) and +-(3,1,2,.5)
