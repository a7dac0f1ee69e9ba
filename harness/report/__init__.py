"""Reports: the tables (Markdown and CSV) and seaborn plots of the benchmark suite (``python -m harness bench``)
and of the ``report`` verb (``python -m harness report``, :func:`write_report`).

:func:`write_bench_report` reads the suite's run directories and check files and writes into one folder:

Tables, each as ``NAME.md`` (title, provenance paragraph, what the numbers rest on, notes, table) and
``NAME.csv`` (plain comma-separated values, one header line, no comment lines, so any CSV reader takes it
as it is) with a sibling ``NAME.provenance.json``: ``{"table", "csv", "markdown", "title", "rests_on",
"notes", "columns", "input_commits", "provenance"}`` where ``provenance`` is the ``header`` given to
:func:`write_bench_report` (command, commit, UTC time, packages, machine, profile). A table with a second
part writes it as ``NAME_PART.csv`` (with its own ``.provenance.json``) and as a second section of ``NAME.md``.

* ``returns``: final evaluation return per (task, backend, algo, horizon): IQM over training seeds with a
  95% percentile-bootstrap CI, mean and std, initial return, and the IQM improvement over the base algorithm
  (``shac-tdadpt`` -> ``shac``) with a two-sample bootstrap CI (:func:`returns_table`);
* ``grad_variance_vs_h`` (+ ``_growth``): the actor-gradient variance against the horizon;
* ``returns_vs_h``: the final return against the horizon at one budget of env steps per run;
* ``wall_time``: the time split of every run; ``throughput``: env-steps/s of the throughput checks;
* ``backends``: one algorithm x task x horizon on every backend side by side;
* ``sim_to_sim`` (+ ``_mean``): a policy evaluated on another backend than it trained on;
* ``landscape``: the roughness of the h-step and TD-lambda actor losses (``harness/checks/landscape.py``);
* ``checks``: every check file (gradcheck, throughput, crosscheck) in one line each.

Plots (PNG, matplotlib's Agg backend, one figure per file): ``learning_curves_steps``,
``learning_curves_wall``, ``grad_variance_vs_h``, ``returns_vs_h``, ``lambda_alpha``, ``wall_time``,
``throughput``, ``scaling`` (every scaling check's curves, log-log), ``performance_profile`` and one
``landscape_*.png`` per landscape (``harness.report.plots.plot_landscape``, when that
module imports).
A plot without data is skipped (and a stale file of that name removed); ``index.md`` lists what was
written and what was skipped, and why.

Statistics (:mod:`harness.report.stats`): the interquartile mean over training seeds with a 95%
percentile-bootstrap CI, for the bench report and the ``report`` verb alike.

Modules, each one responsibility:

* ``records``: reading run directories and check files (:class:`RunRecord`, :class:`CheckRecord`), grouping;
* ``stats``: every statistic (IQM, bootstrap CIs, geometric means, medians, statistical power);
* ``tables``: the bench report's tables as pure functions of the records;
* ``documents``: Markdown and CSV writing (cells by :func:`harness.formatting.fmt`), provenance, one
  ``*_document`` per table;
* ``plots``: the report's figures (saved through :func:`harness.figures.save_figure`);
* ``suite``: :func:`write_bench_report` and ``index.md``;
* ``compare``: the ``report`` verb's per-run and per-algorithm tables and curves.
"""

from harness.report.compare import write_report
from harness.report.suite import write_bench_report, write_index

__all__ = ["write_bench_report", "write_index", "write_report"]
