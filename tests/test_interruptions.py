"""Runs are never lost: real training processes killed by SIGKILL, SIGTERM and SIGINT at random moments
(during start-up, mid-epoch, inside checkpoint and metrics writes) leave folders that `train --resume`
continues into exactly the uninterrupted run. Uses the point-mass plug-in (tox installs it): fast epochs."""

from __future__ import annotations

import json
import os
import random
import re
import signal
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

import pytest
import torch

import backends
import harness
from harness.run.train import WALL_TIME_FIELDS

pytestmark = pytest.mark.skipif("pointmass" not in backends.available(), reason="the point-mass plug-in is absent")

EPOCHS = 16  # enough epochs that the kills land in training, also on a fast idle machine
TRAIN = ["--task", "pointmass", "--backend", "pointmass", "--algo", "shac-tdadpt", "--num-envs", "8"]
TRAIN += ["--horizon", "8", "--critic-iterations", "1", "--seed", "4"]
WALL = set(WALL_TIME_FIELDS)


def _env(delay: float = 0.0) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    if delay:
        env["DIFFSIM_BENCH_TEST_WRITE_DELAY"] = str(delay)  # every write stays half-done this long
    return env


def _start(args: list[str], delay: float) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "harness", *args],
        env=_env(delay),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def _rows(run: Path) -> list[dict]:
    lines = (run / "metrics.jsonl").read_text().splitlines() if (run / "metrics.jsonl").exists() else []
    rows = []
    for i, line in enumerate(lines):
        try:
            rows.append(json.loads(line))
        except ValueError:
            assert i == len(lines) - 1, f"corrupt metrics line {i + 1} that is not the last"
    return rows


def _check_folder(run: Path) -> None:
    """0 corrupt files: config.json and checkpoints load; metrics rows parse (a torn last line aside);
    0 completed epochs lost beyond the last checkpoint."""
    if (run / "config.json").exists():
        json.loads((run / "config.json").read_text())
    epoch = None
    for name in ("checkpoint_init.pt", "checkpoint.pt"):
        if (run / name).exists():
            epoch = torch.load(run / name, map_location="cpu", weights_only=False)["epoch"]
    rows = _rows(run)
    if epoch is not None:
        assert len(rows) <= epoch + 1, (len(rows), epoch)  # at most the epoch whose checkpoint the kill cut


def _hit_before_our_handlers(err: str) -> bool:
    """Whether a signal's output is the interpreter's own, from before ``harness/__main__.py`` installed
    the handlers: a "Fatal Python error" in site's start-up, or Python's default KeyboardInterrupt raised
    in start-up code (frozen or standard-library frames, the empty ``harness/__init__.py``, and
    ``harness/__main__.py`` above the handlers). A KeyboardInterrupt from anywhere later is our bug."""
    if "init_import_site" in err:
        return True
    if not err.rstrip().endswith("KeyboardInterrupt"):
        return False
    main_lines = (Path(harness.__file__).parent / "__main__.py").read_text().splitlines()
    handlers = next(i for i, line in enumerate(main_lines, 1) if line.startswith("for _signum in"))
    stdlib = Path(sysconfig.get_paths()["stdlib"]).resolve()
    for name, line in re.findall(r'File "([^"]+)", line (\d+)', err):
        path = Path(name)
        if not path.is_absolute() or stdlib in path.resolve().parents:
            continue  # frozen, or the standard library's
        if path.parts[-2:] == ("harness", "__init__.py"):
            continue
        if path.parts[-2:] == ("harness", "__main__.py") and int(line) < handlers:
            continue
        return False
    return True


def _wait_for_a_random_moment(proc: subprocess.Popen, run: Path, rng: random.Random) -> None:
    """A third of the kills land anywhere from start-up on; the rest a random time into a random
    later epoch (with every write held half-done for 50 ms, many land inside a write)."""
    if rng.random() < 0.3:
        time.sleep(rng.uniform(0.3, 4.0))
        return
    target = len(_rows(run)) + rng.randint(0, 3)
    deadline = time.time() + 120
    while proc.poll() is None and len(_rows(run)) < target and time.time() < deadline:
        time.sleep(0.01)
    time.sleep(rng.uniform(0.0, 0.3))


