"""The harness's figures' common ground: matplotlib on the Agg backend with the report's seaborn theme,
and the one figure saver (:func:`save_figure`) through which every PNG the harness makes is written
(the bench report's, the ``report`` verb's, ``landscape``, ``parity``, ``scaling``)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


class NoPlotData(Exception):
    """A plot has nothing to show; the message says why."""


def pyplot():
    """matplotlib's pyplot on the Agg backend and seaborn with the report's theme."""
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt
    import seaborn as sns

    sns.set_theme(style="whitegrid", context="notebook")
    return plt, sns


def save_figure(fig, path: str | Path) -> Path:
    """Write ``fig`` as a PNG (100 dpi, cropped to what is drawn) through a temporary file in the same
    folder and a rename, so an interruption never leaves half an image; the figure is closed."""
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".png")
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=100, bbox_inches="tight")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    finally:
        plt.close(fig)
    return path
