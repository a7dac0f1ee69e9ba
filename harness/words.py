"""Reading a command's words, for the parser and for everything that reads a recorded command line
back (the suite addresses a check by the physics its arguments name; the checks table prints it):
``KEY=VALUE`` options and the preset and adapter options a command names; and the value type of
every flag (argparse ``type=``), so a check kind declares its own flags (:mod:`harness.checks.kinds`)
with the same types the shared flags have."""

from __future__ import annotations

import argparse
import math

from harness.bounds import MAX_SPAN


def parse_option(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` with VALUE read as an int, a float or else a string."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    for kind in (int, float):
        try:
            return key.strip(), kind(value)
        except ValueError:
            pass
    return key.strip(), value.strip()


def physics_words(words: list[str]) -> tuple[str | None, list[str]]:
    """The physics a command's words name besides the defaults: the ``--preset`` value (None when
    absent) and every ``--backend-option`` ``KEY=VALUE`` as written. The suite addresses a check by them
    and the checks table prints them, so both read them here."""
    preset = words[words.index("--preset") + 1] if "--preset" in words[:-1] else None
    options = [value for flag, value in zip(words, words[1:], strict=False) if flag == "--backend-option"]
    return preset, options


# -- value types of flags ------------------------------------------------------------------------------


def integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def int_in(low: int, high: int):
    """An integer flag in [low, high] (:mod:`harness.bounds`; a spec's keys have the same limits), so
    that a value the types or the machine cannot hold is refused before any work."""

    def parse(text: str) -> int:
        value = integer(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"expected an integer in [{low}, {high}], got {value}")
        return value

    parse.__name__ = "integer"  # argparse names the type in its messages
    parse.bounds = (low, high)
    return parse


def one_line(text: str) -> str:
    """A name or path given on the command line: not empty (an empty value would read as "not given"),
    one line, no control characters."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a non-empty value, got ''")
    if any(ord(ch) < 32 for ch in text):
        raise argparse.ArgumentTypeError(f"expected one line without control characters, got {text!r}")
    return text


def finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def positive_float(text: str) -> float:
    value = finite(text) if text.lower() not in ("nan", "inf", "-inf") else float("nan")
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"expected a positive finite number, got {text!r}")
    return value


def positive_float_up_to(high: float):
    """A number flag in (0, high]: positive, finite, and no larger than a bound of the machine or of
    what the number means."""

    def parse(text: str) -> float:
        value = positive_float(text)
        if value > high:
            raise argparse.ArgumentTypeError(f"expected a number in (0, {high:g}], got {text!r}")
        return value

    parse.__name__ = "number"
    parse.bounds = (0.0, high)
    return parse


#: a landscape's half-width: beyond :data:`MAX_SPAN` every point is NaN
span = positive_float_up_to(MAX_SPAN)


def boolean(text: str) -> bool:
    if text.lower() in ("1", "true", "yes"):
        return True
    if text.lower() in ("0", "false", "no"):
        return False
    raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")


def optional_float(text: str) -> float | None:
    return None if text.lower() == "none" else finite(text)
