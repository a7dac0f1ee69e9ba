"""The bench report's tables as documents: a :class:`Table` (title, what its numbers rest on, notes, one
or more :class:`Section`) written as ``NAME.md`` with a provenance paragraph and, per section,
``NAME[SUFFIX].csv`` with ``NAME[SUFFIX].provenance.json`` beside it (:func:`write_table`); and one
``*_document`` function per table, which :func:`build_tables` calls in the order ``index.md`` lists them."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from harness.formatting import fmt, fmt_ci, fmt_count, fmt_pct, fmt_range, fmt_verdict, is_missing, markdown_table
from harness.report.aggregate import aggregate_table
from harness.report.claims import (
    LOCOMOTION_SPEED,
    ablation_table,
    claims_table,
    lambda_course_table,
    locomotion_table,
)
from harness.report.free_claims import (
    gradient_variance_claim_table,
    lambda_rate_table,
    landscape_claim_table,
    step_gain_claim_table,
)
from harness.report.records import CheckRecord, RunRecord
from harness.report.stats import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, EFFECTS
from harness.report.tables import (
    BACKEND_MEASURES,
    TIME_PARTS,
    backends_table,
    checks_table,
    grad_variance_growth_table,
    grad_variance_table,
    landscape_table,
    power_table,
    returns_table,
    returns_vs_h_table,
    sim_to_sim_mean_table,
    sim_to_sim_table,
    step_gain_table,
    throughput_table,
    wall_time_table,
)
from harness.results import atomic_write_text, write_json

# -- Markdown and CSV -----------------------------------------------------------------------------
ColumnSpec = list[tuple[str, str | Callable[[pd.Series], str]]]  # (header, column name or row -> cell)


@dataclass
class Section:
    """One table: its rows, how the Markdown shows them, and the suffix of its CSV (``""``: ``NAME.csv``)."""

    frame: pd.DataFrame
    columns: ColumnSpec
    heading: str | None = None
    csv_suffix: str = ""
    empty: str = "none"


@dataclass
class Table:
    name: str
    title: str
    rests_on: str
    sections: list[Section]
    notes: list[str] = field(default_factory=list)
    input_commits: list[str] = field(default_factory=list)


def markdown_rows(frame: pd.DataFrame, columns: ColumnSpec) -> list[str]:
    """A Markdown table of ``frame`` as ``columns`` say."""
    rows = ([how(row) if callable(how) else fmt(row[how]) for _, how in columns] for _, row in frame.iterrows())
    return markdown_table([h for h, _ in columns], rows)


def header_lines(header: dict) -> list[str]:
    """The provenance paragraph of every Markdown table: command, commit, UTC time, packages, machine."""
    commit = header.get("commit") or header.get("git_commit") or "unknown"
    profile = f" (profile `{header['profile']}`)" if header.get("profile") else ""
    spec = f" from `{header['spec']}`" if header.get("spec") else ""
    lines = [
        f"Made by: `{header.get('command', 'unknown')}`{profile}{spec}, commit `{commit}`, "
        f"{header.get('created_utc', 'time unknown')}."
    ]
    packages = header.get("packages") or {}
    listed = ", ".join(f"{name} {version or '(not installed)'}" for name, version in packages.items())
    python = f"; Python {header['python']}" if header.get("python") else ""
    lines.append(f"Packages: {listed or 'not recorded'}{python}.")
    lines.append(f"Machine: {machine_text(header.get('machine') or {})}.")
    return lines


def machine_text(machine: dict) -> str:
    """The machine a report was made on, in one line."""
    if not machine:
        return "not recorded"
    parts = [str(machine.get("cpu_model", "CPU unknown"))]
    if machine.get("cpu_count") is not None:
        parts.append(f"{machine['cpu_count']} CPUs")
    if machine.get("platform"):
        parts.append(str(machine["platform"]))
    if machine.get("torch_num_threads") is not None:
        parts.append(f"torch threads {machine['torch_num_threads']}")
    parts.append(f"OMP_NUM_THREADS={machine.get('OMP_NUM_THREADS')}")
    parts.append("GPUs: " + (", ".join(machine.get("gpus") or []) or "none"))
    return ", ".join(parts)


def commit_counts(values: Iterable[str | None]) -> list[str]:
    """``commit (n files)`` per distinct commit, the most frequent first; missing ones as ``unknown``."""
    counts = Counter(v or "unknown" for v in values)
    return [f"{commit} ({n})" for commit, n in counts.most_common()]


def markdown_document(table: Table, header: dict) -> str:
    lines = [f"# {table.title}", "", *header_lines(header), "", table.rests_on]
    if table.input_commits:
        lines[-1] += f" Inputs made at commit(s), with how many files: {', '.join(table.input_commits)}."
    for note in table.notes:
        lines += ["", note]
    for section in table.sections:
        lines.append("")
        if section.heading:
            lines += [f"## {section.heading}", ""]
        if section.frame.empty:
            lines.append(f"No rows: {section.empty}.")
        else:
            lines += markdown_rows(section.frame, section.columns)
    return "\n".join(lines) + "\n"


def write_table(table: Table, out_dir: Path, header: dict) -> list[Path]:
    """``NAME.md``, and per section ``NAME[SUFFIX].csv`` with ``NAME[SUFFIX].provenance.json`` beside it."""
    written = [atomic_write_text(out_dir / f"{table.name}.md", markdown_document(table, header))]
    for section in table.sections:
        stem = f"{table.name}{section.csv_suffix}"
        csv_text = section.frame.to_csv(index=False, lineterminator="\n")
        written.append(atomic_write_text(out_dir / f"{stem}.csv", csv_text))
        sidecar = {
            "table": stem,
            "csv": f"{stem}.csv",
            "markdown": f"{table.name}.md",
            "title": table.title + (f": {section.heading}" if section.heading else ""),
            "rests_on": table.rests_on,
            "notes": table.notes,
            "columns": list(section.frame.columns),
            "input_commits": table.input_commits,
            "provenance": header,
        }
        written.append(write_json(out_dir / f"{stem}.provenance.json", sidecar))
    return written


def _signed_pct(value) -> str:
    """A relative change as a signed whole percentage: 0.25 -> +25%; an interval's infinite bound reads
    "unbounded"."""
    if is_missing(value):
        return "n/a"
    return f"{100.0 * value:+.0f}%" if math.isfinite(value) else "unbounded"


def _change_ci(row: pd.Series) -> str:
    low, high = row["change_ci_low"], row["change_ci_high"]
    if is_missing(low) or is_missing(high):
        return "n/a"
    level = f"{100 * row['confidence']:g}% " if "confidence" in row and not is_missing(row["confidence"]) else ""
    return f"{level}[{_signed_pct(low)}, {_signed_pct(high)}]"


def _design_cell(row: pd.Series) -> str:
    """What the sequential design does next with a claim, and the seeds per algorithm it asks for."""
    return f"{row['design']}: {int(row['seeds_wanted'])} seeds"


def _spent_cell(row: pd.Series) -> str:
    """The compute the look's runs took: env steps and training core-hours (both algorithms' runs)."""
    return f"{int(row['spent_env_steps']):,} env steps, {row['spent_core_hours']:.1f} core-h"


def _base_cell(row: pd.Series) -> str:
    if not isinstance(row["base"], str):
        return "-"
    return row["base"] if not is_missing(row["base_seeds"]) else f"{row['base']} (no runs)"


def _velocity_cell(row: pd.Series) -> str:
    seeds, of = row["forward_velocity_seeds"], row["seeds"]
    return fmt(row["forward_velocity_iqm"]) + (f" ({seeds} of {of} seeds)" if 0 < seeds < of else "")


def rests_on_runs(runs: list[RunRecord], what: str = "training runs") -> str:
    """The sentence saying what a table's numbers rest on: runs, groups, seeds, epochs, env steps, and the
    devices they trained on where any was not the CPU (a suite reuses a run finished on another device)."""
    if not runs:
        return f"Rests on no {what}."
    seeds_per_group = Counter(r.group for r in runs).values()
    devices = Counter(r.device for r in runs)
    counts = ", ".join(f"{d} ({n})" for d, n in devices.most_common())
    where = "" if set(devices) == {"cpu"} else f" Trained on {counts}: wall times are each device's."
    return (
        f"Rests on {len(runs)} {what} in {len(seeds_per_group)} (task, backend, algo, h, N, planned epochs) groups "
        f"with {fmt_range(seeds_per_group)} training seeds each, {fmt_range(r.epochs for r in runs)} epochs and "
        f"{fmt_range(r.env_steps for r in runs)} env steps per run.{where}"
    )


# -- the tables as documents ----------------------------------------------------------------------
def _key_columns(*names: str) -> ColumnSpec:
    labels = {"horizon": "h", "env_steps": "env steps per run", "num_envs": "N"}
    return [(labels.get(n, n), n) for n in names]


def _run_commits(runs: Iterable[RunRecord]) -> list[str]:
    return commit_counts(r.commit for r in runs)


def _whole(column: str):
    """A cell of whole numbers from a column that pandas holds as floats (it has missing values)."""
    return lambda r: "n/a" if is_missing(r[column]) else str(int(r[column]))


def returns_document(runs: list[RunRecord]) -> Table:
    """Final evaluation returns: IQM, CI and improvement over the base algorithm."""
    evaluated = [r for r in runs if r.evaluation is not None]
    returns = returns_table(runs)
    eval_protocol = ""
    if evaluated:
        eval_protocol = (
            f" Each run's final (and initial) policy is evaluated deterministically over "
            f"{fmt_range(r.evaluation.get('seeds') or 0 for r in evaluated)} eval seeds x "
            f"{fmt_range(r.evaluation.get('num_envs') or 0 for r in evaluated)} envs, first episode of each env."
        )
    return Table(
        "returns",
        "Final evaluation return per algorithm",
        rests_on_runs(evaluated, "evaluated training runs") + eval_protocol,
        [
            _returns_section(returns),
            _power_section(runs),
            _claims_section(runs),
            _lambda_course_section(runs),
            _lambda_rate_section(runs),
            _ablation_section(runs),
            _grad_variance_section(runs),
            _locomotion_section(runs),
        ],
        _returns_notes(),
        _run_commits(evaluated),
    )


def _returns_section(returns) -> Section:
    """The returns table proper: one row per (task, backend, algorithm, horizon, N, epochs)."""
    return Section(
        returns,
        _key_columns("task", "backend", "algo", "horizon", "num_envs", "seeds", "epochs", "env_steps")
        + [
            ("IQM final", "iqm_final"),
            ("95% CI", lambda r: fmt_ci(r["iqm_ci_low"], r["iqm_ci_high"])),
            ("mean ± std", lambda r: f"{fmt(r['mean_final'])} ± {fmt(r['std_final'])}"),
            ("initial (mean)", "mean_initial"),
            ("vs base", _base_cell),
            ("IQM improvement (descriptive)", "improvement_iqm"),
            ("P(algo > base) (descriptive)", "p_improvement"),
            ("detectable at 80% power (paired)", "mde_80"),
            ("forward velocity m/s (IQM)", _velocity_cell),
            ("velocity 95% CI", lambda r: fmt_ci(r["forward_velocity_ci_low"], r["forward_velocity_ci_high"])),
        ],
        empty="no run has an eval.json",
    )


def _power_section(runs: list[RunRecord]) -> Section:
    """Seeds per algorithm a two-sample t-test needs to detect an improvement (a planning figure)."""
    return Section(
        power_table(runs),
        _key_columns("task", "backend", "num_envs", "epochs", "horizon", "family", "algos", "seeds")
        + [
            ("between-seed std (pooled)", "pooled_std"),
            ("base's mean", "base_mean"),
            ("std / base mean", "cv"),
        ]
        + [(f"seeds for +{round(e * 100)}%", _whole(f"seeds_for_{round(e * 100)}pct")) for e in EFFECTS],
        heading="Statistical power: seeds per algorithm needed to detect an improvement",
        csv_suffix="_power",
        empty="no run has an eval.json",
    )


def _claims_section(runs: list[RunRecord]) -> Section:
    """The paper's claims, each TD-lambda variant against its base, by the pre-registered analysis."""
    return Section(
        claims_table(runs),
        _key_columns("task", "backend", "num_envs", "epochs", "horizon", "env_steps", "metric", "algo", "base")
        + [
            ("seed pairs", "pairs"),
            ("look", lambda r: r["look"] if isinstance(r["look"], str) and r["look"] else "none yet"),
            ("claimed", lambda r: _signed_pct(r["claimed_change"])),
            ("mean ratio - 1 (verdict's estimand)", lambda r: _signed_pct(r["measured_change"])),
            ("interval", _change_ci),
            ("verdict", "verdict"),
            ("design", _design_cell),
            ("IQM algo / base (descriptive)", lambda r: f"{fmt(r['iqm_algo'])} / {fmt(r['iqm_base'])}"),
            ("P(algo > base) (descriptive)", "p_improvement"),
            ("sign-flip p", "sign_flip_p"),
            ("spent", _spent_cell),
            ("paper", "source"),
        ],
        heading="The paper's claims: each TD-lambda variant against its base",
        csv_suffix="_claims",
        empty="no setting has evaluated runs of a claim's two algorithms",
    )


