"""The ``report`` verb (harness/report/compare.py) on synthetic run directories: the per-algorithm table
over seeds carries the bench report's statistics (IQM with a 95% percentile-bootstrap CI over seeds),
recomputed here with scipy directly; the per-run medians, the Markdown and the curves."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from harness.formatting import fmt
from harness.report.compare import AGGREGATED, GROUP, STATISTICS, summarize, write_report

EVAL_FINALS = {"shac": [1.0, 2.0, 3.0, 4.0, 100.0], "sapo": [7.0]}


def make_run(root: Path, algo: str, seed: int, final: float, grad_var: list[float]) -> Path:
    """config.json, metrics.jsonl (one row per entry of ``grad_var``) and eval.json, as harness/run/train.py
    leaves them."""
    run = root / f"ant_newton_{algo}_s{seed}"
    run.mkdir(parents=True)
    config = {"task": "ant", "backend": "newton", "seed": seed, "algo": {"algo": algo, "num_envs": 4, "horizon": 8}}
    (run / "config.json").write_text(json.dumps(config))
    rows = [
        {
            "epoch": epoch,
            "env_steps": (epoch + 1) * 32,
            "wall_s": (epoch + 1) * 6.0,
            "sim_forward_s": 1.0,
            "backward_s": 2.0,
            "update_s": 3.0,
            "actor_grad_var": value,
            "lam": 0.95,
            "train_episode_return": 10.0 * epoch + seed,
        }
        for epoch, value in enumerate(grad_var)
    ]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    block = lambda value: {"mean_return": value, "std_over_seeds": 0.5}  # noqa: E731
    (run / "eval.json").write_text(json.dumps({"seeds": 3, "initial": block(-5.0), "final": block(final)}))
    return run


@pytest.fixture
def runs(tmp_path) -> list[Path]:
    made = []
    for algo, finals in EVAL_FINALS.items():
        for seed, final in enumerate(finals):
            made.append(make_run(tmp_path / "runs", algo, seed, final, [1.0, 4.0, math.nan, 2.0 + seed]))
    return made


def _bootstrap_iqm_ci(values: list[float]) -> tuple[float, float]:
    """The bench report's interval, written out: scipy's percentile bootstrap of trim_mean(x, 0.25),
    2000 resamples, rng seeded 0."""
    ci = stats.bootstrap(
        (np.asarray(values),),
        lambda x, axis: stats.trim_mean(x, 0.25, axis=axis),
        n_resamples=2000,
        confidence_level=0.95,
        method="percentile",
        rng=np.random.default_rng(0),
    ).confidence_interval
    return ci.low, ci.high


def test_runs_of_other_settings_or_adapter_options_are_never_pooled(runs, tmp_path):
    """Seeds pool only within the bench report's row: a run of another planned epoch count, env count or
    adapter option (labelled in the backend column) is a row of its own, in the table and in the curves."""
    variants = {"epochs": ("epochs", 40), "envs": ("num_envs", 8), "options": ("backend_options", {"fd_scheme": "x"})}
    extra = []
    for name, (key, value) in variants.items():
        run = make_run(tmp_path / name, "shac", 9, 50.0, [1.0, 2.0])
        config = json.loads((run / "config.json").read_text())
        (config["algo"] if key == "num_envs" else config)[key] = value
        (run / "config.json").write_text(json.dumps(config))
        extra.append(run)
    write_report(runs + extra, tmp_path / "out" / "cmp", "python -m harness report", plot=True)
    with (tmp_path / "out" / "cmp_by_algo.csv").open() as fh:
        rows = [row for row in csv.DictReader(fh) if row["algo"] == "shac"]
    assert sorted(int(row["seeds"]) for row in rows) == [1, 1, 1, 5]
    assert {row["backend"] for row in rows} == {"newton", "newton+fd_scheme=x"}


def _by_algo(path: Path) -> dict[str, dict[str, str]]:
    with path.open() as fh:
        return {row["algo"]: row for row in csv.DictReader(fh)}


def test_by_algo_gives_iqm_with_the_bootstrap_ci_of_the_bench_report(runs, tmp_path):
    written = write_report(runs, tmp_path / "out" / "cmp", "python -m harness report", plot=False)
    assert [p.name for p in written] == ["cmp.md", "cmp.csv", "cmp_by_algo.csv"]
    table = _by_algo(tmp_path / "out" / "cmp_by_algo.csv")
    header = list(next(iter(table.values())))
    assert header == [*GROUP, "seeds", "env_steps"] + [f"{c}_{k}" for c in AGGREGATED for k in STATISTICS]

    shac = table["shac"]
    finals = EVAL_FINALS["shac"]
    assert shac["seeds"] == "5"
    assert float(shac["eval_final_iqm"]) == pytest.approx(3.0)  # the middle half of 1, 2, 3, 4, 100
    low, high = _bootstrap_iqm_ci(finals)
    assert float(shac["eval_final_ci_low"]) == pytest.approx(low)
    assert float(shac["eval_final_ci_high"]) == pytest.approx(high)
    assert low < 3.0 < high
    assert float(shac["eval_final_mean"]) == pytest.approx(np.mean(finals))
    assert float(shac["eval_final_std"]) == pytest.approx(np.std(finals, ddof=1))
    assert float(shac["wall_min_iqm"]) == pytest.approx(0.4)  # every seed: 4 epochs of 6 s

    # one seed: the IQM is its value and there is no interval (nor a std)
    sapo = table["sapo"]
    assert float(sapo["eval_final_iqm"]) == 7.0
    assert sapo["eval_final_ci_low"] == sapo["eval_final_ci_high"] == sapo["eval_final_std"] == ""

    text = (tmp_path / "out" / "cmp.md").read_text()
    assert "95% percentile-bootstrap CI" in text and "Student" not in text
    assert "One training seed for some algorithms" in text
    row = next(line for line in text.splitlines() if line.startswith("| ant | newton |") and "| shac |" in line)
    assert f"| {fmt(3.0)} [{fmt(low)}, {fmt(high)}] |" in row
    header_cells = next(line for line in text.splitlines() if line.startswith("| task | backend | envs |"))
    assert header_cells.count("|") == row.count("|")  # one header per cell


def test_per_run_medians_skip_unlogged_epochs(runs):
    # epochs 1.0, 4.0, NaN, 2.0 + seed: the NaN epoch is dropped, the median of the other three is taken
    assert summarize(runs[0])["median_actor_grad_var"] == 2.0
    assert summarize(runs[3])["median_actor_grad_var"] == 4.0
    assert summarize(runs[0])["median_actor_grad_nsr"] is None  # never logged


def test_curves_are_written_atomically(runs, tmp_path):
    out = tmp_path / "plots" / "cmp"
    paths = write_report(runs, out, "python -m harness report")
    png = tmp_path / "plots" / "cmp.png"
    assert paths[-1] == png and png.read_bytes().startswith(b"\x89PNG")
    assert sorted(p.name for p in png.parent.iterdir()) == ["cmp.csv", "cmp.md", "cmp.png", "cmp_by_algo.csv"]


def _drawn_panels(records, monkeypatch, tmp_path) -> dict[str, int]:
    """plot_curves' panels as {title: lines drawn}, the figure caught before it is saved."""
    from harness.report import compare
    from harness.report.records import load_run

    caught = {}
    monkeypatch.setattr(compare, "save_figure", lambda fig, path: caught.setdefault("fig", fig) and Path(path))
    loaded = [load_run(r) for r in records]
    compare.plot_curves(loaded, [summarize(r) for r in loaded], tmp_path / "curves.png")
    return {ax.get_title(): len(ax.get_lines()) for ax in caught["fig"].axes}


