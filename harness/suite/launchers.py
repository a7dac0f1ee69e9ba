"""Where the suite's jobs run: local processes (the default) or Ray tasks on a cluster.

Every job is the same command line either way (``python -m harness bench-run RUN``, ``gradcheck ...``),
its output appended to ``STORE/NAME/logs/JOB.log`` and its results written into the content-addressed
store, so a cluster's results land where a local run's would, in the same folders and tables.

* ``LocalLauncher``: one process per job, ``--jobs`` at a time (one per core on a CPU machine: a Warp
  CPU kernel uses one thread). Each job runs in its own session; the suite passes Ctrl-C/SIGTERM on.
  A suite that dies without passing anything on (SIGKILL, a crash) still takes its jobs down: each job
  holds the read end of a pipe whose write end only the suite has, and the end of that pipe (the
  kernel closes it when the suite dies, however it dies) makes the job send itself one SIGINT
  (``harness/__main__.py``), so a training job checkpoints at its epoch boundary and stops, and running
  the suite again resumes it; none is left training unseen. A pipe rather than the kernel's
  parent-death signal: that signal comes again each time the dying suite's threads hand the job on to
  one another, and a second SIGINT means "stop now", without the checkpoint.
* ``RayLauncher`` (``--launcher ray [--address HOST:PORT]``; ``pip install 'diffsim-bench[ray]'``): each
  job is a Ray task that asks for one CPU, plus ``--gpus-per-run`` of a GPU when the suite's device is
  CUDA, and runs the command in a child process on whichever node Ray picks. The store must be a path
  every node sees (shared storage). A task whose worker dies (node lost, process killed) is retried by
  Ray; the retry resumes the run from its last checkpoint, and the run's claim (harness/run/folder_claims.py)
  guarantees that the dead worker, or a second suite racing for the same spec, never writes the run
  at the same time. The child dies with its Ray worker (``PR_SET_PDEATHSIG``), so a killed worker
  leaves no orphan training behind.
"""

from __future__ import annotations

import functools
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

from harness import SUITE_LIFELINE
from harness.results import RunError

LAUNCHERS = ("local", "ray")
RAY_RETRIES = 3  # attempts after the first when a worker dies or a child is killed
_FORWARDED_ENV = ("OMP_", "WARP_", "DIFFSIM_", "CUDA_", "PYTHON")  # the driver's settings that reach every job


def _job_env() -> dict:
    env = {k: v for k, v in os.environ.items() if k.startswith(_FORWARDED_ENV) and k != SUITE_LIFELINE}
    env.setdefault("OMP_NUM_THREADS", "1")
    env["PYTHONUNBUFFERED"] = "1"
    return env


def last_error_line(log: Path) -> str:
    """The last line of a job's log that says what went wrong (``error:``, an exception), else its last line."""
    try:
        lines = [line.strip() for line in log.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        return ""
    for line in reversed(lines[-200:]):
        if line.startswith("error:") or "Error" in line.split(":", 1)[0] or line.startswith("Traceback"):
            return line[:300]
    return lines[-1][:300] if lines else ""


class LocalLauncher:
    """Jobs as child processes of this one."""

    name = "local"

    def __init__(self, workers: int):
        self.workers = max(1, workers)

    def describe(self) -> str:
        return f"local, {self.workers} process(es) at once"

    def start(self, argv: list[str], log: Path):
        fh = log.open("a")
        fh.write(f"\n$ {' '.join(argv)}\n")
        fh.flush()
        lifeline, held = os.pipe()  # both ends close on exec, so no other job inherits this suite's end
        env = {**os.environ, **_job_env(), SUITE_LIFELINE: str(lifeline)}
        try:
            proc = subprocess.Popen(
                argv, stdout=fh, stderr=subprocess.STDOUT, env=env, start_new_session=True, pass_fds=(lifeline,)
            )
        except BaseException:
            os.close(held)
            raise
        finally:
            os.close(lifeline)
            fh.close()
        proc.lifeline = held  # closed when the job has ended; until then the job knows the suite lives
        return proc

    def wait(self, handle) -> int:
        try:
            return handle.wait()
        finally:
            os.close(handle.lifeline)

    def signal(self, handle, signum: int) -> None:
        handle.send_signal(signum)

    def close(self) -> None:
        pass


# -- Ray ------------------------------------------------------------------------------------------


class ChildKilled(RuntimeError):
    """The job's process died of a signal nobody sent on purpose (OOM killer, SIGKILL): Ray retries it."""


def _signal_on_parent_death(signum: int, parent: int) -> None:  # pragma: no cover - runs in the forked child
    """In a forked child before exec: have the kernel send ``signum`` when the thread that started it dies.

    Ray's worker threads block SIGINT, and a blocked signal stays blocked across exec, so it is unblocked
    first, or the job could never be asked to checkpoint and stop. Where prctl is missing (not Linux)
    the job runs without the guard. A parent already gone before the guard took effect is caught by
    comparing the parent's pid.
    """
    import ctypes

    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signum)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:
        os._exit(128 + signum)