def _lambda_course_section(runs: list[RunRecord]) -> Section:
    """Fig. 4b: does the learned lambda fall over training?"""
    return Section(
        lambda_course_table(runs),
        _key_columns("task", "backend", "num_envs", "epochs", "horizon", "env_steps", "algo", "seeds")
        + [
            ("lambda after epoch 1 (mean)", "lambda_first"),
            (
                "final lambda (mean ± std)",
                lambda r: f"{fmt(r['lambda_final_mean'])} ± {fmt(r['lambda_final_std'])}",
            ),
            ("change (mean)", "change"),
            ("95% CI", lambda r: fmt_ci(r["change_ci_low"], r["change_ci_high"])),
            ("epochs lambda fell", lambda r: fmt_pct(r["falling_share"])),
            ("verdict: lambda falls", "verdict"),
            ("paper", "source"),
        ],
        heading="The paper's claim that the learned lambda falls over training",
        csv_suffix="_lambda",
        empty="no adaptive-lambda algorithm has evaluated runs",
    )


def _lambda_rate_section(runs: list[RunRecord]) -> Section:
    """Fig. 4b judged on what lambda's optimiser allows."""
    return Section(
        lambda_rate_table(runs),
        _key_columns("task", "backend", "num_envs", "epochs", "horizon", "env_steps", "algo", "seeds")
        + [
            ("phi updates x lr (limit)", "limit"),
            ("change of phi (mean)", "delta_phi"),
            ("95% CI", lambda r: fmt_ci(r["delta_phi_ci_low"], r["delta_phi_ci_high"])),
            (
                "share of the limit used (mean, range)",
                lambda r: f"{fmt_pct(r['used_share'])} ({fmt_pct(r['used_share_min'])}-{fmt_pct(r['used_share_max'])})",
            ),
            ("epochs lambda fell", lambda r: fmt_pct(r["falling_share"])),
            ("verdict", "verdict"),
            ("paper", "source"),
        ],
        heading="The learned lambda's fall against what its optimiser allows",
        csv_suffix="_lambda_rate",
        empty="no adaptive-lambda algorithm has evaluated runs",
    )


