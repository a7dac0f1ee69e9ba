"""The bench report's figures (PNG, matplotlib's Agg backend, seaborn, one figure per file), each
saved by :func:`harness.figures.save_figure`."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pandas as pd

from harness.figures import NoPlotData, pyplot, save_figure
from harness.formatting import fmt, fmt_rate, is_missing
from harness.report.records import RunRecord, group_runs, metric_column, rank
from harness.report.stats import BOOTSTRAP_SEED
from harness.report.tables import GRAD_STATISTICS, TIME_PARTS

CURVE_POINTS = 100  # points of the common x grid of a learning curve; also the most epochs a lambda curve shows
CURVE_BOOTSTRAP = 200  # seaborn's resamples for a curve's band: a picture, not a table, and 2 CPU cores


# -- plots ----------------------------------------------------------------------------------------
def _algo_palette(algos: Iterable[str]) -> dict[str, tuple]:
    """The same colour for an algorithm in every plot."""
    _, sns = pyplot()
    colours = sns.color_palette("tab10", 10)
    fixed = {"shac": colours[0], "shac-tdfixed": colours[9], "shac-tdadpt": colours[2]}
    fixed |= {"sapo": colours[1], "sapo-tdfixed": colours[3], "sapo-tdadpt": colours[4]}
    spare = iter(colours[5:9] * 10)
    return {algo: fixed.get(algo) or next(spare) for algo in sorted(set(algos), key=rank)}


def _curve_setting(run: RunRecord) -> tuple:
    return (run.horizon, run.num_envs or 0, run.planned_epochs or 0)


def curve_settings(runs: list[RunRecord]) -> dict[tuple[str, str], tuple]:
    """Per (task, backend) the (horizon, num_envs, planned epochs) with the most runs (on a tie the shortest h,
    then the fewest envs and epochs): the one curves show, so a band never mixes runs of different settings."""
    counts = Counter((r.task, r.backend, _curve_setting(r)) for r in runs if r.epochs)
    chosen: dict[tuple[str, str], tuple[tuple, int]] = {}
    for (task, backend, setting), n in counts.items():
        best = chosen.get((task, backend))
        if best is None or (n, [-x for x in setting]) > (best[1], [-x for x in best[0]]):
            chosen[(task, backend)] = (setting, n)
    return {key: setting for key, (setting, _) in sorted(chosen.items())}


CURVE_MEASURES = {
    "per_step": "reward per env step (training windows)",
    "episode": "training episode return (running mean)",
}


def _training_return(metrics: pd.DataFrame) -> tuple[pd.Series, str]:
    """The mean task reward per env step of each training window where logged (every epoch has one, also
    before the first 1000-step episode ends), else (runs older than that metric) the running average of
    finished training episodes or the last finished episode's return; and which of the two it is."""
    per_step = metric_column(metrics, "train_reward_per_step")
    if per_step.notna().any():
        return per_step, "per_step"
    average = metric_column(metrics, "train_episode_return_avg")
    return (average if average.notna().any() else metric_column(metrics, "train_episode_return")), "episode"


def learning_curve_frame(runs: list[RunRecord], x: str) -> pd.DataFrame:
    """Training return of every run on a common x grid per (task, backend, horizon): ``x`` is ``env_steps``
    or ``wall_min``. Only the runs of :func:`curve_settings`; no extrapolation (NaN outside a run's range),
    so the end of a band rests on the runs that got there."""
    settings = curve_settings(runs)
    chosen = [r for r in runs if r.epochs and settings.get((r.task, r.backend)) == _curve_setting(r)]
    rows = []
    for (task, backend, horizon), members in group_runs(chosen, lambda r: (r.task, r.backend, r.horizon)).items():
        series = []
        for run in members:
            xs = (
                metric_column(run.metrics, "env_steps")
                if x == "env_steps"
                else metric_column(run.metrics, "wall_s") / 60.0
            )
            ys, measure = _training_return(run.metrics)
            ok = (xs.notna() & ys.notna()).to_numpy()
            if ok.any():
                series.append((run, xs.to_numpy()[ok], ys.to_numpy()[ok], measure))
        if not series:
            continue
        # one measure per panel: where some runs log the per-step reward, the others (older) are left out
        measures = {m for *_, m in series}
        measure = "per_step" if "per_step" in measures else "episode"
        series = [(run, xs, ys) for run, xs, ys, m in series if m == measure]
        grid = np.linspace(0.0, max(xs.max() for _, xs, _ in series), CURVE_POINTS)
        for run, xs, ys in series:
            inside = (grid >= xs.min()) & (grid <= xs.max())
            for gx, gy in zip(grid[inside], np.interp(grid[inside], xs, ys), strict=True):
                rows.append(
                    {
                        "panel": f"{task} / {backend}, h={horizon}, N={members[0].num_envs}"
                        + ("" if measure == "per_step" else " (episode returns)"),
                        "measure": measure,
                        "task": task,
                        "backend": backend,
                        "algo": run.algo,
                        "seed": run.seed,
                        x: gx,
                        "return": gy,
                    }
                )
    return pd.DataFrame(rows, columns=["panel", "measure", "task", "backend", "algo", "seed", x, "return"])