def run_job_in_this_process(words: list[str], log: str, env: dict, cwd: str | None, stop_file: str) -> int:
    """Body of the Ray task: run ``python -m harness WORDS`` here, appending to ``log``; its exit code.

    The driver asks a job to stop by creating ``stop_file`` (on the shared store, so it works on any
    node): the job's process gets SIGINT, so a training job checkpoints at its epoch boundary and exits
    130 (resumable), as with a local Ctrl-C. The wait polls, because a blocking wait would also keep
    Ray's own cancellation (an exception raised in this thread) from ever arriving.
    """
    argv = [sys.executable, "-m", "harness", *words]
    with open(log, "a") as fh:
        fh.write(f"\n$ {' '.join(argv)}   [ray worker {socket.gethostname()} pid {os.getpid()}]\n")
        fh.flush()
        proc = subprocess.Popen(
            argv,
            stdout=fh,
            stderr=subprocess.STDOUT,
            env={**os.environ, **env},
            cwd=cwd if cwd and Path(cwd).is_dir() else None,
            preexec_fn=functools.partial(_signal_on_parent_death, signal.SIGKILL, os.getpid()),
        )
        try:
            while True:
                try:
                    code = proc.wait(timeout=0.5)
                    break
                except subprocess.TimeoutExpired:
                    if os.path.exists(stop_file):
                        proc.send_signal(signal.SIGINT)
                        code = proc.wait()
                        break
        except KeyboardInterrupt:  # ray.cancel: stop the job at once (it resumes from its last checkpoint)
            proc.kill()
            proc.wait()
            raise
    if code < 0 and -code not in (signal.SIGINT, signal.SIGTERM):
        raise ChildKilled(f"{' '.join(words[:2])}: killed by {signal.Signals(-code).name}")
    return code


CONNECT_TIMEOUT_S = 10.0
# A Ray head's address is its GCS, a gRPC server: it answers the HTTP/2 connection preface with a
# SETTINGS frame (a 9-byte frame header of type 4). Something else listening there (a web server, a
# database) does not, and ray.init would retry it for minutes.
_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
_SETTINGS = 4


def _reachable(address: str, timeout: float | None = None) -> None:
    """Refuse, in one line within ``timeout`` seconds, a head address that is malformed, where nothing
    listens, or where what listens does not speak gRPC (not a Ray head); ray.init would retry for minutes."""
    timeout = CONNECT_TIMEOUT_S if timeout is None else timeout
    address = address.removeprefix("ray://")
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise RunError(f"--address {address}: expected HOST:PORT of a Ray head, e.g. 10.0.0.1:6379")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout) as sock:
            sock.settimeout(timeout)
            sock.sendall(_HTTP2_PREFACE)
            header = b""
            while len(header) < 9:
                chunk = sock.recv(9 - len(header))
                if not chunk:
                    break
                header += chunk
    except TimeoutError:
        raise RunError(f"--address {address}: no answer within {timeout:g} s; not a Ray head") from None
    except OSError as exc:
        raise RunError(f"--address {address}: no Ray head answers there ({exc.strerror or exc})") from None
    if len(header) < 9 or header[3] != _SETTINGS:
        raise RunError(f"--address {address}: something listens there, but not a Ray head (no gRPC answer)")


class RayLauncher:
    """Jobs as Ray tasks: one CPU each (and a GPU fraction on CUDA), retried when their worker dies."""

    name = "ray"

    def __init__(self, address: str | None, workers: int | None, device: str, gpus_per_run: float):
        try:
            import ray
        except ImportError:
            raise RunError("--launcher ray needs Ray: pip install 'diffsim-bench[ray]'") from None
        self.ray = ray
        if address and address != "auto":
            _reachable(address)
        try:
            ray.init(address=address, log_to_driver=False, configure_logging=False, include_dashboard=False)
        except Exception as exc:  # a wrong address, no cluster there
            where = address or "a new local Ray instance"
            raise RunError(f"--launcher ray: cannot connect to {where}: {str(exc).splitlines()[0]}") from None
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.workers = workers or cpus
        self.cpus = cpus
        self.gpus = float(gpus_per_run) if device.startswith("cuda") else 0.0
        self.address = address
        self.task = ray.remote(run_job_in_this_process).options(
            num_cpus=1, num_gpus=self.gpus, max_retries=RAY_RETRIES, retry_exceptions=[ChildKilled]
        )
        self.cwd = os.getcwd()
        self.stop_files: dict = {}  # task reference -> the file that asks it to stop

    def describe(self) -> str:
        gpu = f", {self.gpus:g} GPU per run" if self.gpus else ""
        return f"ray at {self.address or 'a local instance'}: {self.cpus} CPUs, {self.workers} jobs in flight{gpu}"

    def start(self, argv: list[str], log: Path):
        words = argv[3:] if argv[1:3] == ["-m", "harness"] else argv
        stop_file = log.with_name(log.name + ".stop")
        stop_file.unlink(missing_ok=True)
        handle = self.task.remote(words, str(log), _job_env(), self.cwd, str(stop_file))
        self.stop_files[handle] = stop_file
        return handle

    def wait(self, handle) -> int:
        ray = self.ray
        try:
            return int(ray.get(handle))
        except ray.exceptions.TaskCancelledError:
            return 130
        except ray.exceptions.RayError as exc:
            print(f"ray: {str(exc).strip().splitlines()[-1][:300]}", file=sys.stderr, flush=True)
            return 1
        finally:
            self.stop_files.pop(handle, Path("/nonexistent")).unlink(missing_ok=True)

    def signal(self, handle, signum: int) -> None:
        """First signal: ask the job to checkpoint and stop (its stop file); a second: cancel it at once."""
        stop_file = self.stop_files.get(handle)
        if stop_file is not None and not stop_file.exists():
            stop_file.touch()
        else:
            self.ray.cancel(handle, force=True)

    def close(self) -> None:
        self.ray.shutdown()


def make_launcher(kind: str, workers: int | None, address: str | None, device: str, gpus_per_run: float):
    if kind == "local":
        if address:
            raise RunError("--address is for --launcher ray")
        return LocalLauncher(workers or 1)
    if kind == "ray":
        return RayLauncher(address, workers, device, gpus_per_run)
    raise RunError(f"--launcher must be one of {', '.join(LAUNCHERS)}, got {kind!r}")