def _ablation_section(runs: list[RunRecord]) -> Section:
    """Fig. 6: SAPO-TDAdpt's lambda updated more or less often than its default."""
    return Section(
        ablation_table(runs),
        _key_columns("task", "backend", "num_envs", "epochs", "horizon", "env_steps", "algo", "seeds")
        + [
            ("against", "reference"),
            ("mean final return", "mean_final"),
            ("IQM final (descriptive)", "iqm_final"),
            (
                "final lambda (mean): setting / own",
                lambda r: f"{fmt(r['lambda_final'])} / {fmt(r['reference_lambda_final'])}",
            ),
            ("seed pairs", "pairs"),
            ("mean ratio - 1", lambda r: _signed_pct(r["measured_change"])),
            ("interval", _change_ci),
            ("verdict: this setting lowers the return", "verdict"),
            ("pairs under half of their own's return", lambda r: f"{r['collapsed_pairs']} of {r['pairs']}"),
            ("paper", "source"),
        ],
        heading="The paper's Fig. 6: how often lambda is updated",
        csv_suffix="_ablation",
        empty="no ablation setting has evaluated runs beside its algorithm's own",
    )


def _grad_variance_section(runs: list[RunRecord]) -> Section:
    """Fig. 2: does TD-lambda lower the actor gradient's variance over training?"""
    return Section(
        gradient_variance_claim_table(runs),
        _key_columns("task", "backend", "num_envs", "epochs", "horizon", "env_steps", "statistic", "algo")
        + [
            ("base", "base"),
            ("seed pairs", "pairs"),
            (
                "level algo / base (geometric mean)",
                lambda r: f"{fmt(r['level_algo'])} / {fmt(r['level_base'])}",
            ),
            ("ratio", "ratio"),
            ("95% CI", lambda r: fmt_ci(r["ratio_ci_low"], r["ratio_ci_high"])),
            ("verdict: TD-lambda lowers it", "verdict"),
            ("paper's levels", "paper_levels"),
            ("paper", "source"),
        ],
        heading="The paper's claim that TD-lambda lowers the actor gradient's variance over training",
        csv_suffix="_grad_variance",
        empty="no finished variant and base logged the actor-gradient statistics",
    )


