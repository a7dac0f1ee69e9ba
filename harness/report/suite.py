"""The bench report's entry point: :func:`write_bench_report` reads the suite's runs and checks and writes
every table, plot and ``index.md`` into one folder (what each holds: :mod:`harness.report`)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from pathlib import Path

from harness.checks.scaling import plot_scaling
from harness.figures import NoPlotData, pyplot
from harness.report.aggregate import headline_settings, plot_performance_profiles
from harness.report.documents import Table, build_tables, header_lines, markdown_rows, write_table
from harness.report.free_claims import judged_curves, plot_gradient_variance_curves
from harness.report.plots import (
    PLOT_DESCRIPTIONS,
    plot_grad_variance,
    plot_lambda_alpha,
    plot_landscapes,
    plot_learning_curves,
    plot_returns_vs_h,
    plot_throughput,
    plot_wall_time,
)
from harness.report.records import by_group, load_check, load_run, say
from harness.report.swap import commit, stage
from harness.results import atomic_write_bytes, atomic_write_text


def write_bench_report(
    runs: list[Path], checks: list[Path], out_dir: Path, header: dict, stream=None, also=None
) -> list[Path]:
    """Write every table (Markdown, CSV, provenance JSON) and plot of the suite into ``out_dir``, replacing
    the previous report as one set (:mod:`harness.report.swap`); ``also(folder)`` writes further files of
    the set into ``folder`` and returns their paths.

    ``runs``: run directories (config.json, metrics.jsonl, optional eval.json, eval_on_*.json,
    sim2sim_on_*.json, landscape.json); ``checks``: check JSON files; ``header``: ``provenance()`` plus
    ``profile``. Returns the files written; skipped plots are printed on ``stream`` (None: standard output) and
    listed in index.md.
    """
    out_dir = Path(out_dir)
    unique_runs = list(dict.fromkeys(Path(r).resolve() for r in runs))
    records = [rec for rec in (load_run(r, stream) for r in unique_runs) if rec is not None]
    check_records = [c for c in (load_check(Path(p), stream) for p in dict.fromkeys(checks)) if c is not None]
    for key, members in by_group(records).items():
        seeds = Counter(r.seed for r in members)
        repeated = sorted(s for s, n in seeds.items() if n > 1)
        if repeated:
            say(stream, f"group {key} has seed(s) {repeated} more than once (different run directories): all counted")

    staged = stage(out_dir)
    tables = build_tables(records, check_records)
    main = {table.name: table.sections[0].frame for table in tables}  # the plots draw from the tables' numbers
    for table in tables:
        write_table(table, staged, header)

    plots: list[tuple[str, Callable[[Path], Path]]] = [
        ("learning_curves_steps.png", lambda p: plot_learning_curves(records, "env_steps", p)),
        ("learning_curves_wall.png", lambda p: plot_learning_curves(records, "wall_min", p)),
        ("grad_variance_vs_h.png", lambda p: plot_grad_variance(main["grad_variance_vs_h"], p)),
        ("returns_vs_h.png", lambda p: plot_returns_vs_h(main["returns_vs_h"], p)),
        ("lambda_alpha.png", lambda p: plot_lambda_alpha(records, p)),
        ("grad_variance_training.png", lambda p: plot_gradient_variance_curves(judged_curves(records), p)),
        ("wall_time.png", lambda p: plot_wall_time(main["wall_time"], p)),
        ("throughput.png", lambda p: plot_throughput(main["throughput"], p)),
        ("scaling.png", lambda p: plot_scaling(scaling_rows(check_records), p)),
        ("performance_profile.png", lambda p: plot_performance_profiles(records, p)),
    ]
    plotted, skipped, unplotted = [], [], []
    for name, draw in plots:
        try:
            plotted.append(draw(staged / name))
        except NoPlotData as reason:
            skipped.append(f"{name}: {reason}")
            unplotted.append(name)  # a figure from an earlier report would pass for this one
        except Exception as exc:  # a plot must not cost the tables of a finished suite
            skipped.append(f"{name}: failed: {type(exc).__name__}: {exc}")
            unplotted.append(name)
            pyplot()[0].close("all")  # the half-drawn figure
    plotted += copy_filmstrips(records, staged)
    landscape_pngs, landscape_skipped = plot_landscapes(records, staged)
    plotted += landscape_pngs
    skipped += landscape_skipped
    for line in skipped:
        say(stream, f"skipped plot {line}")
    write_index(tables, plotted, skipped, staged, header, headline_lines(tables, records, plotted))
    if also is not None:
        also(staged)
    return commit(out_dir, remove=tuple(unplotted))


def scaling_rows(checks) -> list[dict]:
    """Every env count of every ``scaling`` check, in file order."""
    return [row for check in checks if check.kind == "scaling" for row in check.result.get("rows", [])]


def copy_filmstrips(records, out_dir: Path) -> list[Path]:
    """One filmstrip per task and engine(s) shown (``render`` wrote it into a run's folder; the lowest
    seed's), copied beside the tables as ``filmstrip_TASK_SHOWN.png`` so the report holds it."""
    chosen: dict[tuple[str, str], Path] = {}
    for record in sorted(records, key=lambda r: (r.seed, r.algo)):
        for strip in sorted(record.path.glob("render_*_filmstrip.png")):
            shown = strip.name.removeprefix("render_").removesuffix("_filmstrip.png")
            chosen.setdefault((record.task, shown), strip)
    copied = []
    for (task, shown), strip in sorted(chosen.items()):
        target = out_dir / f"filmstrip_{task}_{shown}.png"
        atomic_write_bytes(target, strip.read_bytes())
        copied.append(target)
    return copied


HEADLINE_PLOTS = ("learning_curves_steps.png", "performance_profile.png", "grad_variance_vs_h.png")


def headline_lines(tables: list[Table], records, plotted: list[Path]) -> list[str]:
    """What a reader takes in first: final returns at each task's headline setting (the one the aggregates
    use), the aggregates across tasks, and the headline plots inline."""
    by_name = {table.name: table for table in tables}
    lines = ["## Headline", ""]
    returns = by_name["returns"].sections[0]
    settings = headline_settings(records)
    if not returns.frame.empty and settings:
        frame = returns.frame
        keep = [
            settings.get((row["task"], row["backend"])) == (row["num_envs"], row["epochs"], row["horizon"])
            for _, row in frame.iterrows()
        ]
        shown = [c for c in returns.columns if c[0] not in ("mean ± std", "initial (mean)", "IQM improvement")]
        shown = [c for c in shown if c[0] not in ("improvement 95% CI", "detectable at 80% power")]
        lines += ["Final evaluation return at each task's headline setting (all settings: `returns.md`):", ""]
        lines += markdown_rows(frame[keep], shown) + [""]
    aggregate = by_name["aggregate"].sections[0]
    if not aggregate.frame.empty:
        lines += ["Across tasks, normalised scores (how: `aggregate.md`):", ""]
        lines += markdown_rows(aggregate.frame, aggregate.columns) + [""]
    names = {p.name for p in plotted}
    for name in HEADLINE_PLOTS:
        if name in names:
            lines += [f"![{PLOT_DESCRIPTIONS[name]}]({name})", ""]
    for name in sorted(n for n in names if n.startswith("filmstrip_")):
        lines += [f"![{filmstrip_description(name)}]({name})", ""]
    return lines if len(lines) > 2 else []


def filmstrip_description(name: str) -> str:
    """``filmstrip_TASK_SHOWN.png`` in words."""
    import tasks

    rest = name.removeprefix("filmstrip_").removesuffix(".png")
    task = next((t for t in sorted(tasks.available(), key=len, reverse=True) if rest.startswith(t + "_")), "")
    shown = rest.removeprefix(task + "_") if task else rest
    where = "both engines side by side" if shown == "compare" else f"on {shown}"
    return f"the final policy{f' on {task}' if task else ''}, {where} (harness render)"


def _other_description(name: str) -> str:
    if name.startswith("filmstrip_"):
        return filmstrip_description(name)
    return "actor-loss landscape, h-step vs TD-lambda (harness.report.plots.plot_landscape)"


def write_index(
    tables: list[Table], plotted: list[Path], skipped: list[str], out_dir: Path, header: dict, headline=()
) -> Path:
    """``index.md``: the headline tables and plots, then what the report holds, and which plots were
    skipped and why."""
    lines = ["# Benchmark report", "", *header_lines(header), "", *headline, "## Tables", ""]
    for table in tables:
        csvs = ", ".join(f"`{table.name}{s.csv_suffix}.csv`" for s in table.sections)
        lines.append(f"- `{table.name}.md` ({csvs}): {table.title}. {table.rests_on}")
    lines += [
        "",
        "CSV provenance: every `NAME.csv` has a `NAME.provenance.json` beside it "
        "(command, commit, time, packages, machine, what the numbers rest on).",
    ]
    lines += ["", "## Plots", ""]
    lines += [f"- `{p.name}`: {PLOT_DESCRIPTIONS.get(p.name) or _other_description(p.name)}" for p in plotted]
    if not plotted:
        lines.append("- none")
    if skipped:
        lines += ["", "Skipped:", "", *[f"- {line}" for line in skipped]]
    return atomic_write_text(out_dir / "index.md", "\n".join(lines) + "\n")
