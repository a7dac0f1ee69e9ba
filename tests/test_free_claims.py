"""The free claims (harness/report/free_claims.py) on synthetic runs whose numbers are known: Fig. 2's
gradient-variance comparison (paired log-ratios of per-run epoch medians, the verdict's cases, seeds that
pair), Fig. 4b's lambda against the optimiser's pace (the Adam step bound, where phi starts, the
config's lambda optimiser, the two verdicts), Fig. 3's roughness ratio over final policies and
Proposition 1's bound against the pooled one-step gains."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from harness.report.free_claims import (
    BOUND_FAILS,
    BOUND_HOLDS,
    PACED,
    RATE_LIMITED,
    adam_step_bound,
    ema,
    gradient_variance_claim_table,
    gradient_variance_curves,
    lambda_rate_table,
    landscape_claim_table,
    plot_gradient_variance_curves,
    step_gain_claim_table,
)
from harness.report.records import RunRecord

EVALUATED = {"initial": {"mean_return": 0.0}, "final": {"mean_return": 1.0}}
LR = 5e-4
PHI0 = math.log(0.95 / 0.05)  # where TDAdpt starts phi: lambda = cfg.lam = 0.95


def record(
    root: Path,
    algo: str,
    seed: int,
    columns: dict[str, list],
    finished: bool = True,
    planned: int = 2000,
    task: str = "ant",
    algo_config: dict | None = None,
) -> RunRecord:
    """A run as the report reads it: its metrics (one row per epoch, ``columns`` beside epoch and env_steps)
    and, when ``algo_config`` is given, a config.json whose ``algo`` section holds it."""
    epochs = len(next(iter(columns.values())))
    path = root / f"{task}_{algo}_s{seed}_e{planned}"
    path.mkdir(parents=True, exist_ok=True)
    if algo_config is not None:
        (path / "config.json").write_text(json.dumps({"task": task, "algo": {"algo": algo} | algo_config}))
    metrics = pd.DataFrame({"epoch": range(epochs), "env_steps": [2048 * (e + 1) for e in range(epochs)]} | columns)
    return RunRecord(
        path=path,
        task=task,
        backend="newton",
        algo=algo,
        horizon=32,
        seed=seed,
        num_envs=64,
        metrics=metrics,
        evaluation=EVALUATED if finished else None,
        planned_epochs=planned,
    )


def levels_run(root, algo, seed, level, nsr=1.0, **kw) -> RunRecord:
    """A run whose actor_grad_var has epoch median ``level`` (with a NaN epoch and a spike far above it,
    which the median ignores) and whose noise-to-signal ratio is ``nsr`` in every epoch."""
    var = [level * 0.5, math.nan, level, level * 1e9, level * 0.9, level * 2.0]
    return record(root, algo, seed, {"actor_grad_var": var, "actor_grad_nsr": [nsr] * 6}, **kw)


def row_of(table: pd.DataFrame, **where) -> pd.Series:
    mask = np.logical_and.reduce([table[k] == v for k, v in where.items()])
    assert mask.sum() == 1, table
    return table[mask].iloc[0]


# -- Fig. 2 -----------------------------------------------------------------------------------------
def test_a_variant_100_times_lower_on_every_seed_is_confirmed(tmp_path):
    base = [3e4, 1e4, 2e4, 5e3, 8e3]
    noise = [1.3, 0.8, 1.1, 0.9, 1.0]  # the per-seed ratio varies about 1/100
    runs = [levels_run(tmp_path, "shac", s, b) for s, b in enumerate(base)]
    variant = np.array(base) * np.array(noise) / 100.0
    runs += [levels_run(tmp_path, "shac-tdadpt", s, v) for s, v in enumerate(variant)]
    table = gradient_variance_claim_table(runs)
    row = row_of(table, algo="shac-tdadpt", statistic="actor_grad_var")
    logs = np.log(np.array(noise) / 100.0)
    low, high = stats.t.interval(0.95, len(logs) - 1, loc=logs.mean(), scale=stats.sem(logs))
    assert row["pairs"] == 5 and row["base"] == "shac"
    assert row["ratio"] == pytest.approx(math.exp(logs.mean()))
    assert (row["ratio_ci_low"], row["ratio_ci_high"]) == pytest.approx((math.exp(low), math.exp(high)))
    assert row["level_base"] == pytest.approx(stats.gmean(base))
    assert (row["level_base_min"], row["level_base_max"]) == (5e3, 3e4)
    assert row["level_algo"] / row["level_base"] == pytest.approx(row["ratio"])
    assert row["verdict"] == "confirmed" and row["source"] == "Fig. 2" and "1e4" in row["paper_levels"]
    # the noise-to-signal ratio is the same on both sides: its row is open
    nsr = row_of(table, algo="shac-tdadpt", statistic="actor_grad_nsr")
    assert nsr["ratio"] == pytest.approx(1.0) and nsr["verdict"] == "undecided"


def test_levels_equal_in_distribution_are_undecided(tmp_path):
    base = [1e3, 2e3, 3e3, 4e3, 5e3]
    variant = [3e3, 5e3, 1e3, 4e3, 2e3]  # the same five levels on other seeds: the log-ratios sum to 0
    runs = [levels_run(tmp_path, "sapo", s, b) for s, b in enumerate(base)]
    runs += [levels_run(tmp_path, "sapo-tdfixed", s, v) for s, v in enumerate(variant)]
    row = row_of(gradient_variance_claim_table(runs), algo="sapo-tdfixed", statistic="actor_grad_var")
    assert row["ratio"] == pytest.approx(1.0)
    assert row["ratio_ci_low"] < 1.0 < row["ratio_ci_high"] and row["verdict"] == "undecided"


def test_one_pair_is_undecided_whatever_its_ratio(tmp_path):
    runs = [levels_run(tmp_path, "shac", 0, 1e4), levels_run(tmp_path, "shac-tdfixed", 0, 1e1)]
    row = row_of(gradient_variance_claim_table(runs), statistic="actor_grad_var")
    assert row["pairs"] == 1 and row["ratio"] == pytest.approx(1e-3)
    assert math.isnan(row["ratio_ci_low"]) and row["verdict"] == "undecided (under 2 pairs)"


def test_only_seeds_both_algorithms_finished_are_pairs(tmp_path):
    runs = [levels_run(tmp_path, "shac", s, 1e4) for s in (0, 1)]
    runs.append(levels_run(tmp_path, "shac", 2, 1e4, finished=False))  # its seed-2 variant has no partner
    runs += [levels_run(tmp_path, "shac-tdadpt", s, level) for s, level in ((0, 1e2), (1, 1.2e2), (2, 1e9))]
    runs.append(levels_run(tmp_path, "shac-tdadpt", 3, 1e9))  # no base run of seed 3 at all
    row = row_of(gradient_variance_claim_table(runs), statistic="actor_grad_var")
    assert row["pairs"] == 2 and row["ratio"] == pytest.approx(math.sqrt(1e-2 * 1.2e-2))
    assert row["level_algo_max"] == 1.2e2 and row["verdict"] == "confirmed"


@pytest.mark.parametrize(("planned", "verdict"), [(2000, "contradicted"), (500, "not confirmed at this budget")])
def test_a_higher_variance_contradicts_only_at_the_papers_protocol(tmp_path, planned, verdict):
    runs = [levels_run(tmp_path, "shac", s, 1e3 * (s + 1), planned=planned) for s in range(3)]
    runs += [levels_run(tmp_path, "shac-tdfixed", s, 1e5 * (s + 1.5), planned=planned) for s in range(3)]
    row = row_of(gradient_variance_claim_table(runs), statistic="actor_grad_var")
    assert row["ratio_ci_low"] > 1.0 and row["verdict"] == verdict and row["epochs"] == planned


def test_an_unresolved_noise_to_signal_level_is_not_a_pair(tmp_path):
    runs = [levels_run(tmp_path, "shac", s, 1e4, nsr=2.0) for s in range(3)]
    runs += [levels_run(tmp_path, "shac-tdadpt", s, 1e2, nsr=math.inf if s == 2 else 1.0) for s in range(3)]
    row = row_of(gradient_variance_claim_table(runs), statistic="actor_grad_nsr")
    assert (row["pairs"], row["pairs_unresolved"]) == (2, 1) and row["ratio"] == pytest.approx(0.5)


def test_curves_are_the_smoothed_finite_epochs_of_every_run(tmp_path):
    runs = [levels_run(tmp_path, "shac", 0, 10.0), levels_run(tmp_path, "shac-tdadpt", 1, 1.0, finished=False)]
    curves = gradient_variance_curves(runs, "actor_grad_var", weight=0.5)
    shac = curves[curves["algo"] == "shac"]
    assert list(shac["env_steps"]) == [2048, 6144, 8192, 10240, 12288]  # the NaN epoch is left out
    # bias-corrected EMA of 5, 10, 1e10, 9, 20 at weight 0.5: (0.5 s + 0.5 x) / (1 - 0.5^t)
    s1 = 2.5 / 0.5
    s2 = (0.5 * 2.5 + 5.0) / 0.75
    assert shac["value"].iloc[0] == pytest.approx(s1) and shac["value"].iloc[1] == pytest.approx(s2)
    assert set(curves["seed"]) == {0, 1} and list(curves.columns)[-4:] == ["algo", "seed", "env_steps", "value"]
    assert ema(np.full(7, 3.0), 0.9) == pytest.approx(np.full(7, 3.0))
    assert plot_gradient_variance_curves(curves, tmp_path / "fig2.png").stat().st_size > 0


# -- Fig. 4b ----------------------------------------------------------------------------------------
def lambda_run(root, seed, pace, epochs=5, **kw) -> RunRecord:
    """An adaptive run whose phi falls by ``pace`` each epoch from logit(0.95); ``lam`` logged after each
    epoch's update, as training logs it (so the first logged value has already moved once)."""
    phi = PHI0 - pace * np.arange(1, epochs + 1)
    return record(root, "shac-tdadpt", seed, {"lam": list(1.0 / (1.0 + np.exp(-phi)))}, **kw)