def _locomotion_section(runs: list[RunRecord]) -> Section:
    """Do the final policies move forward?"""
    return Section(
        locomotion_table(runs),
        _key_columns("task", "backend", "num_envs", "epochs", "horizon", "env_steps", "algo", "seeds")
        + [
            ("untrained velocity m/s (mean)", "untrained_velocity"),
            ("look", lambda r: r["look"] or "before the first"),
            ("look's mean m/s [CI]", lambda r: f"{fmt(r['look_velocity'])} {_ci_at(r)}"),
            ("verdict", "verdict"),
            ("design", lambda r: f"{r['design']} -> {r['seeds_wanted']} seeds"),
            ("all seeds' mean m/s [95% CI] (descriptive)", _all_seeds_velocity),
            (f"seeds at >= {LOCOMOTION_SPEED} m/s", lambda r: f"{r['seeds_moving']} of {r['seeds']}"),
            ("paper says", "paper_says"),
            ("paper's claim", "paper_verdict"),
            ("paper", "source"),
        ],
        heading="Forward locomotion: do the final policies move forward?",
        csv_suffix="_locomotion",
        empty="no evaluation recorded a forward velocity",
    )


def _ci_at(row) -> str:
    """A locomotion look's interval with its level."""
    return f"{fmt_ci(row['look_ci_low'], row['look_ci_high'])} ({100 * row['confidence']:g}%)"


def _all_seeds_velocity(row) -> str:
    """The mean forward velocity over every seed with its 95% t CI: a description, never the verdict."""
    return f"{fmt(row['final_velocity'])} {fmt_ci(row['final_velocity_ci_low'], row['final_velocity_ci_high'])}"


def _returns_notes() -> list[str]:
    """How each section of the returns table is computed (the table's notes)."""
    return [
        "IQM: interquartile mean over training seeds (`scipy.stats.trim_mean(x, 0.25)`, rliable's "
        "definition), each seed contributing its eval.json final mean return; under 4 seeds it trims "
        "nothing and is the mean. 95% CI: percentile bootstrap over seeds, "
        f"{BOOTSTRAP_RESAMPLES} resamples, `np.random.default_rng({BOOTSTRAP_SEED})` "
        "(`scipy.stats.bootstrap`; one task and backend per row is one stratum, so rliable's stratified "
        "bootstrap is this plain one), descriptive: at 5 seeds it covers less than 95% "
        "(results/statistics/coverage.md). n/a under 2 seeds. mean ± std: sample std (n - 1).",
        "IQM improvement: IQM(algo) - IQM(base) at the same task, backend, h, N and epochs (base of "
        "shac-tdfixed and shac-tdadpt is shac, of sapo-tdfixed and sapo-tdadpt sapo); P(algo > base): "
        "rliable's probability of improvement (`rliable.metrics.probability_of_improvement`: the chance "
        "that a random seed of the algorithm scores above a random seed of its base, ties counting half; "
        "0.5 is no difference). Both descriptive, without an interval: the verdicts are the claims "
        "table's, and a percentile bootstrap of P at 5 seeds covers far less than 95% "
        "(results/statistics/coverage.md).",
        "Detectable at 80% power (paired): the smallest true difference of mean final returns between the "
        "algorithm and its base that a two-sided paired t-test at level 0.05 detects with probability 0.8 "
        "over the seeds both have, (t_0.975 + t_0.8) s_d / sqrt(n) at n - 1 degrees of freedom, s_d the std "
        "of the seed-paired differences; an improvement below it is not evidence either way. Power table: "
        "per algorithm family (a base and its TD-lambda variants), the between-seed std pooled over the "
        "family's algorithms, and the seeds per algorithm at which a two-sample t-test detects +25%, +50% "
        "and +100% of the base's mean return (blank: over 10,000), a planning figure.",
        "Forward velocity: the final policy's velocity along +x (the root's; the SoftJumper's centre of "
        "mass), each env's mean over its first episode, averaged over envs and eval seeds; IQM and CI over "
        "training seeds as for the return. It says whether a policy moves forward at all, whatever the "
        "reward's other terms pay; over the training seeds whose evaluation recorded it (the cell says how "
        "many when not all did), n/a when none did.",
        "The paper's claims, by the analysis plan fixed in docs/statistics.md before the runs it decides: "
        "each claimed improvement of a TD-lambda variant over its base (ARE: Fig. 5 for the Ant, Fig. 9 and "
        "the abstract for the Go2) as the relative change of the mean final return, mean(algo) / mean(base) -"
        " 1 (the paper normalises by the base's mean), over the seeds both algorithms have evaluated (seed s "
        "gives both the same initial policy and environments: a paired design); for the Go2's SHAC-TDAdpt "
        "also of the mean forward velocity. Interval: the paired Fieller interval (the ratios r whose paired "
        "t-test of algo - r base does not reject), unbounded where the base's mean is not told from 0. Seeds "
        "arrive in a group-sequential design: looks at 5 and 10 seed pairs, 0.025 of the error spent at each "
        "(97.5% intervals, Bonferroni), a look reads its own first pairs only, a claim decided at a look "
        "keeps that look's verdict, and one undecided at the first look stops there when futile (conditional "
        "power under 0.10: were the next pairs to come from what the first five show, under 10% of 2,000 "
        "simulated completions would decide). Verdict: confirmed when the interval lies above 0 and does not "
        "lie below the claimed size; contradicted when it lies below the claimed size at the paper's protocol"
        " (N 64, h 32, 2000 epochs), not confirmed at this budget when it does so at another setting; "
        "undecided when it holds both 0 and the claimed size. Design: what the design does next (continue, "
        "decided, futile, last look) and the seeds per algorithm it asks for, which `bench --profile "
        "protocol` plans. Descriptive only, never a verdict: each side's IQM, rliable's probability of "
        "improvement over the pairs' seeds (its bootstrap interval under-covers at these seeds, so none is "
        "shown) and the exact sign-flip p-value of the paired differences (its smallest value at 5 pairs is "
        "0.0625). Spent: env steps and training wall time (core-hours) of both algorithms' runs the look "
        "read; a base's runs count for each claim that reads them.",
        'The learned lambda (Fig. 4b: it "gradually decreases over time"): per finished run of an '
        "adaptive-lambda algorithm, lambda after its first and its last epoch; change: last - first, mean "
        "over seeds with the 95% CI of a one-sample t-test; epochs lambda fell: the share of epochs whose "
        "update lowered it, averaged over seeds. Verdict: confirmed when the CI lies below 0, contradicted "
        "when above, undecided otherwise. Its course per epoch: lambda_alpha.png.",
        "The learned lambda's pace (Fig. 4b judged on what the optimiser allows): lambda = sigmoid(phi) and "
        "phi takes one AdamW step per lambda update, about the learning rate in size whenever the gradient "
        "keeps its sign, so a fall in every epoch says only that the sign never turned. Per finished run, "
        "the change of phi from logit(0.95) to its final value against the limit updates x learning rate; "
        "verdict: at the optimiser's rate limit when every seed used 90% of it or more (the data set only "
        "the sign), slower than the optimiser allows when phi fell (95% t CI over seeds below 0) using "
        "less (the data, or the gradient's varying size, set the pace), undecided otherwise.",
        "Fig. 6 (how often lambda is updated): each ablation setting of an algorithm ((b_lambda, m_lambda) "
        "of SAPO-TDAdpt: env groups per lambda iteration, lambda iterations per epoch) against the "
        "algorithm's own runs at the same setting, (1, 1), on the seeds both have evaluated (seed s: the "
        "same initial policy and environments), by the analysis fixed in docs/statistics.md before the "
        "ablation's runs were read: mean(setting) / mean(own) - 1 with the paired Fieller interval. The "
        "paper says (4, 2) and (4, 3) lower the return: judged on direction at 97.5% each (Bonferroni over "
        "the two), confirmed when the interval lies below 0, contradicted when above 0 at the paper's "
        "protocol (not confirmed at this budget elsewhere), undecided otherwise; the other settings are "
        "described with a 95% interval and no verdict. Pairs under half of their own's return: the seeds "
        "on which the setting's final return fell below half of its pair's (the paper's \"plummets\").",
        "Actor-gradient variance over training (Fig. 2): per run the median over epochs of the logged "
        "variance (raw, and the scale-free noise-to-signal ratio), per seed pair variant / base; the ratio "
        "is the geometric mean over pairs with the 95% t interval of the paired log-ratios. Verdict: "
        "confirmed when the interval lies below 1, contradicted above 1 at the paper's protocol (not "
        "confirmed at this budget elsewhere), undecided otherwise. The levels are shown beside the paper's "
        "descriptively: the variance scales with the loss, whose normalisation differs between "
        "implementations. The curves: grad_variance_training.png.",
        f"Forward locomotion: a policy moves forward when its forward velocity (as above) reaches "
        f"{LOCOMOTION_SPEED} m/s, a slow walk for a legged robot of the Go2's or the Ant's size and above the "
        "drift of a policy that stands still or falls over (the untrained policies' column shows that "
        "drift). Per setting and algorithm, over the training seeds whose evaluation recorded a velocity "
        "(seed order): the untrained policies' mean velocity; the verdict, read at the claims' looks (5 "
        "seeds, then 10) on the look's first seeds with a one-sample t interval at 97.5% (both looks hold "
        "the mean together at 95%; a verdict reached is kept): moves forward when the interval lies above "
        "the speed, does not when below, undecided otherwise; what the design does next; and, descriptive "
        "only, the mean and 95% t CI over every seed and the seeds that reach the speed "
        "(docs/statistics.md). Where the paper says whether an "
        "algorithm acquires forward locomotion on a task (Sec. V-E: the Go2's SHAC does not, at the "
        "paper's budget; its SHAC-TDAdpt improves on that markedly), the claim is confirmed when the "
        "verdict agrees, contradicted when it disagrees at the paper's protocol (N 64, h 32, 2000 epochs), "
        "not confirmed at this budget when it disagrees below it, undecided while the verdict is.",
        "Runs without eval.json (unfinished) are left out of these tables.",
    ]


