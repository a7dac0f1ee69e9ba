"""Run-folder claims: one worker at a time writes a run, on any storage every node of a cluster sees.

A worker claims ``RUN`` by creating ``RUN/.claim.N`` with ``O_CREAT | O_EXCL``, N one more than the
highest generation present. Exclusive creation is atomic on local POSIX filesystems and on NFSv3 and
later, so of two workers racing for one generation exactly one succeeds; the holder is the highest
generation. While it works, a thread refreshes the file's modification time (the heartbeat) every
``heartbeat_s`` seconds and checks that no higher generation has appeared.

Stale claims. A claim naming this machine (host name and boot id) and a process that no longer exists
(compared by pid and start time, so a reused pid is not mistaken for the holder) is stale at once: a
worker killed here is taken over without waiting. A claim from another machine is stale when its
heartbeat has not moved for ``stale_s`` seconds of the waiter's own clock; watching for a change,
rather than comparing timestamps, makes the rule immune to clock skew between nodes. A stale claim is
taken over by claiming the next generation (the dead worker's file stays beneath it and is removed
on release); two workers taking over the same stale claim race for that generation and one wins.

Safety. A holder that finds a higher generation than its own (it was presumed dead, say its node
stalled for ``stale_s``) exits at once with code 75 and writes nothing more. The new holder resumes
from the last checkpoint, which is written atomically under a name unique to its writer, so no file
is torn. Release removes the generations from the lowest up, the holder's own last, so no new claim
can be created (and then removed) while the holder's still stands.
"""

from __future__ import annotations

import json
import os
import socket
import sys
import threading
import time
from pathlib import Path

HEARTBEAT_S = 5.0
STALE_S = 60.0
LOST_CLAIM_EXIT = 75  # EX_TEMPFAIL: another worker holds the run now; nothing was written after losing it
PREFIX = ".claim."


def _boot_id() -> str:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


def _start_ticks(pid: int) -> int | None:
    """A process's start time in clock ticks since boot (Linux), to tell it from a later one with its pid."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # the command name (field 2) is in parentheses and may hold spaces: split after its closing one
    return int(stat.rsplit(")", 1)[1].split()[19])


def process_alive(pid: int, start: int | None = None) -> bool:
    """Whether process ``pid`` runs on this machine (and, given its ``start`` ticks, is that same process)."""
    if Path("/proc").is_dir():
        now = _start_ticks(pid)
        return now is not None and (start is None or now == start)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


MACHINE = f"{socket.gethostname()}/{_boot_id()}"


def generations(run_dir: Path) -> list[int]:
    """The claim generations present in ``run_dir``, lowest first."""
    found = []
    try:
        names = os.listdir(run_dir)
    except FileNotFoundError:
        return []
    for name in names:
        if name.startswith(PREFIX) and name[len(PREFIX) :].isdigit():
            found.append(int(name[len(PREFIX) :]))
    return sorted(found)


def holder(run_dir: Path) -> dict | None:
    """The current claim's content (host, pid, since), or None when the run is unclaimed."""
    gens = generations(Path(run_dir))
    if not gens:
        return None
    try:
        return json.loads((Path(run_dir) / f"{PREFIX}{gens[-1]}").read_text()) | {"generation": gens[-1]}
    except (OSError, ValueError):
        return {"generation": gens[-1]}


class Claim:
    """``with Claim(run_dir): ...`` holds the run for this process; waits while a live worker holds it."""

    def __init__(
        self,
        run_dir: str | os.PathLike,
        heartbeat_s: float = HEARTBEAT_S,
        stale_s: float = STALE_S,
        poll_s: float = 1.0,
        stream=None,
    ):
        stream = stream or sys.stdout  # the stdout of now, not of import time
        self.run_dir = Path(run_dir)
        self.heartbeat_s, self.stale_s, self.poll_s, self.stream = heartbeat_s, stale_s, poll_s, stream
        self.generation: int | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._watched: dict[tuple, float] = {}  # (generation, mtime) -> when this process first saw it

    # -- judging the current holder -----------------------------------------------------------------

    def _stale(self, generation: int) -> bool | None:
        """True when the claim is stale, False when live, None when it vanished meanwhile."""
        path = self.run_dir / f"{PREFIX}{generation}"
        try:
            mtime = path.stat().st_mtime_ns
            text = path.read_text()
        except FileNotFoundError:
            return None
        try:
            info = json.loads(text)
        except ValueError:
            info = None  # created an instant ago and not yet written: judge it by its heartbeat alone
        if info and info.get("machine") == MACHINE:
            return not process_alive(int(info["pid"]), info.get("start_ticks"))
        first_seen = self._watched.setdefault((generation, mtime), time.monotonic())
        return time.monotonic() - first_seen > self.stale_s

    # -- taking and holding -------------------------------------------------------------------------

    def acquire(self) -> Claim:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        announced = None
        while True:
            gens = generations(self.run_dir)
            top = gens[-1] if gens else 0
            if top:
                verdict = self._stale(top)
                if verdict is None:
                    continue  # released or taken over while we looked: look again
                if not verdict:
                    if announced != top:
                        info = holder(self.run_dir) or {}
                        print(
                            f"{self.run_dir.name} is claimed by {info.get('host', '?')} pid {info.get('pid', '?')} "
                            f"(since {info.get('since', '?')}): waiting for it to finish or die",
                            file=self.stream,
                            flush=True,
                        )
                        announced = top
                    time.sleep(self.poll_s)
                    continue
                print(
                    f"{self.run_dir.name}: taking over a stale claim (generation {top})", file=self.stream, flush=True
                )
            path = self.run_dir / f"{PREFIX}{top + 1}"
            try:
                fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                continue  # another worker won this generation: judge it like any holder
            payload = {
                "host": socket.gethostname(),
                "machine": MACHINE,
                "pid": os.getpid(),
                "start_ticks": _start_ticks(os.getpid()),
                "since": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            }
            with os.fdopen(fd, "w") as fh:
                fh.write(json.dumps(payload) + "\n")
                fh.flush()
                os.fsync(fh.fileno())
            self.generation = top + 1
            self._thread = threading.Thread(target=self._beat, name="claim-heartbeat", daemon=True)
            self._thread.start()
            return self

    def _beat(self) -> None:
        path = self.run_dir / f"{PREFIX}{self.generation}"
        while not self._stop.wait(self.heartbeat_s):
            gens = generations(self.run_dir)
            if self._stop.is_set():  # released meanwhile: a removed claim is this worker's own doing
                return
            if not path.exists() or (gens and gens[-1] > self.generation):
                print(
                    f"{self.run_dir.name}: another worker took this run over (this one was presumed dead); "
                    "stopping without writing anything more",
                    file=sys.stderr,
                    flush=True,
                )
                os._exit(LOST_CLAIM_EXIT)
            try:
                os.utime(path)
            except FileNotFoundError:
                pass  # judged on the next beat

    def release(self) -> None:
        """Remove the claim. A signal's exception while the heartbeat winds down (a second Ctrl-C, say)
        still removes it: a claim left behind would hold the run until another worker judged it stale."""
        if self.generation is None:
            return
        self._stop.set()
        try:
            if self._thread is not None:
                self._thread.join()
        finally:
            for gen in generations(self.run_dir):
                if gen <= self.generation:
                    try:
                        (self.run_dir / f"{PREFIX}{gen}").unlink()
                    except FileNotFoundError:
                        pass
            self.generation = None

    def __enter__(self) -> Claim:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
