"""Reading a command's words, for the parser and for everything that reads a recorded command line
back (the suite addresses a check by the physics its arguments name; the checks table prints it):
``KEY=VALUE`` options and the preset and adapter options a command names."""

from __future__ import annotations

import argparse


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