def aggregate_document(runs: list[RunRecord]) -> Table:
    """rliable's aggregates across tasks: normalised-score IQM and probability of improvement."""
    table = aggregate_table(runs)
    return Table(
        "aggregate",
        "Across tasks: aggregate IQM of normalised scores and probability of improvement (rliable)",
        rests_on_runs([r for r in runs if r.evaluation is not None], "evaluated training runs"),
        [
            Section(
                table,
                _key_columns("backend", "algo", "tasks", "seeds")
                + [
                    ("IQM normalised", "iqm_normalised"),
                    ("95% CI", lambda r: fmt_ci(r["iqm_ci_low"], r["iqm_ci_high"])),
                    ("vs base", lambda r: r["base"] if isinstance(r["base"], str) else ""),
                    ("P(algo > base) across tasks", "p_improvement"),
                    ("P 95% CI (descriptive)", lambda r: fmt_ci(r["p_improvement_ci_low"], r["p_improvement_ci_high"])),
                    ("settings", "settings"),
                ],
                empty="no task has evaluated runs that improved on the untrained policy",
            )
        ],
        [
            "Runs: per task and backend the setting (N, epochs, h) with the most evaluated runs, so no task "
            "counts twice (harness/report/aggregate.py).",
            "Normalised score, per task and backend: (final return - untrained) / (best - untrained), untrained "
            "the mean initial-policy return of the setting's runs, best the highest IQM final return among its "
            "algorithms: 0 is an untrained policy, 1 the best algorithm on that task and engine.",
            "IQM normalised: `rliable.metrics.aggregate_iqm` over every seed of every task; 95% CI: rliable's "
            f"stratified bootstrap (seeds resampled within each task, {BOOTSTRAP_RESAMPLES} resamples, percentile). "
            "P(algo > base): `rliable.metrics.probability_of_improvement` averaged over the tasks both have, CI "
            "from rliable's stratified independent bootstrap. Performance profiles: performance_profile.png.",
        ],
        _run_commits(runs),
    )


