"""A report's files replaced as one set: a reader of the folder sees the previous complete set or the new
one, never the new tables beside the previous plots.

The new set is written into a staging folder of this process's own (``.report-staging-PID``) beside the
old one; nothing of the old set changes until every new file is whole. Then, holding the folder's lock
(two suites that share a store report one at a time), a journal (``.report-swap-PID.json``) names the
moves and removals, the files move into place (``os.replace`` each, with SIGINT and SIGTERM held back
for the few milliseconds it takes) and the journal goes. A process killed outright mid-swap leaves its
journal, and the next report (:func:`recover`) finishes that swap before anything else; one killed
while staging leaves an unfinished stage, which is discarded, so the previous set stands. :data:`SET`
records the names of the set in place, so a file the new set no longer has (a plot without data) is
removed with the swap rather than left to pass for part of it.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import threading
from pathlib import Path

from harness.results import RunError, atomic_write_text

STAGE = ".report-staging-"  # + the writer's process id
JOURNAL = ".report-swap-"  # + the writer's process id + ".json"
SET = ".report-set.json"
LOCK = ".report.lock"


def _own(prefix: str, suffix: str = "") -> str:
    return f"{prefix}{os.getpid()}{suffix}"


def _writer_gone(name: str, prefix: str, suffix: str = "") -> bool:
    from harness.run.folder_claims import process_alive

    pid = name.removeprefix(prefix).removesuffix(suffix)
    return pid.isdigit() and int(pid) != os.getpid() and not process_alive(int(pid))


def recover(out_dir: Path) -> str | None:
    """Finish the swaps that killed writers left (their journals) and discard their unfinished stages; a
    phrase saying what it did, or None when there was nothing to do. A live writer's files are left alone."""
    out_dir = Path(out_dir)
    said = []
    with _locked(out_dir):
        for journal in sorted(out_dir.glob(f"{JOURNAL}*.json")):
            if not _writer_gone(journal.name, JOURNAL, ".json"):
                continue
            try:
                plan = json.loads(journal.read_text())
            except ValueError:  # torn while being written: the swap had not begun
                plan = None
            stage_name = journal.name.removeprefix(JOURNAL).removesuffix(".json")
            if plan is not None:
                _apply(out_dir, plan, out_dir / f"{STAGE}{stage_name}")
                said.append(f"finished the swap of an interrupted report ({len(plan['move'])} files)")
            journal.unlink()
        for folder in sorted(out_dir.glob(f"{STAGE}*")):
            if folder.is_dir() and _writer_gone(folder.name, STAGE):
                shutil.rmtree(folder)
                said.append("discarded the files of an unfinished report; the previous one stands")
    return "; ".join(said) or None


def stage(out_dir: Path) -> Path:
    """An empty staging folder of this process's own in ``out_dir`` for a new set (after :func:`recover`)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    recover(out_dir)
    folder = out_dir / _own(STAGE)
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    return folder


def commit(out_dir: Path, remove: tuple[str, ...] = ()) -> list[Path]:
    """Move every file of this process's stage into ``out_dir`` as one set; remove the previous set's
    files the new one lacks, and the names in ``remove`` (files of an older report that may not be
    listed). Returns the new set's paths."""
    out_dir = Path(out_dir)
    staged = out_dir / _own(STAGE)
    names = sorted(p.name for p in staged.iterdir() if p.is_file())
    in_the_way = [name for name in names if (out_dir / name).exists() and not (out_dir / name).is_file()]
    if in_the_way:  # found before the first move: the previous set stays whole
        shutil.rmtree(staged)
        raise RunError(f"{out_dir / in_the_way[0]} is not a file; move it away so the report can be written there")
    with _locked(out_dir), _signals_held():
        stale = sorted((set(_previous_set(out_dir)) | set(remove)) - set(names))
        plan = {"move": names, "remove": stale}
        journal = out_dir / _own(JOURNAL, ".json")
        atomic_write_text(journal, json.dumps(plan))
        _apply(out_dir, plan, staged)
        journal.unlink()
    return [out_dir / name for name in names]


def _apply(out_dir: Path, plan: dict, staged: Path) -> None:
    """A journal's moves and removals; each step may already be done (a swap resumed)."""
    for name in plan["move"]:
        if (staged / name).is_file():
            os.replace(staged / name, out_dir / name)
    for name in plan["remove"]:
        if (out_dir / name).is_file():
            (out_dir / name).unlink()
    atomic_write_text(out_dir / SET, json.dumps(sorted(plan["move"])) + "\n")
    shutil.rmtree(staged, ignore_errors=True)


def _previous_set(out_dir: Path) -> list[str]:
    try:
        names = json.loads((out_dir / SET).read_text())
    except (OSError, ValueError):
        return []
    return [n for n in names if isinstance(n, str) and "/" not in n] if isinstance(names, list) else []


@contextlib.contextmanager
def _locked(out_dir: Path):
    """The folder's report lock: one swap (or recovery) at a time."""
    import fcntl

    with open(out_dir / LOCK, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


@contextlib.contextmanager
def _signals_held():
    """SIGINT and SIGTERM wait until the block ends (main thread only: elsewhere they reach the main
    thread anyway)."""
    held = (signal.SIGINT, signal.SIGTERM)
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)
