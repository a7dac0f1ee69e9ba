"""Result files that say how they were made, written so an interruption never leaves half a file."""

from __future__ import annotations

import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from importlib import metadata
from pathlib import Path

_PACKAGES = ("torch", "warp-lang", "newton", "mujoco", "mujoco-warp", "numpy")


class RunError(RuntimeError):
    """A run directory, output path or configuration problem, reported as one line (exit 2)."""


class RunStopped(RuntimeError):
    """A run stopped on a signal, resumably: in training after checkpointing at an epoch boundary
    (``epoch``), or outside training (``epoch`` None: setting up or evaluating, where nothing is written
    but whole files)."""

    def __init__(self, run_dir, epoch: int | None, signum: int):
        self.signum = signum
        name = signal.Signals(signum).name
        if epoch is None:
            super().__init__(f"{name}: stopped {run_dir} outside its training; run the same command to continue")
        else:
            super().__init__(f"{name}: stopped at epoch {epoch} with a checkpoint in {run_dir}; continue with --resume")


def _git_commit() -> str | None:
    """The commit this code is: recorded at build time in an installed package (``harness/_commit.txt``,
    written by setup.py), else its checkout's HEAD; None when neither says."""
    recorded = Path(__file__).resolve().parent / "_commit.txt"
    try:
        if recorded.is_file():
            return recorded.read_text().strip() or None
    except OSError:
        pass
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=5,
        )
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def _git_dirty(here: Path | None = None) -> bool | None:
    """Whether the checkout this code runs from (or ``here``) has uncommitted changes to tracked files
    (the result then comes from more than ``git_commit``); None for an installed build or outside a
    checkout."""
    here = here or Path(__file__).resolve().parent
    if (here / "_commit.txt").is_file():
        return None
    try:
        out = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=10,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return bool(out.stdout.strip()) if out.returncode == 0 else None


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine() -> dict:
    """What makes float results machine-specific: CPU model and the thread settings of torch and Warp.

    The same seed gives identical metrics on one machine with the same settings; another CPU or thread
    count changes the order of float reductions, and training runs then diverge (docs/runs.md, "Reproducibility").
    """
    import torch

    gpus = (
        [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())] if torch.cuda.is_available() else []
    )
    return {
        "platform": platform.platform(),
        "cpu_model": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "processor": platform.machine(),
        "torch_num_threads": torch.get_num_threads(),
        "torch_num_interop_threads": torch.get_num_interop_threads(),
        "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
        "MKL_NUM_THREADS": os.environ.get("MKL_NUM_THREADS"),
        "warp_cpu_kernels": "single-threaded (one Warp CPU kernel runs on one thread)",
        "gpus": gpus,
        # other work on the machine when the result was made (timings want it near 0 beyond their own job)
        "load_average_1min": round(os.getloadavg()[0], 2),
    }


def shown_path(path: str | os.PathLike) -> str:
    """A path as results show it: relative to the working directory or the repository where it lies
    inside one (``harness/profiles/standard.toml``), so no machine's folders end up in a result."""
    resolved = Path(path).resolve()
    for base in (Path.cwd().resolve(), Path(__file__).resolve().parents[1]):
        if resolved.is_relative_to(base):
            return str(resolved.relative_to(base))
    return str(path)


def harness_command(words: list[str] | None = None) -> str:
    """``python -m harness WORDS`` (default: this process's arguments) as a result records it, its
    absolute paths shown as :func:`shown_path` shows them."""
    words = sys.argv[1:] if words is None else words
    return " ".join(["python -m harness", *(shown_path(w) if os.path.isabs(w) else w for w in map(str, words))])


def provenance(command: str | None = None) -> dict:
    """The command, code version, package versions and machine behind a result.

    ``command`` defaults to the harness invocation of this process.
    """
    versions = {}
    for name in _PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {
        "command": command or harness_command(),
        "git_commit": _git_commit(),
        "git_dirty": _git_dirty(),
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "python": platform.python_version(),
        "machine": machine(),
        "packages": versions,
    }


SUFFIX_ROOM = len(".provenance.json")  # the longest suffix a verb adds to a name it is given