def grad_variance_document(runs: list[RunRecord]) -> Table:
    """Both actor-gradient statistics per horizon, and their growth from the shortest horizon to the longest."""
    trained = [r for r in runs if r.epochs]
    per_h = grad_variance_table(runs)

    def with_ci(stem):
        return lambda r: f"{fmt(r[stem + '_gmean'])} [{fmt(r[stem + '_ci_low'])}, {fmt(r[stem + '_ci_high'])}]"

    def growth(stem):
        return lambda r: (
            f"{fmt(r[stem + '_growth'])} [{fmt(r[stem + '_growth_ci_low'])}, {fmt(r[stem + '_growth_ci_high'])}]"
        )

    return Table(
        "grad_variance_vs_h",
        "Actor-gradient variance against the horizon h: raw and scale-free",
        rests_on_runs(trained),
        [
            Section(
                per_h,
                _key_columns("task", "backend", "algo", "num_envs", "epochs", "horizon", "seeds")
                + [
                    ("updates skipped %", "skipped_pct"),
                    ("raw: seeds' gmean [95% CI]", with_ci("var")),
                    ("raw: pooled median", "median"),
                    ("raw: Q1", "q1"),
                    ("raw: Q3", "q3"),
                    ("NSR: seeds", "nsr_seeds"),
                    ("NSR: seeds' gmean [95% CI]", with_ci("nsr")),
                    ("NSR: pooled median", "nsr_median"),
                ],
                empty="no run has metrics",
            ),
            Section(
                grad_variance_growth_table(runs),
                _key_columns("task", "backend", "algo", "num_envs", "epochs")
                + [
                    ("from h", "h_min"),
                    ("to h", "h_max"),
                    ("raw growth [95% CI]", growth("var")),
                    ("raw growth, pooled medians", "growth_factor"),
                    ("NSR growth [95% CI]", growth("nsr")),
                ],
                heading="Growth from the shortest horizon (and from h 32) to the longest",
                csv_suffix="_growth",
                empty="no algorithm has runs at more than one horizon",
            ),
        ],
        [
            "raw: actor_grad_var, the trace of the K group gradients' covariance; it scales with the square of "
            "the loss, so it also measures the loss's size (actor_reward_weight). NSR: actor_grad_nsr, that "
            "variance over the bias-corrected squared norm of the mean gradient; unchanged by the loss's scale "
            "(docs/gradient-statistics.md). Seeds' gmean: the geometric mean over training seeds of each seed's "
            "median over epochs, with a 95% percentile bootstrap CI over seeds; inf when a seed's median NSR is "
            "unresolved (inf). Pooled median, Q1, Q3: every finite epoch of every seed. Growth: the ratio of "
            "the seeds' geometric means at the longest h to the shortest (and to h 32), with an unpaired "
            "bootstrap CI; 'pooled medians' is the same ratio of pooled medians. A row pools only runs of one "
            "setting (N envs, planned epochs). Runs from before the scale-free statistic have no NSR "
            "(NSR: seeds counts the runs that logged it). Updates skipped: the share of actor updates whose "
            "gradient norm passed the skip threshold or was not finite; their statistics are not logged, so "
            "where many are skipped the row describes only the updates that were taken, and understates the "
            "noise."
        ],
        _run_commits(trained),
    )


def returns_vs_h_document(runs: list[RunRecord]) -> Table:
    """Final return against h at one budget."""
    evaluated = [r for r in runs if r.evaluation is not None]
    return Table(
        "returns_vs_h",
        "Final evaluation return against the horizon h at one budget",
        rests_on_runs(evaluated, "evaluated training runs"),
        [
            Section(
                returns_vs_h_table(runs),
                _key_columns("task", "backend", "algo", "num_envs", "budget", "horizon", "epochs", "seeds")
                + [
                    ("IQM final", "iqm_final"),
                    ("95% CI", lambda r: fmt_ci(r["iqm_ci_low"], r["iqm_ci_high"])),
                    ("mean ± std", lambda r: f"{fmt(r['mean_final'])} ± {fmt(r['std_final'])}"),
                    ("wall min per run", "wall_min_mean"),
                    ("updates skipped %", "skipped_pct"),
                ],
                empty="no algorithm has evaluated runs at two horizons with one budget",
            )
        ],
        [
            "The paper's Fig. 7 (right) at the budget this machine affords: every row of a block spends the "
            "same env steps per run (budget: N x h x planned epochs; budgets within 2% count as one, since "
            "epochs are whole numbers), so a longer horizon gets fewer, longer updates. IQM and 95% CI over "
            "training seeds as in returns.md; wall minutes: training only, the mean over seeds (evaluation "
            "excluded), on the machine in the header; updates skipped: the share of actor updates whose "
            "gradient norm passed the skip threshold or was not finite."
        ],
        _run_commits(evaluated),
    )


def wall_time_document(runs: list[RunRecord]) -> Table:
    """Wall time per run and its split."""
    trained = [r for r in runs if r.epochs]
    wall = wall_time_table(runs)
    split_columns = [
        (label, lambda r, s=stem: f"{fmt(r[s + '_min'])} ({fmt_pct(r[s + '_frac'])})") for stem, label, _ in TIME_PARTS
    ]
    return Table(
        "wall_time",
        "Wall time of every training run and where it goes",
        rests_on_runs(trained),
        [
            Section(
                wall,
                _key_columns("run", "task", "backend", "algo", "horizon", "num_envs", "seed", "epochs")
                + [("wall min", "wall_min"), ("s / epoch", "s_per_epoch")]
                + split_columns,
                empty="no run has metrics",
            )
        ],
        [
            "Minutes summed over epochs (share of the wall time in brackets). Actor update includes gradient "
            "clipping, the variance estimate and SAPO's temperature step. Epochs logged before the update "
            "was split count their whole update as 'update (not split)'. Other: the rest of the wall time "
            "(rollout bookkeeping, logging, checkpoints). Evaluation is not part of the wall time."
        ],
        _run_commits(trained),
    )