def test_curves_draw_the_raw_variance_beside_the_scale_free_ratio_and_name_each(runs, monkeypatch, tmp_path):
    # runs from before the scale-free statistic: its panel is there, named, and empty
    panels = _drawn_panels(runs, monkeypatch, tmp_path)
    raw = "raw actor-gradient variance (K groups; scales with the loss squared)"
    nsr = "noise-to-signal ratio (scale-free)"
    assert panels[raw] > 0 and panels[nsr] == 0
    for run in runs:  # now every epoch logs the ratio too (inf: unresolved, drawn as a gap)
        path = run / "metrics.jsonl"
        rows = [json.loads(line) for line in path.read_text().splitlines()]
        for i, row in enumerate(rows):
            row["actor_grad_nsr"] = math.inf if i == 0 else 0.5 + i
        path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    panels = _drawn_panels(runs, monkeypatch, tmp_path)
    assert panels[raw] > 0 and panels[nsr] > 0


def test_a_run_given_twice_counts_once(runs, tmp_path):
    out = tmp_path / "twice"
    write_report([runs[0], *runs], out, "cmd", plot=False)
    rows = list(csv.DictReader(open(out.with_suffix(".csv"))))
    assert len(rows) == len(runs)


def test_damaged_and_stale_files_are_said_in_one_line_each_and_not_counted(runs, tmp_path, capsys):
    """The bench report's reader: a truncated eval.json, a stale one (older than the run's last epoch) and a
    metrics file that is not JSON lines are each said once and leave their columns empty; no traceback."""
    truncated = (runs[0] / "eval.json").read_text()
    (runs[0] / "eval.json").write_text(truncated[: len(truncated) // 2])
    stale = json.loads((runs[1] / "eval.json").read_text()) | {"policy_epoch": 2}
    (runs[1] / "eval.json").write_text(json.dumps(stale))
    (runs[2] / "metrics.jsonl").write_text("not json\n{}\n")
    write_report(runs, tmp_path / "out" / "cmp", "cmd", plot=True)
    said = [line for line in capsys.readouterr().out.splitlines() if not line.startswith("wrote")]
    assert len(said) == 3, said
    assert "ignored" in said[0] and "stale" in said[1] and "metrics ignored" in said[2]
    rows = {row["run"]: row for row in csv.DictReader(open(tmp_path / "out" / "cmp.csv"))}
    assert rows[runs[0].name]["eval_final"] == rows[runs[1].name]["eval_final"] == ""
    assert rows[runs[2].name]["epochs"] == "0" and rows[runs[3].name]["eval_final"] == "4.0"