def plot_learning_curves(runs: list[RunRecord], x: str, path: Path) -> Path:
    plt, sns = pyplot()
    frame = learning_curve_frame(runs, x)
    if frame.empty:
        raise NoPlotData("no run has logged a training reward")
    panels = list(dict.fromkeys(frame["panel"]))
    palette = _algo_palette(frame["algo"])
    grid = sns.relplot(
        data=frame,
        kind="line",
        x=x,
        y="return",
        hue="algo",
        hue_order=list(palette),
        palette=palette,
        col="panel",
        col_order=panels,
        col_wrap=min(3, len(panels)),
        errorbar=("ci", 95),
        n_boot=CURVE_BOOTSTRAP,
        seed=BOOTSTRAP_SEED,
        height=3.6,
        aspect=1.35,
        facet_kws={"sharex": False, "sharey": False},
    )
    grid.set_titles("{col_name}")
    xlabel = "env steps" if x == "env_steps" else "wall-clock training time (min)"
    measures = set(frame["measure"])
    ylabel = CURVE_MEASURES[measures.pop()] if len(measures) == 1 else "training return (see panel titles)"
    grid.set_axis_labels(xlabel, ylabel)
    from matplotlib import ticker

    for ax in grid.axes.flat:
        ax.xaxis.set_major_locator(ticker.MaxNLocator(5))
        if x == "env_steps":
            ax.xaxis.set_major_formatter(ticker.EngFormatter(sep=""))  # 40k, 1M: no overlapping long numbers
    versus = "env steps" if x == "env_steps" else "wall-clock time"
    grid.figure.suptitle(
        f"Training return vs {versus}\nmean over training seeds, 95% bootstrap CI band (each point over the "
        "seeds that reached it);\neach task / backend at its most common horizon",
        y=1.0,
        va="bottom",  # above the panels' own titles, however many lines it has
    )
    return save_figure(grid.figure, path)