def throughput_document(checks: list[CheckRecord]) -> Table:
    """env-steps/s of the throughput checks."""
    throughput_checks = [c for c in checks if c.kind == "throughput"]
    return Table(
        "throughput",
        "Simulation throughput per backend and task",
        f"Rests on {fmt_count(len(throughput_checks), 'throughput check file')}.",
        [
            Section(
                throughput_table(checks),
                _key_columns("task", "backend", "integrator", "num_envs", "horizon", "windows", "file")
                + [
                    ("forward env-steps/s", "forward_steps_per_s"),
                    (
                        "forward+backward env-steps/s",
                        lambda r: (
                            fmt(r["forward_backward_steps_per_s"])
                            + (" (estimated)" if r["forward_backward_estimated"] else "")
                        ),
                    ),
                    ("bare engine forward", "bare_forward_steps_per_s"),
                    ("bare engine forward+backward", "bare_engine_steps_per_s"),
                    ("adapter/bare time, forward", "forward_overhead_ratio"),
                    ("adapter/bare time, forward+backward", "overhead_ratio"),
                    ("gradient cost factor", "gradient_cost_factor"),
                    ("speed with gradients, as a share of (same process)", _against),
                ],
                empty="no throughput check",
            )
        ],
        [
            "env-steps/s = envs x steps / seconds, best of the timed windows (harness/checks/throughput.py). "
            "adapter/bare: time through this project's adapter over the engine's own loop (1.0 = no overhead). "
            "Estimated: `throughput --grad-cost-only` (finite-difference worlds timed, not a full step). "
            "Share of another backend: `throughput --against B`, the two adapters' windows with gradients timed "
            "in one process, alternating; the ratio of their median times, with the range of the rounds' ratios."
        ],
        commit_counts(c.provenance.get("git_commit") for c in throughput_checks),
    )


def _against(row) -> str:
    """A throughput row's speed with gradients as a share of another backend's, timed in the same process."""
    if is_missing(row["against"]):
        return ""
    rounds = f"{fmt(row['speed_ratio_min'])}-{fmt(row['speed_ratio_max'])}"
    return f"{fmt(row['speed_ratio'])} of {row['against']} (rounds {rounds})"


def backends_document(runs: list[RunRecord]) -> Table:
    """One algorithm, task and horizon on every backend side by side."""
    trained = [r for r in runs if r.epochs]
    wide = backends_table(runs)
    last = "_" + BACKEND_MEASURES[-1]
    backend_names = [c[: -len(last)] for c in wide.columns if c.endswith(last)]
    by_backend: ColumnSpec = []
    for b in backend_names:
        by_backend += [
            (f"{b} seeds", f"{b}_seeds"),
            (f"{b} epochs", f"{b}_epochs"),
            (f"{b} env steps", f"{b}_env_steps"),
            (f"{b} IQM final", f"{b}_iqm_final"),
            (f"{b} gain over untrained", f"{b}_gain_mean"),
            (f"{b} updates skipped %", f"{b}_skipped_pct"),
            (f"{b} median grad norm", f"{b}_grad_norm_median"),
            (f"{b} wall min", f"{b}_wall_min_mean"),
            (f"{b} s / epoch", f"{b}_s_per_epoch_mean"),
        ]
    return Table(
        "backends",
        "The same algorithm, task and horizon on every backend",
        rests_on_runs(trained),
        [
            Section(
                wide,
                _key_columns("task", "algo", "horizon", "num_envs") + by_backend,
                empty="no (task, algo, horizon) has runs on two or more backends",
            )
        ],
        [
            "Per backend: training seeds (runs), epochs and env steps per run, IQM of the final eval return "
            "over the evaluated seeds, the mean gain of the final policy's eval return over the untrained "
            "policy's (same protocol), the share of actor updates skipped as exploding or non-finite (all seeds' "
            "epochs), the median over seeds of each run's median actor-gradient norm (before clipping), mean "
            "wall minutes per run and mean seconds per epoch."
        ],
        _run_commits(trained),
    )


def sim_to_sim_document(runs: list[RunRecord]) -> Table:
    """Policies evaluated on another backend than they trained on."""
    s2s = sim_to_sim_table(runs)
    s2s_runs = [r for r in runs if any(e["backend"] != e["trained_on"] for e in r.cross_evaluations.values())]
    return Table(
        "sim_to_sim",
        "Sim-to-sim: policies evaluated on another backend than they trained on",
        rests_on_runs(s2s_runs) + f" {fmt_count(len(s2s), 'cross-backend evaluation')}.",
        [
            Section(
                s2s,
                _key_columns("task", "algo", "horizon", "num_envs", "epochs", "seed", "trained_on", "evaluated_on")
                + [
                    ("return where trained", "own_return"),
                    ("return on other", "other_return"),
                    ("gap (other - own)", "gap"),
                    ("own from", "own_source"),
                    ("same protocol", "same_protocol"),
                ],
                empty="no run has an eval_on_*.json or sim2sim_on_*.json",
            ),
            Section(
                sim_to_sim_mean_table(s2s),
                _key_columns("task", "algo", "horizon", "num_envs", "epochs", "trained_on", "evaluated_on", "seeds")
                + [
                    ("mean return where trained", "own_return_mean"),
                    ("mean return on other", "other_return_mean"),
                    ("mean gap", "gap_mean"),
                    ("gap std", "gap_std"),
                ],
                heading="Mean over seeds",
                csv_suffix="_mean",
                empty="no cross-backend evaluation",
            ),
        ],
        [
            "Return of the final policy (deterministic). Where trained: from the evaluation written with the "
            "same protocol on the training backend when there is one (sim2sim_on_<training backend>.json), "
            "else eval.json; 'same protocol' says whether both used the same eval seeds, envs and step cap."
        ],
        commit_counts(e.get("provenance", {}).get("git_commit") for r in runs for e in r.cross_evaluations.values()),
    )


