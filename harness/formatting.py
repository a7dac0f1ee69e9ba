"""How the harness writes a number for people to read: :func:`fmt` is the one cell formatter of every
Markdown table (the bench report's and the ``report`` verb's), the others build on it or write what a
table's prose needs (a percentage, an interval, a count, a range, a rate on a plot's bars)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import pandas as pd


def is_missing(value) -> bool:
    """None, NaN (any float type), pd.NA or NaT."""
    try:
        return value is None or bool(pd.isna(value))
    except (TypeError, ValueError):  # a list or array cell
        return False


def fmt(value) -> str:
    """A table cell: n/a for missing, yes/no for booleans, about 4 significant digits for floats."""
    if is_missing(value):
        return "n/a"
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        magnitude = abs(float(value))
        if magnitude == 0.0:
            return "0"
        if magnitude >= 1e6 or magnitude < 1e-3:
            return f"{value:.3g}"
        return f"{value:.1f}" if magnitude >= 100 else f"{value:.3g}" if magnitude < 1 else f"{value:.2f}"
    return str(value)


def fmt_ci(low, high) -> str:
    """An interval ``[low, high]``; n/a when a bound is missing."""
    return "n/a" if is_missing(low) or is_missing(high) else f"[{fmt(low)}, {fmt(high)}]"


def fmt_verdict(passed) -> str:
    """A check's verdict: PASS, FAIL or n/a (the check gives none)."""
    return "n/a" if is_missing(passed) else ("PASS" if passed else "FAIL")


def fmt_pct(value) -> str:
    """A fraction as a whole percentage: 0.25 -> 25%."""
    return "n/a" if is_missing(value) else f"{100.0 * value:.0f}%"


def fmt_count(n: int, noun: str) -> str:
    """``1 run``, ``2 runs``."""
    return f"{n} {noun}" + ("" if n == 1 else "s")


def fmt_range(values: Iterable) -> str:
    """The one value all share, else ``min-max``, with thousands separators."""
    distinct = sorted(set(values))
    if not distinct:
        return "n/a"
    return f"{distinct[0]:,}" if len(distinct) == 1 else f"{distinct[0]:,}-{distinct[-1]:,}"


def fmt_rate(value: float) -> str:
    """A rate on a bar: whole numbers with thousands separators from 100 up, else 3 significant digits."""
    return f"{value:,.0f}" if value >= 100 else f"{value:.3g}"


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> list[str]:
    """The lines of a Markdown table: every table the harness writes, the report's and each check's own,
    goes through here, so a cell's ``|`` never splits a row."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell).replace("|", "/") for cell in row) + " |" for row in rows]
    return lines