def test_the_adam_step_bound_is_reached_by_a_growing_gradient_of_one_sign():
    torch = pytest.importorskip("torch")
    betas, t = (0.7, 0.95), 40
    k = np.arange(t)
    a = (1 - betas[0]) * betas[0] ** k / (1 - betas[0] ** t)
    c = (1 - betas[1]) * betas[1] ** k / (1 - betas[1] ** t)
    phi = torch.nn.Parameter(torch.zeros((), dtype=torch.float64))
    opt = torch.optim.AdamW([phi], lr=LR, betas=betas, weight_decay=0.0)
    for g in (a / c)[::-1] * 1e3:  # the gradient of step t - k is proportional to a_k / c_k
        before = float(phi.detach())
        phi.grad = torch.tensor(float(g), dtype=torch.float64)
        opt.step()
    assert (before - float(phi.detach())) / LR == pytest.approx(adam_step_bound(t, betas), rel=1e-6)
    assert adam_step_bound(1, betas) == pytest.approx(1.0)
    assert adam_step_bound(100_000, betas) == pytest.approx(0.3 / math.sqrt(0.05 * (1 - 0.49 / 0.95)))


def test_lambda_falling_by_lr_every_epoch_is_at_the_rate_limit(tmp_path):
    runs = [lambda_run(tmp_path, s, LR) for s in range(3)]
    row = row_of(lambda_rate_table(runs), algo="shac-tdadpt")
    # phi starts at logit(0.95), before the first logged value: all 5 updates count, so the share is 1
    # (measured from the first logged value it would be 4 updates' travel over 5: 0.8)
    assert row["updates"] == 5 and row["limit"] == pytest.approx(5 * LR)
    assert row["delta_phi"] == pytest.approx(-5 * LR) and row["used_share"] == pytest.approx(1.0)
    assert row["worst_case_limit"] > row["limit"] and row["falling_share"] == 1.0
    assert row["verdict"] == RATE_LIMITED and row["source"] == "Fig. 4b"