def landscape_document(runs: list[RunRecord]) -> Table:
    """Roughness of the h-step and TD-lambda actor losses."""
    landscapes = [r for r in runs if r.landscape is not None]
    return Table(
        "landscape",
        "Roughness of the actor-loss landscapes: h-step vs TD-lambda return",
        rests_on_runs(landscapes, "runs with a landscape.json"),
        [
            Section(
                landscape_table(runs),
                _key_columns("task", "backend", "algo", "horizon", "seed", "grid", "span", "lambda")
                + [
                    ("roughness h-step", "roughness_h_step"),
                    ("roughness TD-lambda", "roughness_td_lambda"),
                    ("ratio", "ratio_h_step_over_td_lambda"),
                ],
                empty="no run has a landscape.json",
            ),
            Section(
                landscape_claim_table(runs),
                _key_columns("task", "backend", "num_envs", "epochs", "horizon", "grid", "span", "algos")
                + [
                    ("final policies", "policies"),
                    (
                        "roughness h-step / TD-lambda (geometric mean)",
                        lambda r: f"{fmt(r['roughness_h_step'])} / {fmt(r['roughness_td_lambda'])}",
                    ),
                    ("ratio", "ratio"),
                    ("95% CI", lambda r: fmt_ci(r["ratio_ci_low"], r["ratio_ci_high"])),
                    ("verdict: TD-lambda smoother", "verdict"),
                    ("paper", "source"),
                ],
                heading="The paper's claim that the TD-lambda loss is smoother (each final policy its own pair)",
                csv_suffix="_claims",
                empty="no setting has a final policy with a landscape.json",
            ),
        ],
        [
            "Roughness: total variation of the loss surface per grid line over its range (harness/checks/landscape.py; "
            "0.5 for a plane, >> 1 for a jagged surface). Ratio: h-step / TD-lambda (> 1: TD-lambda smoother).",
            "The claim's estimand, interval and verdict words are fixed in docs/statistics.md (Fig. 3): the "
            "geometric mean over final policies of the ratio, a one-sample t interval on the log-ratios; "
            "'contradicted' only at the paper's Ant protocol (N 64, h 32, 2000 epochs or more).",
        ],
        commit_counts((r.landscape.get("provenance") or {}).get("git_commit") for r in landscapes),
    )


def step_gain_document(runs: list[RunRecord]) -> Table:
    """Proposition 1's bound against the one-step gains along final policies."""
    measured = [r for r in runs if r.step_gain is not None]
    return Table(
        "step_gain",
        "Proposition 1: the one-step Jacobian's gain B_f along trained policies against 1/(gamma lambda)",
        rests_on_runs(measured, "runs with a step_gain.json"),
        [
            Section(
                step_gain_table(runs),
                _key_columns("task", "backend", "algo", "horizon", "seed", "states", "lambda")
                + [
                    ("state gain median", "gain_median"),
                    ("state gain p95", "gain_p95"),
                    ("action gain median", "action_gain_median"),
                    ("growth per step over a window (median)", "window_growth"),
                ],
                empty="no run has a step_gain.json",
            ),
            Section(
                step_gain_claim_table(runs),
                _key_columns("task", "backend", "num_envs", "epochs", "horizon", "algos")
                + [
                    ("final policies", "policies"),
                    ("states", "states"),
                    ("bound 1/(gamma 0.95)", "bound"),
                    ("state gain median", "gain_median"),
                    ("state gain p95 (pooled)", "gain_p95"),
                    ("p95 per policy (range)", lambda r: f"{fmt(r['gain_p95_min'])}-{fmt(r['gain_p95_max'])}"),
                    ("states above the bound", lambda r: fmt_pct(r["share_above_bound"])),
                    ("growth per step over a window", "window_growth"),
                    ("verdict", "verdict"),
                    ("paper", "source"),
                ],
                heading="The paper's Proposition 1 on the states trained policies visit",
                csv_suffix="_claims",
                empty="no setting has a final policy with a step_gain.json",
            ),
        ],
        [
            "State gain: the spectral norm of one control step's Jacobian d s'/d s over the generalized "
            "coordinates (root quaternion left out), at states the final policy visits with stochastic actions "
            "(harness/checks/step_gain.py). Its units mix positions and velocities: the bound is read in the "
            "coordinates the algorithms see. Growth per step over a window: ||d s_{t+h}/d s_t||^(1/h) with the "
            "actions held, the rate eq. 19's chain actually compounds at; a norm of a product is at most the "
            "product of the norms, so the per-step gain bounds it from above. Verdict read as docs/statistics.md "
            "fixed it: the pooled 95th percentile against 1/(gamma lambda) at lambda 0.95."
        ],
        commit_counts((r.step_gain.get("provenance") or {}).get("git_commit") for r in measured),
    )


def checks_document(checks: list[CheckRecord]) -> Table:
    """Every check file in one line."""
    return Table(
        "checks",
        "Checks: gradients, cross-backend agreement, throughput",
        f"Rests on {fmt_count(len(checks), 'check file')}.",
        [
            Section(
                checks_table(checks),
                [
                    ("file", "file"),
                    ("kind", "kind"),
                    ("task", "task"),
                    ("backend", "backend"),
                    ("settings", lambda r: r["settings"] if isinstance(r["settings"], str) else "defaults"),
                    ("passed", lambda r: fmt_verdict(r["passed"])),
                    ("key numbers", "summary"),
                    ("made (UTC)", "created_utc"),
                ],
                empty="no check file",
            )
        ],
        [
            "passed: the check's own verdict where it gives one (gradcheck against its tolerance); crosschecks "
            "report agreement numbers without a verdict (n/a). settings: the preset and backend options the "
            "check's command named (defaults: none named)."
        ],
        commit_counts(c.provenance.get("git_commit") for c in checks),
    )


def build_tables(runs: list[RunRecord], checks: list[CheckRecord]) -> list[Table]:
    """Every table of the report, computed (nothing written), in the order index.md lists them."""
    return [
        returns_document(runs),
        aggregate_document(runs),
        grad_variance_document(runs),
        returns_vs_h_document(runs),
        wall_time_document(runs),
        throughput_document(checks),
        backends_document(runs),
        sim_to_sim_document(runs),
        landscape_document(runs),
        step_gain_document(runs),
        checks_document(checks),
    ]