def plot_grad_variance(per_h: pd.DataFrame, path: Path) -> Path:
    """Both gradient statistics against h, log-log: per (task, backend, N, planned epochs) one panel of the
    raw variance and one of the scale-free noise-to-signal ratio, one line per algorithm; points are the
    geometric mean over seeds of each seed's median, bars its 95% bootstrap CI. Where some setting was
    swept over h, only swept settings are drawn (the others are one point each and stay in the table)."""
    plt, sns = pyplot()
    finite = np.zeros(len(per_h), dtype=bool)
    for _, stem, _ in GRAD_STATISTICS:
        values = per_h[f"{stem}_gmean"].astype(float)
        finite |= np.isfinite(values) & (values > 0)
    data = per_h[finite]
    if data.empty:
        raise NoPlotData("no finite actor_grad_var or actor_grad_nsr")
    setting = ["task", "backend", "num_envs", "epochs"]
    swept = data.groupby(setting, dropna=False)["horizon"].transform("nunique") > 1
    if swept.any():
        data = data[swept]
    panels = list(dict.fromkeys(zip(*(data[c] for c in setting), strict=True)))
    ncols = len(GRAD_STATISTICS)
    fig, axes = plt.subplots(len(panels), ncols, figsize=(5.6 * ncols, 3.9 * len(panels)), squeeze=False)
    palette = _algo_palette(data["algo"])
    for row_axes, (task, backend, num_envs, planned) in zip(axes, panels, strict=True):
        same = (data["task"] == task) & (data["backend"] == backend)
        same &= _same(data["num_envs"], num_envs) & _same(data["epochs"], planned)
        sub = data[same]
        horizons = sorted(sub["horizon"].unique())
        algos = [a for a in palette if a in set(sub["algo"])]
        for ax, (_, stem, label) in zip(row_axes, GRAD_STATISTICS, strict=True):
            drawn = False
            for i, algo in enumerate(algos):
                line = sub[sub["algo"] == algo].sort_values("horizon")
                point = line[f"{stem}_gmean"].to_numpy(float)
                keep = np.isfinite(point) & (point > 0)
                if not keep.any():
                    continue
                low, high = line[f"{stem}_ci_low"].to_numpy(float), line[f"{stem}_ci_high"].to_numpy(float)
                spread = np.vstack([np.nan_to_num(point - low), np.nan_to_num(high - point)])[:, keep]
                # a slight horizontal offset per algorithm keeps bars at one h apart
                shift = 2.0 ** (0.05 * (i - (len(algos) - 1) / 2))
                ax.errorbar(
                    line["horizon"].to_numpy(float)[keep] * shift,
                    point[keep],
                    yerr=np.clip(spread, 0.0, None),
                    marker="o",
                    capsize=4,
                    label=algo,
                    color=palette[algo],
                )
                drawn = True
            ax.set_xscale("log", base=2)
            # half an octave of room either side: a single h would otherwise be zoomed onto the offsets
            ax.set_xlim(min(horizons) / 2**0.5, max(horizons) * 2**0.5)
            ax.set_xticks(horizons, [str(h) for h in horizons])
            ax.minorticks_off()
            ax.set_title(f"{task} / {backend}, N={fmt(num_envs)}, {fmt(planned)} epochs\n{label}", fontsize="medium")
            ax.set_xlabel("horizon h (steps)")
            if drawn:
                ax.set_yscale("log")
                ax.legend(fontsize="small")
            else:
                ax.text(0.5, 0.5, "not logged by these runs", ha="center", va="center", transform=ax.transAxes)
    fig.suptitle("Actor-gradient statistics vs horizon: geometric mean over seeds of each seed's median, bars = 95% CI")
    fig.tight_layout()
    return save_figure(fig, path)


def plot_returns_vs_h(per_h: pd.DataFrame, path: Path) -> Path:
    """Final eval return against h at one budget (``returns_vs_h_table``): one panel per (task, backend, N,
    budget), one line per algorithm, points the IQM over training seeds and bars its 95% CI."""
    plt, _ = pyplot()
    if per_h.empty:
        raise NoPlotData("no algorithm has evaluated runs at two horizons with one budget")
    setting = ["task", "backend", "num_envs", "budget"]
    panels = list(dict.fromkeys(zip(*(per_h[c] for c in setting), strict=True)))
    fig, axes = plt.subplots(1, len(panels), figsize=(max(7.0, 5.6 * len(panels)), 4.2), squeeze=False)
    palette = _algo_palette(per_h["algo"])
    for ax, (task, backend, num_envs, budget) in zip(axes[0], panels, strict=True):
        same = (per_h["task"] == task) & (per_h["backend"] == backend)
        same &= _same(per_h["num_envs"], num_envs) & _same(per_h["budget"], budget)
        sub = per_h[same]
        horizons = sorted(sub["horizon"].unique())
        algos = [a for a in palette if a in set(sub["algo"])]
        for i, algo in enumerate(algos):
            line = sub[sub["algo"] == algo].sort_values("horizon")
            point = line["iqm_final"].to_numpy(float)
            low, high = line["iqm_ci_low"].to_numpy(float), line["iqm_ci_high"].to_numpy(float)
            spread = np.clip(np.vstack([np.nan_to_num(point - low), np.nan_to_num(high - point)]), 0.0, None)
            shift = 0.6 * (i - (len(algos) - 1) / 2)  # keeps bars at one h apart
            ax.errorbar(
                line["horizon"].to_numpy(float) + shift,
                point,
                yerr=spread,
                marker="o",
                capsize=4,
                label=algo,
                color=palette[algo],
            )
        ax.set_xticks(horizons, [str(h) for h in horizons])
        ax.set_title(f"{task} / {backend}, N={fmt(num_envs)}, {fmt(budget)} env steps per run", fontsize="medium")
        ax.set_xlabel("horizon h (steps)")
        ax.set_ylabel("final eval return (IQM over seeds)")
        ax.legend(fontsize="small")
    fig.suptitle("Final return vs h at one budget (IQM over seeds, bars: 95% CI)")
    fig.tight_layout()
    return save_figure(fig, path)