def test_lambda_falling_at_30_percent_of_the_limit_sets_its_own_pace(tmp_path):
    runs = [lambda_run(tmp_path, s, pace * LR) for s, pace in enumerate((0.28, 0.30, 0.32))]
    runs.append(lambda_run(tmp_path, 3, LR, finished=False))  # an unfinished run does not count
    row = row_of(lambda_rate_table(runs), algo="shac-tdadpt")
    assert row["seeds"] == 3 and row["used_share"] == pytest.approx(0.30)
    assert (row["used_share_min"], row["used_share_max"]) == pytest.approx((0.28, 0.32))
    assert row["delta_phi_ci_high"] < 0.0 and row["verdict"] == PACED


def test_lambda_that_rises_on_one_seed_is_undecided(tmp_path):
    runs = [lambda_run(tmp_path, s, pace * LR) for s, pace in enumerate((0.3, -0.3, 0.1))]
    assert row_of(lambda_rate_table(runs), algo="shac-tdadpt")["verdict"] == "undecided"


def test_the_limit_follows_the_runs_lambda_optimiser(tmp_path):
    # two steps of lr 1e-3 per epoch: a fall of 2e-3 an epoch is the limit; one update every other epoch
    # with lr 1e-3: a fall of 1e-3 every other epoch is
    twice = {"lambda_lr": 1e-3, "lambda_iterations": 2.0, "lam": 0.95}
    runs = [lambda_run(tmp_path / "a", s, 2e-3, algo_config=twice) for s in range(2)]
    row = row_of(lambda_rate_table(runs), algo="shac-tdadpt")
    assert row["updates"] == 10 and row["used_share"] == pytest.approx(1.0) and row["verdict"] == RATE_LIMITED
    half = {"lambda_lr": 1e-3, "lambda_iterations": 0.5, "lam": 0.95}
    phi = PHI0 - 1e-3 * np.array([1, 1, 2, 2, 3, 3])  # updates in epochs 0, 2, 4
    lam = list(1.0 / (1.0 + np.exp(-phi)))
    runs = [record(tmp_path / "b", "shac-tdadpt", s, {"lam": lam}, algo_config=half) for s in range(2)]
    row = row_of(lambda_rate_table(runs), algo="shac-tdadpt")
    assert row["updates"] == 3 and row["used_share"] == pytest.approx(1.0) and row["lambda_lr"] == 1e-3


