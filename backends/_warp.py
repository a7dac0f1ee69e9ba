"""What every Warp-based adapter shares: a quiet Warp start-up, the torch -> Warp device name, and
the reading of 0/1 backend options.

Warp's native library prints "Warp CUDA warning: Could not find or load the NVIDIA CUDA driver" to
the process's stderr (file descriptor 2, from C) whenever it starts on a machine without a GPU
driver: on the CPU machines this benchmark runs on, that line is noise that turns every one-line
``error:`` into two. :func:`_init_quietly` starts Warp with fd 2 captured and re-emits everything
Warp printed except exactly that line, so real warnings still show.
"""

from __future__ import annotations

import os
import sys
import tempfile

import torch
import warp as wp

from backends.contract import BackendError

NO_DRIVER_LINE = "Could not find or load the NVIDIA CUDA driver"

wp.config.quiet = True  # no per-module compile lines
wp.config.log_level = wp.LOG_WARNING  # no start-up banner; warnings still show


def _init_quietly() -> None:
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            wp.init()
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
        captured.seek(0)
        text = captured.read().decode("utf-8", errors="replace")
    kept = without_driver_line(text)
    if kept:
        sys.stderr.write(kept)


def without_driver_line(text: str) -> str:
    """``text`` less the no-driver line (and only that line)."""
    return "".join(line for line in text.splitlines(keepends=True) if NO_DRIVER_LINE not in line)


_init_quietly()


def warp_device(device: torch.device) -> str:
    """Warp's name for a torch device (``cpu`` or ``cuda:N``)."""
    if device.type == "cpu":
        return "cpu"
    return f"cuda:{device.index or 0}"


def option_flag(options: dict, name: str, default: bool, backend: str) -> bool:
    """A 0/1 backend option: ``options[name]`` if given, else ``default``; anything else is refused."""
    value = options.get(name, int(default))
    if value in (0, 1, "true", "false"):  # CLI: 0/1 arrive as ints, true/false as strings; TOML booleans equal 0/1
        return value in (1, "true")
    raise BackendError(f"{backend} option {name} must be 0 or 1, got {value!r}")