def test_killed_runs_resume_into_the_uninterrupted_run(tmp_path):
    full = tmp_path / "full"
    done = subprocess.run(
        [sys.executable, "-m", "harness", "train", *TRAIN, "--epochs", str(EPOCHS), "--out", str(full)],
        env=_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    expected = [{k: v for k, v in r.items() if k not in WALL} for r in _rows(full)]
    assert len(expected) == EPOCHS

    rng = random.Random(0)
    kinds = [signal.SIGKILL, signal.SIGTERM, signal.SIGINT]
    kills = 0
    for folder in range(3):
        run = tmp_path / f"cut{folder}"
        command = ["train", *TRAIN, "--epochs", str(EPOCHS), "--out", str(run)]
        for attempt in range(40):
            proc = _start(command, delay=0.05)
            killed = False
            if attempt < 5:  # up to five kills per folder, then let it finish
                _wait_for_a_random_moment(proc, run, rng)
                if proc.poll() is None:
                    sig = kinds[kills % len(kinds)]
                    state = (
                        sig.name,
                        (run / "config.json").exists(),
                        (run / "checkpoint.pt").exists(),
                        len(_rows(run)),
                    )
                    proc.send_signal(sig)
                    kills += 1
                    killed = True
                    print("kill", folder, attempt, *state)
            _, err = proc.communicate(timeout=300)
            if killed:
                assert proc.returncode != 0 or "stopped" in err or len(_rows(run)) == EPOCHS
                # mid-training: our handlers, one line, no traceback. A resumed process (rows already
                # written) can still be hit before harness/__main__.py has installed them, on a loaded machine
                if sig != signal.SIGKILL and state[3] > 0 and not _hit_before_our_handlers(err):
                    assert "Traceback" not in err, err
            else:
                assert proc.returncode == 0, err
            _check_folder(run)
            if len(_rows(run)) == EPOCHS and (run / "checkpoint.pt").exists() and proc.returncode == 0:
                break
            # a folder with a config.json must resume; one without (killed during start-up) starts afresh
            command = ["train", "--resume", str(run)] if (run / "config.json").exists() else command
        got = [{k: v for k, v in r.items() if k not in WALL} for r in _rows(run)]
        assert got == expected, f"folder {folder} diverged from the uninterrupted run"
    assert kills >= 10, kills


def test_a_signal_stops_at_an_epoch_boundary_with_a_checkpoint(tmp_path):
    run = tmp_path / "run"
    proc = _start(["train", *TRAIN, "--epochs", "200", "--out", str(run)], delay=0.0)
    deadline = time.time() + 120
    while time.time() < deadline and len(_rows(run)) < 3:
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert err.strip().splitlines()[-1].startswith("stopped: SIGTERM: stopped at epoch"), err
    epoch = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=False)["epoch"]
    assert epoch == len(_rows(run))  # the checkpoint is the boundary after the last row, nothing half-done


def test_a_resume_removes_the_temporary_file_of_an_interrupted_checkpoint_write(tmp_path):
    """A SIGKILL during a checkpoint write leaves ``checkpoint.pt.PID.tmp``; the checkpoint it was
    replacing is intact, and the resume removes the orphan (its writer is gone), nothing else."""
    from harness.cli import main

    run = tmp_path / "run"
    assert main(["train", *TRAIN, "--epochs", "1", "--out", str(run)]) == 0
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()  # a pid that has finished: its temporary file is an orphan
    orphan = run / f"checkpoint.pt.{dead.pid}.tmp"
    orphan.write_bytes(b"")
    live = run / f"checkpoint.pt.{os.getppid()}.tmp"  # a writer still running (not this process): left alone
    live.write_bytes(b"")
    assert main(["train", "--resume", str(run), "--epochs", "2"]) == 0
    assert not orphan.exists() and live.exists()
    assert len(_rows(run)) == 2