def _same(column: pd.Series, value) -> pd.Series:
    """Element-wise equality where a missing value equals a missing value (settings of old runs may lack one)."""
    return column.isna() if is_missing(value) else column == value


def lambda_alpha_frame(runs: list[RunRecord]) -> pd.DataFrame:
    """lambda (every algorithm) and alpha (SAPO's temperature; SHAC has none) per epoch, long format, thinned to
    about CURVE_POINTS epochs per task (every k-th epoch, the same ones for every seed so they average)."""
    settings = curve_settings(runs)
    chosen = [r for r in runs if r.epochs and settings.get((r.task, r.backend)) == _curve_setting(r)]
    rows = []
    for (task,), members in group_runs(chosen, lambda r: (r.task,)).items():
        stride = max(1, math.ceil(max(r.epochs for r in members) / CURVE_POINTS))
        for run in members:
            epochs = metric_column(run.metrics, "epoch")
            keep = ((epochs % stride) == 0) | (epochs == epochs.max())
            quantities = [("lambda", "lam")] + ([("alpha (SAPO temperature)", "alpha")] if run.base == "sapo" else [])
            for label, name in quantities:
                values = metric_column(run.metrics, name)
                for epoch, value in zip(epochs[keep], values[keep], strict=True):
                    if np.isfinite(value):
                        panel = f"{task} / {run.backend}, h={run.horizon}, N={run.num_envs}"
                        rows.append(
                            {"panel": panel, "task": task, "backend": run.backend, "algo": run.algo, "seed": run.seed}
                            | {"quantity": label, "epoch": int(epoch), "value": float(value)}
                        )
    return pd.DataFrame(rows, columns=["panel", "task", "backend", "algo", "seed", "quantity", "epoch", "value"])


def plot_lambda_alpha(runs: list[RunRecord], path: Path) -> Path:
    plt, sns = pyplot()
    frame = lambda_alpha_frame(runs)
    if frame.empty:
        raise NoPlotData("no run has logged lambda")
    palette = _algo_palette(frame["algo"])
    several_backends = frame["backend"].nunique() > 1
    grid = sns.relplot(
        data=frame,
        kind="line",
        x="epoch",
        y="value",
        hue="algo",
        hue_order=list(palette),
        palette=palette,
        style="backend" if several_backends else None,
        row="quantity",
        row_order=[q for q in ("lambda", "alpha (SAPO temperature)") if q in set(frame["quantity"])],
        col="task",
        errorbar=("ci", 95),
        n_boot=CURVE_BOOTSTRAP,
        seed=BOOTSTRAP_SEED,
        height=3.2,
        aspect=1.4,
        facet_kws={"sharex": "col", "sharey": False},
    )
    grid.set_titles("{row_name} | {col_name}")
    for ax in grid.axes.flat:
        if not ax.lines:
            ax.text(0.5, 0.5, "no SAPO run", transform=ax.transAxes, ha="center", va="center", color="grey")
    grid.set_axis_labels("epoch", "value (dimensionless)")
    grid.figure.suptitle(
        "TD lambda and SAPO temperature alpha per epoch\nmean over training seeds, 95% bootstrap CI band "
        "(each point over the seeds that reached it);\n"
        "each task / backend at its most common horizon",
        y=1.0,
        va="bottom",
    )
    return save_figure(grid.figure, path)


def wall_time_split_frame(wall: pd.DataFrame) -> pd.DataFrame:
    """Seconds per epoch of every time part, mean over seeds, per (task, backend, algo, horizon)."""
    if wall.empty:
        return pd.DataFrame()
    per_epoch = wall.copy()
    parts = [stem for stem, _, _ in TIME_PARTS]
    for stem in parts:
        per_epoch[stem] = per_epoch[f"{stem}_min"] * 60.0 / per_epoch["epochs"]
    return per_epoch.groupby(["task", "backend", "algo", "horizon"], sort=False)[parts].mean().reset_index()


