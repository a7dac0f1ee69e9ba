"""The one progress display: a line of text per event, rewritten in place on a terminal, one line per
event elsewhere (a log, a pipe), and the one way a duration is written."""

from __future__ import annotations

import sys


def duration(seconds: float) -> str:
    """``seconds`` as s, min, h or days, whichever reads best."""
    for unit, size in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= 1.5 * size:
            return f"{seconds / size:.1f} {unit}"
    return f"{seconds:.1f} s" if seconds < 10 else f"{seconds:.0f} s"


class ProgressLine:
    """Shows progress lines on ``stream``: on a terminal each replaces the last (``final`` ends it with a
    newline); elsewhere every ``every``-th line and every final one is written as a line of its own,
    so a log holds one event per line."""

    def __init__(self, stream=None, every: int = 1):
        self.stream = stream if stream is not None else sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every, self.count = max(1, every), 0

    def show(self, text: str, final: bool = False) -> None:
        self.count += 1
        if self.tty:
            self.stream.write("\r\033[K" + text + ("\n" if final else ""))
        elif final or self.count % self.every == 0:
            self.stream.write(text + "\n")
        else:
            return
        self.stream.flush()
