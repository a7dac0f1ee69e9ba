"""A run's per-epoch scalars as TensorBoard events, beside its metrics.jsonl: ``RUN/tensorboard/``.

``tensorboard --logdir RUN`` (or a folder of runs) shows them while the run trains. Every number of a
metrics row becomes a scalar at step = epoch, grouped by what it measures: ``train/`` (rewards,
returns, episode lengths), ``loss/``, ``gradient/`` (norms, the raw and scale-free variance
statistics, the effective reward weight, skipped updates), ``adaptation/`` (lambda, SAPO's alpha and
entropy), ``time/`` (seconds per part of an epoch), ``progress/`` (env steps, the rest). metrics.jsonl
stays the record the harness reads; the events are a view of it. A resumed run purges the events from
its checkpoint's epoch on, as it truncates its metrics, so a curve never holds an epoch twice.
"""

from __future__ import annotations

import math
from pathlib import Path

FOLDER = "tensorboard"


def tag(name: str) -> str:
    """The TensorBoard tag of a metrics field."""
    if name.startswith("actor_grad") or name in (
        "actor_reward_weight",
        "actor_update_skipped",
        "critic_updates_skipped",
    ):
        group = "gradient"
    elif name.endswith("_loss"):
        group = "loss"
    elif name.endswith("_s"):
        group = "time"
    elif name.startswith("train_") or name == "finished_episodes":
        group = "train"
    elif name in ("lam", "alpha", "entropy"):
        group = "adaptation"
    else:
        group = "progress"
    return f"{group}/{name}"


class EpochScalars:
    """Writes each epoch's metrics row as scalars (:func:`tag`), from ``first_epoch`` on."""

    def __init__(self, run_dir: Path, first_epoch: int = 0):
        from torch.utils.tensorboard import SummaryWriter

        self.writer = SummaryWriter(str(Path(run_dir) / FOLDER), purge_step=first_epoch or None)

    def write(self, row: dict) -> None:
        step = int(row["epoch"])
        for name, value in row.items():
            if name == "epoch" or value is None or isinstance(value, str):
                continue
            value = float(value)
            if math.isfinite(value):
                self.writer.add_scalar(tag(name), value, step)
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()