def path_problem(path: str | os.PathLike) -> str | None:
    """Why a file cannot be written at ``path``, as a phrase, or None. Checked before any work: a name
    longer than the file system takes (with room for the suffixes a verb adds beside it), a path longer
    than it takes, a nearest existing ancestor that is a file or not writable."""
    path = Path(path).absolute()
    nearest = Path(path.anchor)
    for part in path.parts[1:-1]:  # down from the root to the last ancestor that exists
        try:
            if not (nearest / part).exists():
                break
        except OSError:  # a name too long to look up: said below
            break
        nearest = nearest / part
        if not nearest.is_dir():
            return f"{nearest} is a file, not a directory"
    try:
        name_max, path_max = os.pathconf(nearest, "PC_NAME_MAX"), os.pathconf(nearest, "PC_PATH_MAX")
    except (OSError, ValueError):  # a file system that does not say: the common Linux limits
        name_max, path_max = 255, 4096
    for part in path.parts[1:]:
        size = len(os.fsencode(part))
        if size > name_max - SUFFIX_ROOM:
            return (
                f"the name {part[:24]}... is {size} bytes; the file system takes {name_max}, "
                f"less {SUFFIX_ROOM} for the suffixes written beside it"
            )
    size = len(os.fsencode(str(path)))
    if size > path_max - 2 * name_max:  # the files a run or a suite writes below the given path
        return f"the path is {size} bytes; the file system takes {path_max}, less room for the files written below it"
    if not os.access(nearest, os.W_OK | os.X_OK):
        return f"{nearest} is not writable"
    return None


def out_problem(out: str | os.PathLike, kind: str = "file", flag: str = "--out") -> str | None:
    """The one check of every output path a verb is given, before any work: why ``out`` cannot be
    written as a ``kind`` ("file": a result file or a prefix of files; "folder": a directory a verb fills),
    as one line naming ``flag``, or None. Refused: an empty name (it would read as "not given"), a control
    character (a newline in a file name), what :func:`path_problem` refuses, and an existing path of the
    other kind."""
    text = str(out)
    noun = "a file" if kind == "file" else "a directory"
    if not text.strip():
        return f"{flag} is empty: name {noun}"
    if any(ord(ch) < 32 for ch in text):
        return f"{flag} {text!r}: a name on one line without control characters"
    path = Path(text)
    problem = path_problem(path if kind == "file" else path / "a-file-inside")
    if problem:
        return f"{flag} {text}: {problem}"
    if kind == "file" and path.is_dir():
        return f"{flag} {text} is a directory; name a file"
    if kind != "file" and path.exists() and not path.is_dir():
        return f"{flag} {text} is an existing file, not a directory"
    return None


def slow_write_for_tests() -> None:
    """Tests set DIFFSIM_BENCH_TEST_WRITE_DELAY (seconds) to hold every file write half-done for a while,
    so that a kill lands inside a write; unset (always, outside those tests) this does nothing."""
    delay = os.environ.get("DIFFSIM_BENCH_TEST_WRITE_DELAY")
    if delay:
        time.sleep(float(delay))


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` via a temporary file and an atomic rename."""
    return atomic_write_bytes(path, text.encode())


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` via a temporary file and an atomic rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        slow_write_for_tests()
        os.chmod(tmp, 0o644)  # mkstemp creates 0600; results are for everyone to read
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_json(path: str | os.PathLike, payload: dict) -> Path:
    return atomic_write_text(path, json.dumps(payload, indent=2, sort_keys=False) + "\n")


#: what a check file can hold, by the verb that wrote it (a soft body's crosscheck compares forward
#: rollouts: ``forward-crosscheck``)
CHECK_RESULT_KINDS = (
    "gradcheck",
    "throughput",
    "crosscheck",
    "forward-crosscheck",
    "parity",
    "contact-jacobians",
    "grad-paths",
    "grad-growth",
    "scaling",
    "fd-schemes",
    "solver-probe",
    "peer",
)


def write_check(path: str | os.PathLike, kind: str, result: dict, command: str | None = None) -> Path:
    """A check's result file, one schema for every kind: ``{"kind", "result", "provenance"}``. The kind
    says what ``result`` holds, so a report reads it back without guessing from its keys."""
    if kind not in CHECK_RESULT_KINDS:
        raise ValueError(f"unknown check kind {kind!r}; choose from: {', '.join(CHECK_RESULT_KINDS)}")
    return write_json(path, {"kind": kind, "result": result, "provenance": provenance(command)})


def write_check_and_table(out: str, kind: str, result: dict, text: str) -> list[Path]:
    """``STEM.md`` (``text``), then ``STEM.json`` (the check file; last, since a suite counts the check
    done when it exists), STEM being ``out`` without a ``.json`` suffix."""
    stem = Path(out.removesuffix(".json"))
    return [
        atomic_write_text(stem.with_suffix(".md"), text),
        write_check(stem.with_suffix(".json"), kind, result, harness_command()),
    ]


def read_metrics(path: Path) -> list[dict]:
    """Rows of metrics.jsonl; a torn last line (a kill during its write) is dropped."""
    if not path.exists():
        return []
    lines = path.read_text().splitlines()
    rows = []
    for i, line in enumerate(lines):
        if not line:
            continue
        try:
            rows.append(json.loads(line))
        except ValueError:
            if i == len(lines) - 1:
                break  # torn last line
            raise RunError(f"{path} has a corrupt line {i + 1} (not the last one)") from None
    return rows
