"""What every Warp-based adapter shares: quiet Warp start-up and the torch -> Warp device name."""

from __future__ import annotations

import torch
import warp as wp

wp.config.quiet = True  # no per-module compile lines
wp.config.log_level = wp.LOG_WARNING  # no start-up banner; warnings still show


def warp_device(device: torch.device) -> str:
    """Warp's name for a torch device (``cpu`` or ``cuda:N``)."""
    if device.type == "cpu":
        return "cpu"
    return f"cuda:{device.index or 0}"