# -- Fig. 3 -----------------------------------------------------------------------------------------
def landscape_run(root, algo, seed, h_step, td_lambda, planned=2000) -> RunRecord:
    run = record(root, algo, seed, {"actor_grad_var": [1.0]}, planned=planned)
    run.landscape = {"grid": 40, "span": 1.0, "num_envs": 16, "roughness": {"h_step": h_step, "td_lambda": td_lambda}}
    return run


def test_a_td_lambda_loss_smoother_on_every_policy_is_confirmed(tmp_path):
    ratios = [1.8, 2.2, 2.0, 1.9]
    runs = [landscape_run(tmp_path, "sapo-tdfixed", s, 0.5 * r, 0.5) for s, r in enumerate(ratios)]
    row = landscape_claim_table(runs).iloc[0]
    assert row["policies"] == 4 and row["verdict"] == "confirmed"
    assert row["ratio"] == pytest.approx(math.exp(np.mean(np.log(ratios))))
    logs = np.log(ratios)
    margin = stats.t.ppf(0.975, 3) * logs.std(ddof=1) / 2.0
    assert row["ratio_ci_low"] == pytest.approx(math.exp(logs.mean() - margin))


@pytest.mark.parametrize(("planned", "verdict"), [(2000, "contradicted"), (500, "not confirmed at this budget")])
def test_an_h_step_loss_smoother_contradicts_only_at_the_papers_protocol(tmp_path, planned, verdict):
    runs = [landscape_run(tmp_path, "sapo", s, 0.5, 0.5 * r, planned) for s, r in enumerate([1.9, 2.1, 2.0])]
    assert landscape_claim_table(runs).iloc[0]["verdict"] == verdict


def test_one_policy_or_an_unmapped_surface_does_not_decide(tmp_path):
    runs = [landscape_run(tmp_path, "sapo", 0, 2.0, 1.0), landscape_run(tmp_path, "sapo", 1, None, 1.0)]
    row = landscape_claim_table(runs).iloc[0]
    assert (row["policies"], row["unmapped"]) == (1, 1)
    assert row["verdict"].startswith("undecided")


# -- Proposition 1 ----------------------------------------------------------------------------------
def gain_run(root, algo, seed, gains, growth=1.2, task="ant") -> RunRecord:
    run = record(root, algo, seed, {"actor_grad_var": [1.0]}, task=task)
    rows = [{"state_gain": g, "action_gain": 1.0, "joint_gain": g} for g in gains]
    run.step_gain = {
        "paper_bound": 1.0 / (0.99 * 0.95),
        "rows": rows,
        "window": {"per_step_growth": {"median": growth}},
    }
    return run


def test_the_bound_is_read_on_the_pooled_95th_percentile(tmp_path):
    # 96 of 100 states below the bound: the pooled 95th percentile is below, so it holds ...
    calm = gain_run(tmp_path, "sapo", 0, [1.01] * 60 + [5.0] * 2)
    calmer = gain_run(tmp_path, "sapo-tdfixed", 0, [1.02] * 36 + [6.0] * 2)
    row = step_gain_claim_table([calm, calmer]).iloc[0]
    assert (row["policies"], row["states"]) == (2, 100)
    assert row["verdict"] == BOUND_HOLDS and row["share_above_bound"] == pytest.approx(0.04)
    # ... and one more policy whose states are mostly above turns it
    stiff = gain_run(tmp_path, "sapo-tdadpt", 0, [40.0] * 20)
    row = step_gain_claim_table([calm, calmer, stiff]).iloc[0]
    assert row["verdict"] == BOUND_FAILS and row["gain_p95"] == pytest.approx(40.0)
    assert (row["gain_p95_min"], row["gain_p95_max"]) == (
        pytest.approx(np.quantile([1.01] * 60 + [5.0] * 2, 0.95)),
        40.0,
    )


def test_tasks_are_judged_apart(tmp_path):
    runs = [gain_run(tmp_path, "shac", 0, [1.0] * 10), gain_run(tmp_path, "shac", 0, [9.0] * 10, task="go2")]
    table = step_gain_claim_table(runs)
    assert dict(zip(table["task"], table["verdict"], strict=True)) == {"ant": BOUND_HOLDS, "go2": BOUND_FAILS}