def plot_wall_time(wall: pd.DataFrame, path: Path) -> Path:
    """Stacked bars: seconds per epoch of each time part per (backend, algo, h), one panel per task."""
    plt, sns = pyplot()
    split = wall_time_split_frame(wall)
    if split.empty:
        raise NoPlotData("no run has metrics")
    parts = [(stem, label) for stem, label, _ in TIME_PARTS if (split[stem].fillna(0.0) > 0).any()]
    colours = dict(zip([s for s, _, _ in TIME_PARTS], sns.color_palette("Set2", len(TIME_PARTS)), strict=True))
    tasks = list(dict.fromkeys(split["task"]))
    widths = [max(2, (split["task"] == t).sum()) for t in tasks]
    fig, axes = plt.subplots(1, len(tasks), figsize=(1.3 * sum(widths) + 2.5, 4.6), width_ratios=widths, squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        sub = split[split["task"] == task]
        labels = [f"{a}\n{b} h{h}" for a, b, h in zip(sub["algo"], sub["backend"], sub["horizon"], strict=True)]
        bottom = np.zeros(len(sub))
        for stem, label in parts:
            values = sub[stem].fillna(0.0).to_numpy()
            ax.bar(labels, values, bottom=bottom, label=label, color=colours[stem], width=0.7)
            bottom += values
        ax.set_title(task)
        ax.set_ylabel("seconds per epoch (mean over seeds)")
        ax.tick_params(axis="x", labelsize=8)
    handles, names = axes[0][0].get_legend_handles_labels()
    fig.legend(handles[::-1], names[::-1], loc="center left", bbox_to_anchor=(1.0, 0.5), title="time part")
    fig.suptitle("Where an epoch's wall time goes (sum over epochs / epochs, mean over training seeds)")
    fig.tight_layout()
    return save_figure(fig, path)


def throughput_setups(table: pd.DataFrame) -> list[str]:
    """An x label per throughput row: task, envs and horizon, plus what tells apart two files measuring the
    same (backend, task, envs, h) (e.g. ``central`` of ``throughput_mujoco_warp_ant_central.json``), so that
    seaborn draws them as two bars instead of averaging them."""
    labels = [f"{r['task']}\n{fmt(r['num_envs'])} envs, h={fmt(r['horizon'])}" for _, r in table.iterrows()]
    keys = list(zip(table["backend"], labels, strict=True))
    repeated = {k for k, n in Counter(keys).items() if n > 1}
    for i, (_, r) in enumerate(table.iterrows()):
        if keys[i] in repeated:
            words = Path(str(r["file"])).stem.split("_")
            known = {"throughput", *str(r["backend"]).split("_"), *str(r["task"]).split("_")}
            labels[i] += "\n" + ("_".join(w for w in words if w not in known) or "default")
    return labels


def plot_throughput(table: pd.DataFrame, path: Path) -> Path:
    """env-steps/s forward and forward+backward (adapter and bare engine) per backend x task, log y."""
    plt, sns = pyplot()
    measures = [
        ("forward_steps_per_s", "forward"),
        ("forward_backward_steps_per_s", "forward+backward"),
        ("bare_forward_steps_per_s", "bare engine forward"),
        ("bare_engine_steps_per_s", "bare engine forward+backward"),
    ]
    rows = []
    setups = throughput_setups(table)
    for (_, r), setup in zip(table.iterrows(), setups, strict=True):
        for column, label in measures:
            value = pd.to_numeric(r[column], errors="coerce")
            if np.isfinite(value) and value > 0:
                estimated = column == "forward_backward_steps_per_s" and bool(r["forward_backward_estimated"])
                rows.append(
                    {"backend": r["backend"], "setup": setup, "measure": label + (" (est.)" if estimated else "")}
                    | {"env-steps/s": float(value)}
                )
    frame = pd.DataFrame(rows)
    if frame.empty:
        raise NoPlotData("no throughput check")
    widest = int(frame.groupby("backend")["setup"].nunique().max())
    grid = sns.catplot(
        data=frame,
        kind="bar",
        x="setup",
        y="env-steps/s",
        hue="measure",
        col="backend",
        col_order=sorted(frame["backend"].unique(), key=rank),
        col_wrap=1 if widest > 3 else None,  # many setups: backends one above the other, not a strip
        sharex=False,
        height=4.2,
        aspect=max(1.3, 0.5 * widest),
        palette="muted",
    )
    # log bars start at the axis bottom: a third of the slowest rate keeps the shortest bar visible
    grid.set(yscale="log", ylim=(frame["env-steps/s"].min() / 3.0, None))
    grid.set_titles("{col_name}")
    grid.set_axis_labels("task (envs, horizon)", "env-steps per second (log scale)")
    for ax in grid.axes.flat:
        ax.tick_params(axis="x", labelsize=8)
        for container in ax.containers:
            ax.bar_label(container, labels=[fmt_rate(v) for v in container.datavalues], fontsize=7, padding=1)
    grid.figure.suptitle("Throughput per backend and task (throughput checks)", y=1.0, va="bottom")
    return save_figure(grid.figure, path)


def plot_landscape(result: dict, path) -> Path:
    """Both surfaces side by side as filled contours (own colour scale per panel), roughness in the titles.

    x is the first direction's coefficient (``alphas``), y the second's (``betas``); the cross marks
    the trained policy. Non-finite points are left blank. Written atomically (temporary file, rename).
    """
    plt, sns = pyplot()

    alphas, betas = np.asarray(result["alphas"]), np.asarray(result["betas"])
    labels = {
        "h_step": "h-step return (eq. 9)",
        "td_lambda": f"TD-lambda return (eq. 12), lambda={result['lambda']:.3f}",
    }
    sns.set_theme(style="white")
    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for ax, name in zip(axes, labels, strict=True):
        # surfaces are indexed [alpha, beta]; contourf wants [y, x]
        z = np.ma.masked_invalid(np.asarray(result["losses"][name], dtype=np.float64).T)
        filled = ax.contourf(alphas, betas, z, levels=30, cmap="viridis")
        ax.contour(alphas, betas, z, levels=15, colors="k", linewidths=0.3, alpha=0.5)
        fig.colorbar(filled, ax=ax, label="actor loss")
        ax.plot([0.0], [0.0], marker="x", color="red", markersize=8)
        r = result["roughness"][name]
        ax.set_title(f"{labels[name]}\nroughness {r:.3f}" if r is not None else f"{labels[name]}\nroughness n/a")
        ax.set_xlabel("alpha (direction 1)")
        ax.set_ylabel("beta (direction 2)")
        ax.set_aspect("equal")
    fig.suptitle(
        f"{result['task']} / {result['backend']} / {result['algo']}: {result['grid']}x{result['grid']} grid, "
        f"{result['num_envs']} envs, h={result['horizon']}"
    )
    fig.tight_layout()
    return save_figure(fig, path)


def plot_landscapes(runs: list[RunRecord], out_dir: Path) -> tuple[list[Path], list[str]]:
    """One PNG per run's landscape.json (:func:`plot_landscape`)."""
    landscapes = [r for r in runs if r.landscape is not None]
    if not landscapes:
        return [], []
    written, skipped = [], []
    for run in landscapes:
        name = f"landscape_{run.task}_{run.backend}_{run.algo}_h{run.horizon}_s{run.seed}.png"
        try:
            written.append(Path(plot_landscape(run.landscape, out_dir / name)))
        except Exception as exc:
            skipped.append(f"{name}: {type(exc).__name__}: {exc}")
    return written, skipped


#: what index.md says of each figure of the bench report
PLOT_DESCRIPTIONS = {
    "learning_curves_steps.png": "training return vs env steps, per task x backend at its most common horizon",
    "learning_curves_wall.png": "training return vs wall-clock minutes, same runs",
    "grad_variance_vs_h.png": "raw and scale-free actor-gradient statistics vs h, seeds' 95% CIs, log-log",
    "returns_vs_h.png": "final eval return vs h at one budget, IQM with 95% CI over training seeds",
    "lambda_alpha.png": "lambda and SAPO's alpha per epoch, per task",
    "grad_variance_training.png": "Fig. 2: actor-gradient variance over training (EMA), mean and min-max over seeds",
    "wall_time.png": "seconds per epoch split into simulation, backward and updates",
    "throughput.png": "env-steps/s forward and forward+backward per backend x task, log y",
    "scaling.png": "env-steps/s forward and forward+backward against the number of envs, log-log",
    "performance_profile.png": "rliable performance profiles of normalised scores across tasks, per backend",
}
