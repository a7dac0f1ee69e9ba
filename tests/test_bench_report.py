"""The benchmark suite's tables and plots (the package harness/report/) on synthetic run directories whose
numbers are known: IQM and bootstrap CIs, improvement over the base algorithm, gradient-variance quartiles
and growth, the wall-time split, sim-to-sim gaps, landscapes, checks, provenance and the PNGs."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from harness.report import write_bench_report
from harness.report.documents import header_lines
from harness.report.plots import curve_settings, learning_curve_frame, plot_returns_vs_h
from harness.report.records import base_algo, collect_runs, load_run
from harness.report.stats import minimum_detectable_difference, paired_minimum_detectable_difference, seeds_needed
from harness.report.tables import (
    grad_variance_growth_table,
    grad_variance_table,
    power_table,
    returns_table,
    returns_vs_h_table,
)

COMMIT = "c0ffee1"
HEADER = {
    "profile": "unit",
    "command": "python -m harness bench --profile unit",
    "commit": COMMIT,
    "created_utc": "2026-01-02T03:04:05Z",
    "packages": {"torch": "2.13.0+cpu", "newton": "1.8.0", "mujoco-warp": None},
    "machine": {"cpu_model": "Test CPU", "cpu_count": 2, "OMP_NUM_THREADS": "1", "gpus": []},
}
EPOCHS = 4
# per epoch: seconds of each part; update = actor + critic + lambda (as algorithms/actor_critic.py logs them)
SIM_FORWARD, BACKWARD, ACTOR, CRITIC, LAMBDA = 0.5, 0.3, 0.1, 0.08, 0.02
UPDATE = ACTOR + CRITIC + LAMBDA
EPOCH_S = 1.2  # 0.2 s a epoch of "other"


def _eval_payload(final: float, initial: float = -50.0, **extra) -> dict:
    block = lambda value: {"mean_return": value, "std_over_seeds": 0.0, "per_seed": []}  # noqa: E731
    return (
        {"num_envs": 8, "seeds": 2, "deterministic": True, "max_steps": None}
        | extra
        | {
            "initial": block(initial),
            "final": block(final),
            "provenance": {"git_commit": "e7a1"},
        }
    )


def make_run(
    root: Path,
    task: str,
    backend: str,
    algo: str,
    seed: int,
    horizon: int,
    final: float | None,
    grad_var: list[float],
    split_update: bool = True,
    num_envs: int = 4,
    epochs: int = EPOCHS,
    extra: dict[str, list] | None = None,
) -> Path:
    """A run directory as harness/run/train.py leaves it: config.json, metrics.jsonl and (unless final is None)
    eval.json. ``grad_var``: actor_grad_var of each epoch (NaN allowed, as the log has it)."""
    setting = "" if (num_envs, epochs) == (4, EPOCHS) else f"_n{num_envs}_e{epochs}"
    run = root / f"{task}_{backend}_{algo}_h{horizon}_s{seed}{setting}"
    run.mkdir(parents=True)
    config = {
        "task": task,
        "backend": backend,
        "seed": seed,
        "device": "cpu",
        "epochs": epochs,
        "algo": {"algo": algo, "num_envs": num_envs, "horizon": horizon, "gamma": 0.99, "lam": 0.95},
        "provenance": {"git_commit": "7ra1ned"},
    }
    (run / "config.json").write_text(json.dumps(config))
    rows = []
    for epoch in range(epochs):
        row = {
            "epoch": epoch,
            "env_steps": (epoch + 1) * num_envs * horizon,
            "wall_s": (epoch + 1) * EPOCH_S,
            "epoch_s": EPOCH_S,
            "sim_forward_s": SIM_FORWARD,
            "backward_s": BACKWARD,
            "update_s": UPDATE,
            "actor_loss": -1.0,
            "actor_grad_norm": 1.0,
            "actor_grad_var": grad_var[epoch],
            "lam": 0.95 - 0.01 * epoch,
            "alpha": 1.0 - 0.1 * epoch,
            "entropy": 1.0,
            # no finished episode in the first epoch: null, as train.py logs it
            "train_episode_return": None if epoch == 0 else 10.0 * epoch + seed,
            "train_episode_return_avg": None if epoch == 0 else 5.0 * epoch + seed,
        }
        if split_update:
            row |= {"actor_update_s": ACTOR, "critic_update_s": CRITIC, "lambda_update_s": LAMBDA}
        row |= {name: values[epoch] for name, values in (extra or {}).items()}
        rows.append(row)
    # json.dumps writes NaN as the NaN literal, exactly as the training log does
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    if final is not None:
        (run / "eval.json").write_text(json.dumps(_eval_payload(final)))
    return run


SHAC_FINALS = [1.0, 2.0, 3.0, 4.0, 100.0]
TDADPT_FINALS = [10.0, 11.0, 12.0, 13.0, 14.0]
H16_GRAD_VAR = [1.0, 2.0, 3.0, math.nan]
H32_GRAD_VAR = [4.0, 8.0, 12.0, math.nan]
# another block's runs at h=32 (8 envs, 6 epochs, as the h-sweep beside a headline grid): never pooled with them
OTHER_SETTING = {"num_envs": 8, "epochs": 6}
OTHER_FINALS = [500.0, 600.0]
OTHER_GRAD_VAR = [1000.0] * 6


@pytest.fixture(scope="module")
def suite(tmp_path_factory):
    """Synthetic suite: Ant on Newton (shac and shac-tdadpt, 5 seeds, h=16; shac at h=32 with one
    unfinished seed), Ant on MuJoCo-Warp (shac, h=16, old log without the update split), a sim-to-sim
    evaluation, a landscape and three checks; then the report."""
    root = tmp_path_factory.mktemp("bench")
    runs_root = root / "runs"
    for seed, final in enumerate(SHAC_FINALS):
        make_run(runs_root, "ant", "newton", "shac", seed, 16, final, H16_GRAD_VAR)
    for seed, final in enumerate(TDADPT_FINALS):
        make_run(runs_root, "ant", "newton", "shac-tdadpt", seed, 16, final, [5.0, 5.0, 5.0, 5.0])
    for seed, final in enumerate([20.0, 30.0, None]):  # seed 2 never finished: no eval.json
        make_run(runs_root, "ant", "newton", "shac", seed, 32, final, H32_GRAD_VAR)
    make_run(runs_root, "ant", "mujoco_warp", "shac", 0, 16, 7.0, [1.0] * EPOCHS, split_update=False)
    for seed, final in enumerate(OTHER_FINALS):
        make_run(runs_root, "ant", "newton", "shac", seed, 32, final, OTHER_GRAD_VAR, **OTHER_SETTING)

    sim2sim = runs_root / "ant_newton_shac_h16_s0"
    payload = _eval_payload(-5.0, backend="mujoco_warp", trained_on="newton")
    (sim2sim / "eval_on_mujoco_warp.json").write_text(json.dumps(payload))

    grid = 5
    alphas = np.linspace(-1.0, 1.0, grid)
    surface = np.add.outer(alphas, alphas)
    landscape = {
        "task": "ant",
        "backend": "newton",
        "algo": "shac-tdadpt",
        "seed": 0,
        "horizon": 16,
        "num_envs": 4,
        "grid": grid,
        "span": 1.0,
        "lambda": 0.9,
        "alphas": alphas.tolist(),
        "betas": alphas.tolist(),
        "losses": {"h_step": surface.tolist(), "td_lambda": (0.5 * surface).tolist()},
        "roughness": {"h_step": 2.0, "td_lambda": 0.5},
    }
    (runs_root / "ant_newton_shac-tdadpt_h16_s0" / "landscape.json").write_text(json.dumps(landscape))

    checks = root / "checks"
    checks.mkdir()
    throughput = {
        "backend": "newton",
        "task": "ant",
        "num_envs": 64,
        "horizon": 32,
        "windows": 3,
        "forward_steps_per_s": 10000.0,
        "forward_backward_steps_per_s": 2500.0,
        "bare_engine_steps_per_s": 3000.0,
        "bare_forward_steps_per_s": 12000.0,
        "overhead_ratio": 1.2,
        "forward_overhead_ratio": 1.2,
        "gradient_cost_factor": 4.0,
    }
    gradcheck = {"backend": "newton", "task": "ant", "max_rel_error": 1e-3, "tolerance": 2e-2, "passed": True}
    crosscheck = {
        "task": "ant",
        "segments": {
            "contact_free": {"pairs": {"newton vs mujoco_warp": {"actions": {"rel_diff": 0.01, "cosine": 0.999}}}}
        },
    }
    check_files = []
    for name, content in (
        (
            "throughput_ant_newton_1.json",
            {"kind": "throughput", "result": throughput, "provenance": {"git_commit": "abc"}},
        ),
        (
            "gradcheck_ant_newton_2.json",
            {
                "kind": "gradcheck",
                "result": gradcheck,
                "provenance": {
                    "git_commit": "abc",
                    "command": "python -m harness gradcheck --backend newton --task ant --preset rewarped "
                    "--backend-option fd_scheme=forward --out x.json",
                },
            },
        ),
        ("crosscheck_ant_newton-mujoco_warp_3.json", {"kind": "crosscheck", "result": crosscheck}),
        ("parity_ant_newton-mujoco_warp_4.json", {"result": crosscheck}),  # no kind: skipped with one line
    ):
        (checks / name).write_text(json.dumps(content))
        check_files.append(checks / name)
    check_files.append(checks / "never_written.json")  # a failed job's output: must not crash the report

    out = root / "report"
    log = io.StringIO()
    written = write_bench_report(collect_runs(runs_root), check_files, out, HEADER, stream=log)
    return {"root": runs_root, "out": out, "written": written, "log": log.getvalue()}


def _row(frame: pd.DataFrame, **where) -> pd.Series:
    match = frame
    for key, value in where.items():
        match = match[match[key] == value]
    assert len(match) == 1, (where, match)
    return match.iloc[0]


def test_returns_iqm_ci_and_improvement(suite):
    returns = pd.read_csv(suite["out"] / "returns.csv")
    shac = _row(returns, task="ant", backend="newton", algo="shac", horizon=16)
    assert shac["seeds"] == 5
    assert shac["iqm_final"] == pytest.approx(3.0)  # the middle half of [1, 2, 3, 4, 100]
    assert shac["iqm_final"] == pytest.approx(stats.trim_mean(SHAC_FINALS, 0.25))
    assert shac["iqm_ci_low"] <= 3.0 <= shac["iqm_ci_high"]
    assert shac["mean_final"] == pytest.approx(22.0)
    assert shac["std_final"] == pytest.approx(np.std(SHAC_FINALS, ddof=1))
    assert shac["mean_initial"] == pytest.approx(-50.0)
    assert shac["env_steps"] == EPOCHS * 4 * 16
    assert pd.isna(shac["improvement_iqm"])  # a base algorithm has nothing to improve on

    tdadpt = _row(returns, task="ant", backend="newton", algo="shac-tdadpt", horizon=16)
    assert tdadpt["iqm_final"] == pytest.approx(12.0)
    assert tdadpt["iqm_ci_low"] <= 12.0 <= tdadpt["iqm_ci_high"]
    assert tdadpt["base"] == "shac"
    assert tdadpt["improvement_iqm"] == pytest.approx(12.0 - 3.0)
    # descriptive beside the claims table's verdict: no interval (an unpaired bootstrap reads a paired design)
    assert "improvement_ci_low" not in returns.columns and "p_improvement_ci_low" not in returns.columns


def test_probability_of_improvement_is_rliables(suite):
    from rliable import metrics

    returns = pd.read_csv(suite["out"] / "returns.csv")
    tdadpt = _row(returns, task="ant", backend="newton", algo="shac-tdadpt", horizon=16)
    expected = metrics.probability_of_improvement(np.array(TDADPT_FINALS)[:, None], np.array(SHAC_FINALS)[:, None])
    assert tdadpt["p_improvement"] == pytest.approx(expected) == pytest.approx(0.8)  # 20 of 25 pairs
    assert pd.isna(_row(returns, task="ant", backend="newton", algo="shac", horizon=16)["p_improvement"])


def test_paper_claims_are_judged_on_seed_pairs_by_the_pre_registered_design(suite):
    from harness.report.sequential import LOOK_ALPHAS, verdict

    claims = pd.read_csv(suite["out"] / "returns_claims.csv")
    # the synthetic suite tests one claim (Ant SHAC-TDAdpt over SHAC, +50%), at one setting: h 16
    row = _row(claims, task="ant", backend="newton", algo="shac-tdadpt")
    assert (row["base"], row["horizon"], row["pairs"], row["look"]) == ("shac", 16, 5, "5 pairs")
    assert row["claimed_change"] == 0.5 and row["confidence"] == pytest.approx(1.0 - LOOK_ALPHAS[0])
    assert row["measured_change"] == pytest.approx(np.mean(TDADPT_FINALS) / np.mean(SHAC_FINALS) - 1.0)
    low, high = row["change_ci_low"], row["change_ci_high"]
    # SHAC's seeds (1, 2, 3, 4, 100) cannot tell its mean from 0: the paired interval is unbounded
    assert (low, high) == (-math.inf, math.inf)
    assert row["verdict"].startswith("undecided") and verdict(low, high, 0.5, False) == "undecided"
    assert row["seeds_wanted"] in (5, 10) and row["design"] in ("continue", "futile")
    # descriptive columns: each side's IQM, rliable's P over the pairs, the exact sign-flip p: the differences
    # are 9, 9, 9, 9 and -86, so every one of the 32 sign patterns has a mean at least as far from 0: p = 1
    assert (row["iqm_algo"], row["iqm_base"]) == pytest.approx((12.0, 3.0))
    assert row["p_improvement"] == pytest.approx(0.8) and row["sign_flip_p"] == pytest.approx(1.0)
    assert row["spent_env_steps"] == 10 * EPOCHS * 4 * 16
    assert len(claims) == 1  # no other claim has both of its algorithms evaluated at one setting
    assert "## The paper's claims" in (suite["out"] / "returns.md").read_text()


def test_a_claim_reads_only_the_seeds_both_algorithms_have(tmp_path):
    from harness.report.claims import PAPER_CLAIMS, claims_table
    from harness.report.stats import paired_ratio_ci

    claim = [c for c in PAPER_CLAIMS if (c.task, c.algo) == ("ant", "shac-tdfixed")]
    finals = {"shac": {0: 100.0, 1: 120.0, 2: 90.0, 3: 130.0, 4: 110.0, 6: 500.0}}
    finals["shac-tdfixed"] = {0: 150.0, 1: 170.0, 2: 140.0, 3: 160.0, 4: 150.0, 5: 900.0}
    for algo, by_seed in finals.items():
        for seed, final in by_seed.items():
            make_run(tmp_path, "ant", "newton", algo, seed, 16, final, [1.0] * EPOCHS)
    row = claims_table([load_run(p) for p in collect_runs(tmp_path)], claim).iloc[0]
    common = [0, 1, 2, 3, 4]  # seed 5 has no base run and seed 6 no variant: neither is a pair
    variant = [finals["shac-tdfixed"][s] for s in common]
    base = [finals["shac"][s] for s in common]
    expected = paired_ratio_ci(variant, base, 0.975)
    assert row["pairs"] == 5
    assert (row["measured_change"], row["change_ci_low"], row["change_ci_high"]) == pytest.approx(expected)
    assert row["change_ci_low"] > 0.0 and row["verdict"] == "confirmed" and row["design"] == "decided"


def test_fig6_ablation_settings_are_paired_with_the_algorithms_own_runs_and_only_two_are_judged(tmp_path):
    """Each (b_lambda, m_lambda) setting of SAPO-TDAdpt is read against the algorithm's own runs on the seeds both
    have: (4, 2) and (4, 3) judged on direction at 97.5%, (1, 0.5) described at 95%; the main algorithms get
    no row."""
    from harness.report.claims import ablation_table
    from harness.report.stats import paired_ratio_ci

    finals = {(1, 1.0): [100.0, 120.0, 110.0], (4, 2.0): [20.0, 26.0, 56.0], (4, 3.0): [150.0, 170.0, 168.0]}
    finals[(1, 0.5)] = [105.0, 140.0]
    for (batches, iterations), values in finals.items():
        for seed, final in enumerate(values):
            root = tmp_path / f"b{batches}_m{iterations:g}"
            run = make_run(root, "ant", "newton", "sapo-tdadpt", seed, 16, final, [1.0] * EPOCHS)
            config = json.loads((run / "config.json").read_text())
            config["algo"] |= {"lambda_batches": batches, "lambda_iterations": iterations}
            (run / "config.json").write_text(json.dumps(config))
    make_run(tmp_path / "sapo", "ant", "newton", "sapo", 0, 16, 90.0, [1.0] * EPOCHS)
    table = ablation_table([load_run(p) for p in collect_runs(tmp_path)])
    rows = {row["algo"]: row for _, row in table.iterrows()}
    degrade, plummet = "sapo-tdadpt (b_lambda 4, m_lambda 2)", "sapo-tdadpt (b_lambda 4, m_lambda 3)"
    assert set(rows) == {degrade, plummet, "sapo-tdadpt (m_lambda 0.5)"}
    low_row = rows[degrade]
    expected = paired_ratio_ci(finals[(4, 2.0)], finals[(1, 1.0)], 0.975)
    assert (low_row["measured_change"], low_row["change_ci_low"], low_row["change_ci_high"]) == pytest.approx(expected)
    assert low_row["reference"] == "sapo-tdadpt" and low_row["pairs"] == 3 and low_row["confidence"] == 0.975
    assert expected[2] < 0.0 and low_row["verdict"] == "confirmed (lowers the return)"
    assert low_row["collapsed_pairs"] == 2  # 20 < 50 and 26 < 60; 56 is not under half of 110
    # above 0, but these runs are not the paper's protocol (N 4, h 16): a budget below it never contradicts
    assert rows[plummet]["change_ci_low"] > 0.0
    assert rows[plummet]["verdict"] == "not confirmed at this budget (raises the return)"
    slower = rows["sapo-tdadpt (m_lambda 0.5)"]
    assert (slower["pairs"], slower["confidence"], slower["verdict"]) == (2, 0.95, "descriptive")
    assert slower["measured_change"] == pytest.approx(245.0 / 220.0 - 1.0)


def test_the_go2_forward_velocity_claim_reads_each_runs_velocity_and_needs_a_moving_base(tmp_path):
    from harness.report.claims import PAPER_CLAIMS, claims_table

    velocity_claims = [c for c in PAPER_CLAIMS if c.metric == "forward velocity"]
    assert [(c.task, c.algo, c.base, c.change) for c in velocity_claims] == [("go2", "shac-tdadpt", "shac", 1.0)]
    settings = {  # num_envs -> (shac's velocities, shac-tdadpt's): one moving base, one that is not, one unrecorded
        4: ([0.1, 0.2], [0.3, 0.5]),
        8: ([-0.1, 0.05], [0.3, 0.5]),
        16: ([None, None], [0.3, 0.5]),
    }
    for num_envs, by_algo in settings.items():
        for algo, velocities in zip(("shac", "shac-tdadpt"), by_algo, strict=True):
            for seed, velocity in enumerate(velocities):
                run = make_run(tmp_path, "go2", "newton", algo, seed, 16, 100.0 + seed, [1.0] * 6, num_envs=num_envs)
                payload = _eval_payload(100.0 + seed)
                if velocity is not None:
                    payload["final"]["mean_forward_velocity"] = velocity
                (run / "eval.json").write_text(json.dumps(payload))
    table = claims_table([load_run(path) for path in collect_runs(tmp_path)], velocity_claims)
    assert sorted(table["num_envs"]) == [4, 8]  # evaluations without a velocity test nothing
    moving = _row(table, num_envs=4)
    assert moving["measured_change"] == pytest.approx(0.4 / 0.15 - 1.0)
    assert moving["metric"] == "forward velocity" and moving["pairs"] == 2
    assert _row(table, num_envs=8)["verdict"].startswith("no ratio: the base's mean is")


def test_forward_locomotion_reads_each_seeds_final_velocity_against_the_speed_and_the_papers_word(tmp_path):
    from harness.report.claims import LOCOMOTION_SPEED, locomotion_table

    velocities = {  # (algo, num_envs) -> final velocity per seed (None: the evaluation recorded none)
        ("shac", 4): [0.02, -0.05, 0.01, 0.03, 0.0, 2.0],  # stands at the 5-seed look; seed 5 waits for the next
        ("shac-tdadpt", 4): [0.9, 1.1, 1.0, 0.95, 1.05],  # walks
        ("shac", 8): [0.0, 2.0],  # before the first look: no verdict, however the seeds read
        ("shac", 16): [1.0, 1.1, 1.2, 1.05, 1.15],  # walks, where the paper says the Go2's SHAC does not
        ("shac-tdfixed", 8): [None, None],  # nothing recorded: no row
    }
    for (algo, num_envs), finals in velocities.items():
        for seed, velocity in enumerate(finals):
            run = make_run(tmp_path, "go2", "newton", algo, seed, 16, 100.0, [1.0] * 6, num_envs=num_envs)
            payload = _eval_payload(100.0)
            if velocity is not None:
                payload["initial"]["mean_forward_velocity"] = 0.05 * seed
                payload["final"]["mean_forward_velocity"] = velocity
            (run / "eval.json").write_text(json.dumps(payload))
    table = locomotion_table([load_run(path) for path in collect_runs(tmp_path)])
    assert sorted(zip(table["algo"], table["num_envs"], strict=True)) == [
        ("shac", 4),
        ("shac", 8),
        ("shac", 16),
        ("shac-tdadpt", 4),
    ]
    still = _row(table, algo="shac", num_envs=4)
    finals = np.array(velocities[("shac", 4)])
    look = finals[:5]  # the first look reads its own first 5 seeds, at 97.5%
    low, high = stats.t.interval(0.975, 4, loc=look.mean(), scale=stats.sem(look))
    assert (still["look"], still["confidence"]) == ("5 seeds", pytest.approx(0.975))
    assert still["look_velocity"] == pytest.approx(look.mean())
    assert (still["look_ci_low"], still["look_ci_high"]) == pytest.approx((low, high))
    assert high < LOCOMOTION_SPEED and still["verdict"] == "does not move forward" and still["design"] == "decided"
    # the descriptive columns read every seed at 95%, the sixth (walking) seed included
    all_low, all_high = stats.t.interval(0.95, 5, loc=finals.mean(), scale=stats.sem(finals))
    assert still["final_velocity"] == pytest.approx(finals.mean())
    assert (still["final_velocity_ci_low"], still["final_velocity_ci_high"]) == pytest.approx((all_low, all_high))
    assert still["untrained_velocity"] == pytest.approx(0.125) and still["seeds_moving"] == 1
    # the paper says the Go2's SHAC does not acquire forward locomotion and its SHAC-TDAdpt improves on it
    assert (still["paper_says"], still["paper_verdict"]) == ("does not move", "confirmed")
    walking = _row(table, algo="shac-tdadpt", num_envs=4)
    assert walking["verdict"] == "moves forward" and walking["seeds_moving"] == 5
    assert (walking["paper_says"], walking["paper_verdict"]) == ("moves", "confirmed")
    early = _row(table, algo="shac", num_envs=8)
    assert (early["look"], early["design"], early["seeds_wanted"]) == ("", "before first look", 5)
    assert early["verdict"] == "undecided (before the first look)" and early["paper_verdict"] == "undecided"
    against = _row(table, algo="shac", num_envs=16)
    # a budget below the paper's protocol (N 64, h 32, 2000 epochs) cannot contradict the paper
    assert against["verdict"] == "moves forward" and against["paper_verdict"] == "not confirmed at this budget"


@pytest.mark.parametrize(
    ("low", "high", "verdict"),
    [(0.3, 0.9, "moves forward"), (-0.1, 0.2, "does not move forward"), (0.1, 0.4, "undecided")]
    + [(math.nan, math.nan, "undecided (under 2 seeds)")],
)
def test_the_locomotion_verdict_reads_its_ci_against_the_speed(low, high, verdict):
    from harness.report.claims import locomotion_verdict

    assert locomotion_verdict(low, high, speed=0.25) == verdict


def test_the_learned_lambdas_course_is_judged_over_finished_adaptive_runs(suite, tmp_path):
    from harness.report.claims import lambda_course_table

    course = pd.read_csv(suite["out"] / "returns_lambda.csv")
    # the synthetic suite's one adaptive algorithm: 5 seeds, each lambda 0.95 - 0.01 epoch over 4 epochs
    row = _row(course, task="ant", backend="newton", algo="shac-tdadpt")
    assert row["seeds"] == 5 and row["lambda_first"] == pytest.approx(0.95)
    assert row["lambda_final_mean"] == pytest.approx(0.92) and row["change"] == pytest.approx(-0.03)
    assert row["falling_share"] == 1.0 and row["verdict"] == "confirmed (falls)"
    assert len(course) == 1  # shac's lambda is fixed: no row
    assert "## The paper's claim that the learned lambda falls" in (suite["out"] / "returns.md").read_text()
    # seeds that disagree leave it open; an unfinished run (no eval.json) does not count
    courses = {0: [0.95, 0.94, 0.93, 0.92], 1: [0.95, 0.96, 0.95, 0.97], 2: [0.95, 0.5, 0.4, 0.3]}
    for seed, lam in courses.items():
        make_run(
            tmp_path,
            "ant",
            "newton",
            "shac-tdadpt",
            seed,
            16,
            None if seed == 2 else 1.0,
            [1.0] * 4,
            extra={"lam": lam},
        )
    row = _row(lambda_course_table([load_run(path) for path in collect_runs(tmp_path)]), algo="shac-tdadpt")
    changes = np.array([-0.03, 0.02])
    assert row["seeds"] == 2 and row["change"] == pytest.approx(changes.mean())
    low, high = stats.t.interval(0.95, 1, loc=changes.mean(), scale=stats.sem(changes))
    assert (row["change_ci_low"], row["change_ci_high"]) == pytest.approx((low, high))
    assert row["falling_share"] == pytest.approx(np.mean([1.0, 1.0 / 3.0]))
    assert row["verdict"] == "undecided"


@pytest.mark.parametrize(
    ("low", "high", "verdict"),
    [(-0.05, -0.01, "confirmed (falls)"), (0.01, 0.05, "contradicted (rises)"), (-0.05, 0.002, "undecided")]
    + [(math.nan, math.nan, "undecided (under 2 seeds)")],
)
def test_the_lambda_verdict_reads_its_ci_against_zero(low, high, verdict):
    from harness.report.claims import lambda_course_verdict

    assert lambda_course_verdict(low, high) == verdict


def test_a_rising_lambda_below_the_papers_protocol_is_not_confirmed_rather_than_contradicted():
    from harness.report.claims import lambda_course_verdict

    assert lambda_course_verdict(0.01, 0.05, paper_protocol=False) == "not confirmed at this budget (rises)"
    assert lambda_course_verdict(-0.05, -0.01, paper_protocol=False) == "confirmed (falls)"


@pytest.mark.parametrize(
    ("low", "high", "at_paper", "said"),
    [
        (0.1, 0.9, True, "confirmed"),
        (0.6, 0.9, True, "confirmed (larger than claimed)"),
        (0.1, 0.3, True, "contradicted (an improvement, smaller than claimed)"),
        (0.1, 0.3, False, "not confirmed at this budget (an improvement, smaller than claimed)"),
        (-0.2, 0.3, True, "contradicted (claimed size excluded)"),
        (-0.2, 0.3, False, "not confirmed at this budget (claimed size excluded)"),
        (-0.5, -0.1, True, "contradicted (below the base)"),
        (-0.2, 0.7, True, "undecided"),
        (math.nan, math.nan, True, "undecided (no interval)"),
        (-0.4, math.inf, True, "undecided"),
        (0.1, math.inf, True, "confirmed"),
        (-math.inf, 0.3, False, "not confirmed at this budget (claimed size excluded)"),
    ],
)
def test_a_claims_verdict_reads_its_interval_against_zero_the_claimed_size_and_the_budget(low, high, at_paper, said):
    from harness.report.sequential import verdict

    assert verdict(low, high, 0.5, at_paper) == said


def test_the_paired_interval_is_the_set_of_ratios_the_paired_t_test_keeps():
    from harness.report.stats import paired_ratio_ci

    variant, base = np.array([12.0, 15.0, 11.0, 14.0]), np.array([10.0, 12.0, 9.0, 9.5])
    point, low, high = paired_ratio_ci(variant, base)
    assert point == pytest.approx(variant.mean() / base.mean() - 1.0) and low < point < high
    for bound in (low, high):  # each bound is where the paired t-test of variant - r base sits at p = 0.05
        assert stats.ttest_1samp(variant - (1.0 + bound) * base, 0.0).pvalue == pytest.approx(0.05, abs=1e-6)
    assert paired_ratio_ci(7.0 * variant, 7.0 * base) == pytest.approx((point, low, high))  # scale-free
    wider = paired_ratio_ci(variant, base, 0.975)
    assert wider[1] < low and wider[2] > high
    assert math.isnan(paired_ratio_ci(variant[:1], base[:1])[1])  # one pair: a value, no interval
    assert all(math.isnan(v) for v in paired_ratio_ci(variant[:2], [-1.0, -2.0]))  # no ratio to a loss
    with pytest.raises(ValueError, match="paired samples differ in size"):
        paired_ratio_ci(variant, base[:3])


def test_pairing_carries_the_seeds_covariance_in_either_direction():
    """Positively correlated seeds (a seed lucky for both): pairing narrows the interval against an unpaired
    reading; negatively correlated ones widen it, where an unpaired interval would claim too much."""
    from harness.report.stats import paired_ratio_ci

    base = np.array([4000.0, 5000.0, 6000.0, 7000.0, 8000.0])
    together = 1.5 * base + np.array([100.0, -100.0, 50.0, -50.0, 0.0])
    against = 1.5 * base[::-1] + np.array([100.0, -100.0, 50.0, -50.0, 0.0])
    _, low_together, high_together = paired_ratio_ci(together, base)
    _, low_against, high_against = paired_ratio_ci(against, base)
    assert together.mean() == pytest.approx(against.mean())  # the same two samples, paired differently
    assert high_together - low_together < 0.1 < high_against - low_against


def test_aggregate_normalises_each_task_by_untrained_and_best(suite):
    aggregate = pd.read_csv(suite["out"] / "aggregate.csv")
    newton = aggregate[aggregate["backend"] == "newton"].set_index("algo")
    # the Ant on Newton at h 16 (5 seeds each): untrained -50, best IQM 12 (shac-tdadpt)
    scale = lambda x: (np.array(x) - -50.0) / (12.0 - -50.0)  # noqa: E731
    assert newton.loc["shac-tdadpt", "iqm_normalised"] == pytest.approx(1.0)
    assert newton.loc["shac", "iqm_normalised"] == pytest.approx(stats.trim_mean(scale(SHAC_FINALS), 0.25))
    assert newton.loc["shac-tdadpt", "p_improvement"] == pytest.approx(0.8)  # order is kept by normalising
    assert "N 4, 4 epochs, h 16" in newton.loc["shac", "settings"]


def test_field_statistics_match_rliable_library(monkeypatch):
    """Our stratified bootstrap against rliable.library's own on the same scores (5 runs x 3 tasks):
    rliable.library does not import with pandas 3 (arch < 8 calls pandas' deprecate_kwarg the old way),
    so the test adapts that one call before importing it.

    Each side's endpoints carry Monte Carlo error of variance ~ 1 / resamples, and the tolerances below
    are sized for one side at 2,000 resamples and the other at 20,000. rliable's bootstrap calls its
    statistic once per resample in Python while ours is vectorised, so rliable takes the 2,000 (the
    report's own count) and ours the 20,000: the same error budget at a tenth of rliable's time."""
    import pandas.util._decorators as decorators

    original = decorators.deprecate_kwarg

    def old_style(*args, **kwargs):
        return (
            original(FutureWarning, *args, **kwargs) if args and isinstance(args[0], str) else original(*args, **kwargs)
        )

    decorators.deprecate_kwarg = old_style
    try:
        from rliable import library, metrics
    finally:
        decorators.deprecate_kwarg = original
    from harness.report import stats as ours

    rng = np.random.default_rng(3)
    x, y = rng.normal(size=(5, 3)), rng.normal(size=(5, 3)) + 0.5
    np.random.seed(0)  # rliable draws its resamples from numpy's global generator
    reps = ours.BOOTSTRAP_RESAMPLES
    monkeypatch.setattr(ours, "BOOTSTRAP_RESAMPLES", 10 * reps)
    point, interval = library.get_interval_estimates(
        {"x": x}, lambda s: np.array([metrics.aggregate_iqm(s)]), reps=reps
    )
    mine = ours.aggregate_iqm_with_ci(list(x.T))
    assert mine[0] == pytest.approx(point["x"][0])
    assert mine[1:] == pytest.approx(interval["x"].ravel(), abs=0.05)  # Monte Carlo error, see above
    point, interval = library.get_interval_estimates({"p": [x, y]}, metrics.probability_of_improvement, reps=reps)
    mine = ours.probability_of_improvement_with_ci(list(x.T), list(y.T))
    assert mine[0] == pytest.approx(point["p"])
    assert mine[1:] == pytest.approx(interval["p"].ravel(), abs=0.03)
    taus = np.linspace(-2, 2, 9)
    point, interval = library.create_performance_profile({"x": x}, taus, reps=reps)
    mine = ours.performance_profile_with_ci(list(x.T), taus)
    assert mine[0] == pytest.approx(point["x"])
    assert np.abs(np.stack(mine[1:]) - interval["x"]).max() <= 0.07


def test_unfinished_run_is_left_out_of_returns_but_not_of_curves(suite):
    returns = pd.read_csv(suite["out"] / "returns.csv")
    h32 = _row(returns, algo="shac", backend="newton", horizon=32, num_envs=4)
    assert h32["seeds"] == 2  # seed 2 has no eval.json
    assert h32["iqm_final"] == pytest.approx(25.0)  # trim_mean of 2 values cuts none
    grad = pd.read_csv(suite["out"] / "grad_variance_vs_h.csv")
    assert _row(grad, algo="shac", backend="newton", horizon=32, num_envs=4)["seeds"] == 3
    wall = pd.read_csv(suite["out"] / "wall_time.csv")
    assert len(wall) == 5 + 5 + 3 + 1 + 2


def test_runs_of_another_setting_are_another_row(suite):
    """Same task, backend, algorithm and h but other envs and epochs (another block of the spec): its own row
    in the returns table, never extra seeds of the first."""
    returns = pd.read_csv(suite["out"] / "returns.csv")
    other = _row(returns, algo="shac", backend="newton", horizon=32, num_envs=8)
    assert (other["seeds"], other["epochs"], other["env_steps"]) == (2, 6, 6 * 8 * 32)
    assert other["iqm_final"] == pytest.approx(np.mean(OTHER_FINALS))
    assert len(returns[(returns["algo"] == "shac") & (returns["horizon"] == 32)]) == 2
    text = (suite["out"] / "returns.md").read_text()
    assert "| ant | newton | shac | 32 | 8 | 2 | 6 |" in text


def test_curves_show_one_setting_per_task_and_backend(suite):
    records = [load_run(path, io.StringIO()) for path in collect_runs(suite["root"])]
    # newton/ant: h=16 at 4 envs has 10 runs, h=32 at 4 envs 3, h=32 at 8 envs 2
    assert curve_settings(records)[("ant", "newton")] == (16, 4, EPOCHS)
    frame = learning_curve_frame(records, "env_steps")
    newton = frame[frame["backend"] == "newton"]
    assert {panel.split(" (")[0] for panel in newton["panel"]} == {"ant / newton, h=16, N=4"}
    assert newton["env_steps"].max() <= EPOCHS * 4 * 16


def test_single_seed_has_a_value_and_no_ci(suite):
    returns = pd.read_csv(suite["out"] / "returns.csv")
    warp = _row(returns, backend="mujoco_warp", algo="shac")
    assert warp["iqm_final"] == pytest.approx(7.0)
    assert pd.isna(warp["iqm_ci_low"]) and pd.isna(warp["iqm_ci_high"])
    assert "| ant | mujoco_warp | shac | 16 | 4 | 1 |" in (suite["out"] / "returns.md").read_text()


def test_tables_are_reproducible(suite):
    runs = [load_run(p) for p in collect_runs(suite["root"])]
    pd.testing.assert_frame_equal(returns_table(runs), returns_table(runs))


def test_grad_variance_quartiles_and_growth(suite):
    grad = pd.read_csv(suite["out"] / "grad_variance_vs_h.csv")
    h16 = _row(grad, task="ant", backend="newton", algo="shac", horizon=16)
    # 5 seeds x [1, 2, 3] pooled (NaN dropped): 15 values, sorted 1 x5, 2 x5, 3 x5
    assert h16["values"] == 15
    assert (h16["q1"], h16["median"], h16["q3"]) == (1.0, 2.0, 3.0)
    h32 = _row(grad, task="ant", backend="newton", algo="shac", horizon=32, num_envs=4)
    assert (h32["q1"], h32["median"], h32["q3"]) == (4.0, 8.0, 12.0)
    assert (h32["seeds"], h32["values"], h32["epochs"]) == (3, 9, EPOCHS)
    other = _row(grad, task="ant", backend="newton", algo="shac", horizon=32, num_envs=8)
    assert (other["seeds"], other["values"], other["median"], other["epochs"]) == (2, 12, 1000.0, 6)
    growth = pd.read_csv(suite["out"] / "grad_variance_vs_h_growth.csv")
    shac = _row(growth, task="ant", backend="newton", algo="shac")
    assert (shac["h_min"], shac["h_max"], shac["growth_factor"]) == (16, 32, pytest.approx(8.0 / 2.0))
    assert shac["num_envs"] == 4
    assert len(growth) == 1  # shac-tdadpt and the 8-env setting have one horizon each


def test_both_gradient_statistics_have_seed_cis_and_growth(tmp_path):
    """Seeds' geometric means with bootstrap CIs for the raw variance and the noise-to-signal ratio, and
    their growth from the shortest h (and from h 32) to the longest; a seed whose median NSR is
    unresolved (inf) makes its cell inf with no CI, and runs from before the statistic count as absent."""
    raw = {16: [1.0, 2.0, 4.0], 32: [2.0, 4.0, 8.0], 80: [8.0, 16.0, 32.0]}
    nsr = {16: [1.0, 1.0, 4.0], 32: [1.0, 2.0, 2.0], 80: [2.0, 2.0, 8.0]}
    for h in raw:
        for seed in range(3):
            extra = {"actor_grad_nsr": [nsr[h][seed]] * EPOCHS}
            make_run(tmp_path, "ant", "newton", "shac", seed, h, None, [raw[h][seed]] * EPOCHS, extra=extra)
    make_run(tmp_path, "ant", "newton", "sapo", 0, 16, None, [1.0] * EPOCHS)  # no NSR logged: an old run
    for seed, value in enumerate([1.0, math.inf]):
        make_run(
            tmp_path,
            "ant",
            "newton",
            "sapo",
            seed,
            80,
            None,
            [1.0] * EPOCHS,
            extra={"actor_grad_nsr": [value] * EPOCHS},
        )
    runs = [load_run(p) for p in collect_runs(tmp_path)]
    table = grad_variance_table(runs)
    h16 = _row(table, algo="shac", horizon=16)
    assert h16["var_gmean"] == pytest.approx(2.0) and h16["nsr_gmean"] == pytest.approx(4.0 ** (1 / 3))
    assert 1.0 <= h16["var_ci_low"] <= h16["var_gmean"] <= h16["var_ci_high"] <= 4.0
    assert _row(table, algo="sapo", horizon=16)["nsr_seeds"] == 0
    unresolved = _row(table, algo="sapo", horizon=80)
    assert unresolved["nsr_gmean"] == math.inf and math.isnan(unresolved["nsr_ci_low"])
    growth = grad_variance_growth_table(runs)
    from16, from32 = _row(growth, algo="shac", h_min=16), _row(growth, algo="shac", h_min=32)
    assert from16["var_growth"] == pytest.approx(8.0) and from32["var_growth"] == pytest.approx(4.0)
    assert from16["nsr_growth"] == pytest.approx((32.0 / 4.0) ** (1 / 3))
    assert from16["var_growth_ci_low"] <= from16["var_growth"] <= from16["var_growth_ci_high"]
    independent = stats.bootstrap(
        (np.log(raw[80]), np.log(raw[16])),
        lambda x, y, axis=-1: x.mean(axis=axis) - y.mean(axis=axis),
        vectorized=True,
        paired=False,
        n_resamples=2000,
        confidence_level=0.95,
        method="percentile",
        rng=np.random.default_rng(0),
    ).confidence_interval
    assert from16["var_growth_ci_low"] == pytest.approx(math.exp(independent.low))
    assert from16["var_growth_ci_high"] == pytest.approx(math.exp(independent.high))


def test_runs_of_another_physics_preset_are_another_task_row(tmp_path):
    for seed, preset in enumerate(["bench", "bench_kf3000"]):
        run = make_run(tmp_path, "ant", "newton", "shac", seed, 16, 1.0, [1.0] * EPOCHS)
        config = json.loads((run / "config.json").read_text())
        config["physics_record"] = {"preset": preset}
        (run / "config.json").write_text(json.dumps(config))
    table = returns_table([load_run(p) for p in collect_runs(tmp_path)])
    assert sorted(table["task"]) == ["ant", "ant.bench_kf3000"] and list(table["seeds"]) == [1, 1]


def test_minimum_detectable_difference_has_the_power_it_claims():
    # s = 1, 5 seeds a side: (t_0.975 + t_0.8 at 8 dof) sqrt(2/5)
    mde = minimum_detectable_difference(1.0, 5, 5)
    assert mde == pytest.approx((stats.t.ppf(0.975, 8) + stats.t.ppf(0.8, 8)) * math.sqrt(0.4))
    for n1, n2 in ((3, 3), (5, 5), (10, 4)):
        d = minimum_detectable_difference(2.0, n1, n2)
        dof, shift = n1 + n2 - 2, d / (2.0 * math.sqrt(1 / n1 + 1 / n2))
        crit = stats.t.ppf(0.975, dof)
        exact = stats.nct.sf(crit, dof, shift) + stats.nct.cdf(-crit, dof, shift)  # the t-test's true power
        assert exact == pytest.approx(0.8, abs=0.03)
    n = seeds_needed(1.0, 1.0)
    assert minimum_detectable_difference(1.0, n, n) <= 1.0 < minimum_detectable_difference(1.0, n - 1, n - 1)
    assert seeds_needed(float("nan"), 1.0) is None


def test_power_table_pools_the_spread_of_a_setting(suite):
    runs = [load_run(p) for p in collect_runs(suite["root"])]
    power = power_table(runs)
    h16 = _row(power, task="ant", backend="newton", horizon=16, num_envs=4, family="shac")
    spread = math.sqrt((np.var(SHAC_FINALS, ddof=1) * 4 + np.var(TDADPT_FINALS, ddof=1) * 4) / 8)
    assert h16["pooled_std"] == pytest.approx(spread)
    assert h16["base_mean"] == pytest.approx(np.mean(SHAC_FINALS))
    assert h16["seeds_for_100pct"] == seeds_needed(spread, np.mean(SHAC_FINALS))
    returns = returns_table(runs)
    tdadpt = _row(returns, algo="shac-tdadpt", backend="newton", horizon=16)
    # paired: the std of the seed-paired differences over the 5 seeds both have
    paired_spread = np.std(np.subtract(TDADPT_FINALS, SHAC_FINALS), ddof=1)
    assert tdadpt["mde_80"] == pytest.approx(paired_minimum_detectable_difference(paired_spread, 5))
    assert paired_minimum_detectable_difference(1.0, 5) == pytest.approx(
        (stats.t.ppf(0.975, 4) + stats.t.ppf(0.8, 4)) / math.sqrt(5)
    )
    assert (suite["out"] / "returns_power.csv").is_file()


def test_wall_time_split(suite):
    wall = pd.read_csv(suite["out"] / "wall_time.csv")
    run = _row(wall, backend="newton", algo="shac", horizon=16, seed=0)
    assert run["wall_min"] == pytest.approx(EPOCHS * EPOCH_S / 60)
    assert run["s_per_epoch"] == pytest.approx(EPOCH_S)
    for stem, per_epoch in (
        ("sim_forward", SIM_FORWARD),
        ("backward", BACKWARD),
        ("actor_update", ACTOR),
        ("critic_update", CRITIC),
        ("lambda_update", LAMBDA),
        ("update_unsplit", 0.0),
        ("other", EPOCH_S - SIM_FORWARD - BACKWARD - UPDATE),
    ):
        assert run[f"{stem}_min"] == pytest.approx(EPOCHS * per_epoch / 60), stem
        assert run[f"{stem}_frac"] == pytest.approx(per_epoch / EPOCH_S), stem
    old = _row(wall, backend="mujoco_warp")  # logged before the update split: all of it is "update"
    assert old["update_unsplit_min"] == pytest.approx(EPOCHS * UPDATE / 60)
    assert old["actor_update_min"] == 0.0


def test_throughput_backends_sim_to_sim_landscape_checks(suite):
    out = suite["out"]
    throughput = pd.read_csv(out / "throughput.csv")
    assert _row(throughput, backend="newton", task="ant")["forward_backward_steps_per_s"] == 2500.0

    backends = pd.read_csv(out / "backends.csv")
    both = _row(backends, task="ant", algo="shac", horizon=16)
    assert (both["newton_seeds"], both["mujoco_warp_seeds"]) == (5, 1)
    assert (both["newton_iqm_final"], both["mujoco_warp_iqm_final"]) == (3.0, 7.0)
    assert len(backends) == 1  # shac-tdadpt and h=32 ran on one backend only

    s2s = pd.read_csv(out / "sim_to_sim.csv")
    row = _row(s2s, seed=0)
    assert (row["trained_on"], row["evaluated_on"]) == ("newton", "mujoco_warp")
    assert (row["own_return"], row["other_return"], row["gap"]) == (1.0, -5.0, -6.0)
    assert row["own_source"] == "eval.json" and bool(row["same_protocol"])
    assert _row(pd.read_csv(out / "sim_to_sim_mean.csv"), algo="shac")["gap_mean"] == -6.0

    land = _row(pd.read_csv(out / "landscape.csv"), algo="shac-tdadpt")
    assert (land["roughness_h_step"], land["roughness_td_lambda"]) == (2.0, 0.5)
    assert land["ratio_h_step_over_td_lambda"] == 4.0

    checks = pd.read_csv(out / "checks.csv")
    assert set(checks["kind"]) == {"throughput", "gradcheck", "crosscheck"}
    assert bool(_row(checks, kind="gradcheck")["passed"])
    # the settings a check ran at come from its command; none recorded reads as the defaults
    assert _row(checks, kind="gradcheck")["settings"] == "preset=rewarped, fd_scheme=forward"
    assert pd.isna(_row(checks, kind="throughput")["settings"])
    assert "| preset=rewarped, fd_scheme=forward |" in (out / "checks.md").read_text()
    assert "min cosine 0.999" in _row(checks, kind="crosscheck")["summary"]
    assert "never_written.json" in suite["log"]
    assert "skipped check" in suite["log"] and "parity_ant_newton-mujoco_warp_4.json" in suite["log"]


def test_every_file_states_its_provenance(suite):
    written = suite["written"]
    markdown = [p for p in written if p.suffix == ".md"]
    assert {p.name for p in markdown} >= {
        f"{name}.md"
        for name in ("returns", "grad_variance_vs_h", "wall_time", "throughput", "backends", "sim_to_sim")
        + ("landscape", "checks", "index")
    }
    for path in markdown:
        text = path.read_text()
        assert COMMIT in text and HEADER["command"] in text and "Test CPU" in text and "torch 2.13.0+cpu" in text
        if path.name != "index.md":
            assert text.startswith("# ") and "Rests on" in text
    for csv in (p for p in written if p.suffix == ".csv"):
        sidecar = json.loads(csv.with_suffix(".provenance.json").read_text())
        assert sidecar["provenance"]["commit"] == COMMIT and sidecar["csv"] == csv.name
        assert sidecar["columns"] == list(pd.read_csv(csv).columns)
    assert "git_commit" not in HEADER
    assert "`deadbee`" in header_lines({"git_commit": "deadbee"})[0]  # provenance()'s own key works too


def test_every_plot_exists(suite):
    pngs = [p for p in suite["written"] if p.suffix == ".png"]
    names = {p.name for p in pngs}
    expected = {"learning_curves_steps", "learning_curves_wall", "grad_variance_vs_h", "lambda_alpha", "wall_time"}
    expected |= {"performance_profile"}
    assert {f"{n}.png" for n in expected | {"throughput"}} <= names
    for path in pngs:
        assert path.is_file() and path.stat().st_size > 1000, path
    # the landscape figure comes from harness.checks.landscape when it imports; else the skip is said
    assert "landscape_ant_newton_shac-tdadpt_h16_s0.png" in names or "skipped plot landscape_" in suite["log"]
    # the suite's horizons have different budgets: no return-vs-h panel (drawn in its own test below)
    assert "skipped plot returns_vs_h.png: no algorithm has evaluated runs at two horizons" in suite["log"]
    # nor a scaling check (the scaling figure is drawn in tests/test_performance_tools.py)
    assert "skipped plot scaling.png: no scaling check" in suite["log"]
    others = suite["log"].replace("skipped plot landscape_", "").replace("skipped plot returns_vs_h.png", "")
    others = others.replace("skipped plot scaling.png", "")
    assert "skipped plot" not in others


def test_empty_inputs_write_tables_and_skip_plots(tmp_path):
    log = io.StringIO()
    written = write_bench_report([], [], tmp_path / "empty", HEADER, stream=log)
    assert not [p for p in written if p.suffix == ".png"]
    assert "No rows" in (tmp_path / "empty" / "backends.md").read_text()
    assert "skipped plot learning_curves_steps.png" in log.getvalue()
    assert "Skipped" in (tmp_path / "empty" / "index.md").read_text()


def test_the_log_goes_to_standard_output_as_it_is_at_the_call(tmp_path, capsys):
    """Without a stream the log reaches today's stdout (here capsys's), not the one the package was imported
    under: a test's captured output, closed since, would make a later report fail."""
    write_bench_report([], [], tmp_path / "empty", HEADER)
    assert "[bench report] skipped plot learning_curves_steps.png" in capsys.readouterr().out


def test_base_algo():
    assert [base_algo(a) for a in ("shac", "shac-tdfixed", "shac-tdadpt", "sapo-tdfixed", "sapo-tdadpt")] == [
        "shac",
        "shac",
        "shac",
        "sapo",
        "sapo",
    ]


def test_the_index_leads_with_the_headline(suite):
    index = (suite["out"] / "index.md").read_text()
    assert index.index("## Headline") < index.index("## Tables") < index.index("## Plots")
    headline = index[index.index("## Headline") : index.index("## Tables")]
    assert "| ant | newton | shac-tdadpt |" in headline and "IQM normalised" in headline
    assert "](learning_curves_steps.png)" in headline and "](performance_profile.png)" in headline


def test_an_evaluation_of_an_earlier_epoch_is_stale(tmp_path):
    """``train --resume --epochs`` extends a run after its eval.json was written: that evaluation is of
    an earlier policy and is not counted as the run's final return."""
    log = io.StringIO()
    fresh = make_run(tmp_path, "ant", "newton", "shac", 0, 16, final=5.0, grad_var=[1.0] * EPOCHS)
    assert load_run(fresh, log).evaluation is not None
    (fresh / "eval.json").write_text(json.dumps(_eval_payload(5.0, policy_epoch=EPOCHS)))
    assert load_run(fresh, log).evaluation is not None
    extended = make_run(tmp_path, "ant", "newton", "shac", 1, 16, final=5.0, grad_var=[1.0] * EPOCHS)
    (extended / "eval.json").write_text(json.dumps(_eval_payload(5.0, policy_epoch=EPOCHS - 2)))
    assert load_run(extended, log).evaluation is None
    assert f"evaluates epoch {EPOCHS - 2} of {EPOCHS}: stale" in log.getvalue()


def test_the_returns_table_gives_the_forward_velocity_over_seeds_where_evaluations_recorded_it(tmp_path):
    velocities = [0.1, 0.4, 0.2, 3.0]
    for seed, velocity in enumerate(velocities):
        run = make_run(tmp_path / "go2", "go2", "newton", "shac", seed, 16, 1.0, [1.0] * EPOCHS)
        payload = json.loads((run / "eval.json").read_text())
        payload["final"]["mean_forward_velocity"] = velocity
        (run / "eval.json").write_text(json.dumps(payload))
    make_run(tmp_path / "go2", "go2", "newton", "shac", 4, 16, 1.0, [1.0] * EPOCHS)  # an older eval.json
    make_run(tmp_path / "ant", "ant", "newton", "shac", 0, 16, 1.0, [1.0] * EPOCHS)
    table = returns_table([load_run(p) for p in collect_runs(tmp_path)]).set_index("task")
    assert table.loc["go2", "forward_velocity_iqm"] == pytest.approx(stats.trim_mean(velocities, 0.25))
    assert table.loc["go2", "forward_velocity_ci_low"] <= 0.3 <= table.loc["go2", "forward_velocity_ci_high"]
    assert (table.loc["go2", "seeds"], table.loc["go2", "forward_velocity_seeds"]) == (5, 4)
    assert math.isnan(table.loc["ant", "forward_velocity_iqm"]) and table.loc["ant", "forward_velocity_seeds"] == 0
    written = write_bench_report(collect_runs(tmp_path), [], tmp_path / "report", HEADER)
    returns_md = next(p for p in written if p.name == "returns.md").read_text()
    assert "| 0.3 (4 of 5 seeds) |" in returns_md  # IQM of the four that recorded it


def test_tables_say_where_their_runs_trained_when_not_all_on_the_cpu(tmp_path):
    for seed in range(2):
        make_run(tmp_path / "runs", "ant", "newton", "shac", seed, 16, 1.0, [1.0] * EPOCHS)
    cpu_only = write_bench_report(collect_runs(tmp_path / "runs"), [], tmp_path / "cpu", HEADER)
    assert "Trained on" not in next(p for p in cpu_only if p.name == "returns.md").read_text()
    gpu = make_run(tmp_path / "runs", "ant", "newton", "shac", 2, 16, 1.0, [1.0] * EPOCHS)
    config = json.loads((gpu / "config.json").read_text())
    (gpu / "config.json").write_text(json.dumps(config | {"device": "cuda"}))
    mixed = write_bench_report(collect_runs(tmp_path / "runs"), [], tmp_path / "mixed", HEADER)
    returns_md = next(p for p in mixed if p.name == "returns.md").read_text()
    assert "Rests on 3 evaluated training runs" in returns_md and "Trained on cpu (2), cuda (1)" in returns_md


def test_returns_against_h_compare_horizons_at_one_budget_only(tmp_path):
    """Rows exist only where one (task, backend, algo, N) has evaluated runs at two or more horizons with
    the same env steps per run (within 2%: epochs are whole numbers); a horizon at another budget is left
    out, and each row carries the IQM over seeds, its CI and the mean wall minutes per run."""
    finals = {16: [10.0, 20.0, 30.0], 32: [40.0, 50.0, 60.0]}
    for horizon, epochs in ((16, 8), (32, 4)):  # 4 envs x 16 x 8 = 4 x 32 x 4 = 512 env steps per run
        for seed, final in enumerate(finals[horizon]):
            make_run(tmp_path, "ant", "newton", "sapo", seed, horizon, final, [1.0] * epochs, epochs=epochs)
    make_run(tmp_path, "ant", "newton", "sapo", 0, 64, 99.0, [1.0] * 4, epochs=4)  # 1,024 env steps: another budget
    make_run(tmp_path, "ant", "newton", "shac", 0, 16, 5.0, [1.0] * 8, epochs=8)  # one horizon only: no row
    table = returns_vs_h_table([load_run(p) for p in collect_runs(tmp_path)])
    assert list(table["horizon"]) == [16, 32] and set(table["algo"]) == {"sapo"}
    assert list(table["budget"]) == [512, 512] and list(table["epochs"]) == [8, 4]
    h32 = _row(table, horizon=32)
    assert h32["seeds"] == 3 and h32["iqm_final"] == pytest.approx(50.0)
    assert h32["iqm_ci_low"] <= 50.0 <= h32["iqm_ci_high"]
    assert h32["wall_min_mean"] == pytest.approx(4 * EPOCH_S / 60.0)
    png = plot_returns_vs_h(table, tmp_path / "returns_vs_h.png")
    assert png.is_file() and png.stat().st_size > 1000


def test_readmes_result_tables_are_the_ones_the_results_make(tmp_path):
    """README's headline tables are generated from the result files they cite (``python -m harness
    readme``): the committed README matches the committed results, and a changed result makes the check
    name its block and the update rewrite exactly that block."""
    import shutil

    from harness.report.readme import BLOCKS, update_readme

    root = Path(__file__).resolve().parents[1]
    assert update_readme(root / "README.md", root, check=True) == []
    copy = tmp_path / "repo"
    for folder in ("results/bench/protocol", "results/bench/standard"):
        (copy / folder).mkdir(parents=True)
        for name in ("returns.csv", "returns_claims.csv", "returns_locomotion.csv", "grad_variance_vs_h_growth.csv"):
            if (root / folder / name).is_file():
                shutil.copy(root / folder / name, copy / folder / name)
    shutil.copytree(root / "results/bench/standard/checks", copy / "results/bench/standard/checks")
    for evaluation in (root / "results/bench/protocol/runs").glob("go2_*/eval.json"):
        target = copy / evaluation.relative_to(root)
        target.parent.mkdir(parents=True)
        shutil.copy(evaluation, target)
    shutil.copy(root / "README.md", copy / "README.md")
    # a Fig. 6 ablation's runs have their own row in returns.csv but no place among the paper's six
    returns = copy / "results/bench/protocol/returns.csv"
    lines = returns.read_text().splitlines(keepends=True)
    (tdadpt,) = [line for line in lines if ",sapo-tdadpt,32,64," in line and line.startswith("ant,newton,")]
    returns.write_text("".join(lines) + tdadpt.replace(",sapo-tdadpt,", ",sapo-tdadpt (b_lambda 4),"))
    assert update_readme(copy / "README.md", copy, check=True) == []
    claims = copy / "results/bench/protocol/returns_claims.csv"
    text = claims.read_text()
    first = text.splitlines()[1]
    fields = first.split(",")
    fields[12] = "0.123"  # shac-tdfixed's measured change
    claims.write_text(text.replace(first, ",".join(fields)))
    assert update_readme(copy / "README.md", copy, check=True) == ["protocol-ant"]
    assert update_readme(copy / "README.md", copy) == ["protocol-ant"]
    assert "+12% [" in (copy / "README.md").read_text()
    assert update_readme(copy / "README.md", copy, check=True) == []
    # the interval is the look's: a pair beyond it waits for the next look, and the label says so
    for pairs, label in (("5", "(97.5%, the 5-pair look) |"), ("6", "(97.5%, the 5-pair look; 6 pairs so far) |")):
        fields[9], fields[10], fields[13] = pairs, "5 pairs", "0.975"
        claims.write_text(text.replace(first, ",".join(fields)))
        update_readme(copy / "README.md", copy)
        assert "+12% [" in (copy / "README.md").read_text() and label in (copy / "README.md").read_text()
    growth = copy / "results/bench/standard/grad_variance_vs_h_growth.csv"
    growth.write_text(growth.read_text().replace(",16.03353702926601,", ",17.0,", 1))  # SHAC's raw variance
    assert update_readme(copy / "README.md", copy) == ["grad-variance-growth"]
    assert "| SHAC | 17x [" in (copy / "README.md").read_text()
    assert set(BLOCKS) == {"protocol-ant", "protocol-go2", "standard-returns", "parity", "grad-variance-growth"}
