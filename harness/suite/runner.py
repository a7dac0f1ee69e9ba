"""Running a suite's jobs (:mod:`harness.suite.bench` plans them): ``workers`` at a time, each in its own process.

Every job runs as ``python -m harness ...`` (local processes, or Ray tasks: :mod:`harness.suite.launchers`)
with its output in ``STORE/NAME/logs/``; a job starts once the jobs it needs are done, a failing job
is reported and the suite goes on with the others, and a progress line (jobs done, ETA from the
estimated costs, corrected by the jobs that finished) follows every event. Ctrl-C or SIGTERM stops
the running jobs at their next epoch boundary (checkpointed); running the same command again
continues where it stopped. ``bench-run`` is one training run's job: train or resume, then evaluate.
At the end the report (:mod:`harness.report`) is written from whatever is finished.
"""

from __future__ import annotations

import contextlib
import json
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

from harness.checks.kinds import CHECK_KINDS
from harness.progress import ProgressLine, duration
from harness.results import RunError, RunStopped, path_problem
from harness.run.folder import CONFIG, JOB
from harness.run.folder_claims import Claim
from harness.suite.bench import (
    Job,
    check_spec,
    damage,
    load_spec,
    memory_problem,
    plan,
)


class SuiteStopped(RunStopped):
    """The suite stopped on a signal; its running jobs checkpointed (exit 128 + signal, like ``train``)."""

    def __init__(self, store, finished: int, total: int, signum: int):
        RuntimeError.__init__(
            self,
            f"{signal.Signals(signum).name}: {finished}/{total} jobs finished, the running ones checkpointed in "
            f"{store}; run the same command again to continue",
        )
        self.signum = signum


# -- running ----------------------------------------------------------------------------------------


class _SuiteProgress:
    """Runs done / total with an ETA from the estimated costs, corrected by the jobs that finished."""

    def __init__(self, name: str, jobs: list[Job], workers: int, stream):
        self.name, self.jobs, self.workers = name, jobs, workers
        self.display = ProgressLine(stream)
        self.t0 = time.perf_counter()
        self.measured: dict[tuple, list[float]] = {}  # cost key -> [actual seconds, estimated seconds]
        self.lock = threading.Lock()

    def record(self, job: Job, seconds: float) -> None:
        with self.lock:
            actual, estimated = self.measured.get(job.cost_key, [0.0, 0.0])
            self.measured[job.cost_key] = [actual + seconds, estimated + job.estimate_s]

    def _remaining(self) -> float:
        """Estimated seconds left: each job's estimate, scaled by how jobs of its kind, backend and task
        actually took so far (1 until one has finished), divided over the workers."""
        left = 0.0
        for job in self.jobs:
            if job.state in ("pending", "running"):
                actual, estimated = self.measured.get(job.cost_key, [0.0, 0.0])
                factor = actual / estimated if estimated > 0 else 1.0
                left += job.estimate_s * factor * (0.5 if job.state == "running" else 1.0)
        return left / max(self.workers, 1)

    def line(self, event: str) -> None:
        with self.lock:
            finished = [j for j in self.jobs if j.state in ("done", "reused", "failed", "skipped")]
            reused = sum(j.state == "reused" for j in self.jobs)
            failed = sum(j.state in ("failed", "skipped") for j in self.jobs)
            runs = [j for j in self.jobs if j.kind == "train"]
            runs_done = sum(j.state in ("done", "reused") for j in runs)
            active = sum(j.state == "running" for j in self.jobs)
            elapsed = time.perf_counter() - self.t0
            text = (
                f"[bench {self.name}] jobs {len(finished)}/{len(self.jobs)} (runs {runs_done}/{len(runs)}; "
                f"{active} running, {reused} reused, {failed} failed) · elapsed {duration(elapsed)} · "
                f"ETA {duration(self._remaining())} · {event}"
            )
        self.display.show(text, final=True)


def run_jobs(jobs: list[Job], store: Path, workers: int, name: str, stream=None, launcher=None) -> list[Job]:
    """Run the jobs not yet done, ``workers`` at a time, in order, each after the jobs it needs, on
    ``launcher`` (harness/suite/launchers.py; default: local processes)."""
    stream = stream or sys.stdout  # the stdout of now, not of import time
    from harness.suite.launchers import LocalLauncher

    launcher = launcher or LocalLauncher(workers)
    logs = store / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    for job in jobs:
        if job.is_done():
            job.state = "reused"
    progress = _SuiteProgress(name, jobs, launcher.workers, stream)
    progress.line(f"start ({launcher.describe()})")
    scheduler = _Scheduler(jobs, launcher, logs, progress, stream)
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM):
            previous[signum] = signal.signal(signum, scheduler.on_signal)
    threads = [threading.Thread(target=scheduler.worker, daemon=True) for _ in range(max(1, launcher.workers))]
    try:
        for t in threads:
            t.start()
        for t in threads:
            while t.is_alive():
                t.join(timeout=0.5)
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    if scheduler.signals_seen:
        done = sum(j.state in ("done", "reused") for j in jobs)
        raise SuiteStopped(store, done, len(jobs), scheduler.signals_seen[0])
    return jobs


class _Scheduler:
    """The worker threads' shared state: which job runs next, the launched handles, and the signals."""

    def __init__(self, jobs: list[Job], launcher, logs: Path, progress: _SuiteProgress, stream) -> None:
        self.jobs, self.launcher, self.logs, self.progress, self.stream = jobs, launcher, logs, progress, stream
        self.by_label = {job.label: job for job in jobs}
        self.cond = threading.Condition()
        self.stop = threading.Event()
        self.running: set = set()  # handles of the launched jobs (processes or Ray task references)
        self.running_lock = threading.Lock()
        self.signals_seen: list[int] = []

    def ready(self, job: Job) -> bool | None:
        """True to start, None to skip (a job it needs failed), False to wait."""
        states = [self.by_label[label].state for label in job.after]
        if any(s in ("failed", "skipped") for s in states):
            return None
        return all(s in ("done", "reused") for s in states)

    def next_job(self) -> Job | None:
        """The next job to run, marked running; None when nothing is left or the suite stops."""
        with self.cond:
            while True:
                pending = [j for j in self.jobs if j.state == "pending"]
                # analyses of finished runs first: a stopped suite then has them for what it trained
                pending.sort(key=lambda j: j.kind not in ("sim_to_sim", "landscape", "step_gain", "render"))
                if not pending or self.stop.is_set():
                    return None
                for candidate in pending:
                    verdict = self.ready(candidate)
                    if verdict is None:
                        candidate.state = "skipped"
                        self.cond.notify_all()
                    elif verdict:
                        candidate.state = "running"
                        return candidate
                if not any(j.state == "pending" for j in self.jobs):
                    return None
                self.cond.wait(timeout=1.0)

    def worker(self) -> None:
        while not self.stop.is_set():
            job = self.next_job()
            if job is None:
                return
            self.run_one(job)
            with self.cond:
                self.cond.notify_all()

    def run_one(self, job: Job) -> None:
        from harness.suite.launchers import last_error_line

        if job.kind == "train":
            _write_job_file(job)
        log = self.logs / f"{job.label.replace(' ', '_').replace('/', '-')}.log"
        self.progress.line(f"start {job.label}")
        start = time.perf_counter()
        with self.running_lock:
            if self.stop.is_set():
                job.state = "pending"
                return
            handle = self.launcher.start(job.argv, log)
            self.running.add(handle)
        code = self.launcher.wait(handle)
        with self.running_lock:
            self.running.discard(handle)
        seconds = time.perf_counter() - start
        if code in (130, 143) or self.stop.is_set():
            job.state = "pending"
            self.stop.set()
            self.progress.line(f"stopped {job.label} (resumable)")
            return
        job.state = "done" if code == 0 and job.is_done() else "failed"
        self.progress.record(job, seconds)
        note = "" if job.state == "done" else f" (exit {code}; see {log}): {last_error_line(log)}"
        self.progress.line(f"{job.state} {job.label} in {duration(seconds)}{note}")

    def on_signal(self, signum, frame) -> None:
        # Jobs run in their own sessions, so a terminal's Ctrl-C reaches only this process: pass each
        # signal on exactly once. The first makes a training job finish its epoch and checkpoint; a
        # second stops it at once (it resumes from its last checkpoint either way).
        self.signals_seen.append(signum)
        self.stop.set()
        if len(self.signals_seen) == 1:
            print(
                f"\n{signal.Signals(signum).name}: the running jobs checkpoint at their next epoch boundary and "
                "stop; run the same command again to continue (again to stop them now)",
                file=self.stream,
                flush=True,
            )
        with self.running_lock:
            for handle in self.running:
                self.launcher.signal(handle, signum)


def _write_job_file(job: Job) -> None:
    """The run's planned configuration, read by ``bench-run`` (and by nothing that changes it)."""
    from harness.results import write_json

    job.run_dir.mkdir(parents=True, exist_ok=True)
    payload = {**job.run.identity(), "eval": job.run.eval_settings(), "key": job.run.key, "preset": job.run.preset}
    write_json(job.run_dir / JOB, payload)


def bench_run(run_dir: str | Path, stream=None) -> Path:
    """One training run of the suite: train, or resume an interrupted one, then evaluate (``bench-run``)."""
    stream = stream or sys.stdout  # the stdout of now, not of import time
    run_dir = Path(run_dir)
    path = run_dir / JOB
    if not path.is_file():
        raise RunError(f"{run_dir} has no job.json: bench-run runs directories planned by `bench`")
    from harness.run.train import job_problem, train_planned

    try:
        job = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise RunError(f"{path} is unreadable ({exc}); plan the run again with bench") from None
    problem = job_problem(job)
    if problem:  # before the claim: nothing is written for a job that cannot run
        raise RunError(f"{path}: {problem}; plan the run again with bench")
    with _signals_unwind(run_dir), Claim(run_dir, stream=stream):  # one worker writes a run; the others wait
        train_planned(run_dir, job, stream)
    return run_dir


class _Signalled(BaseException):
    """Raised by a signal handler: a BaseException, so that no ``except Exception`` on the way (a file
    loader's, say) takes it for an error of its own."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


@contextlib.contextmanager
def _signals_unwind(run_dir: Path):
    """SIGINT/SIGTERM end ``bench-run`` by an exception (:class:`RunStopped`) rather than at once, so that
    the run's claim is released on the way out: another worker then takes the run without waiting for
    the claim to go stale. Training takes the signals over while it runs (finish the epoch, checkpoint);
    a second signal stops at once, as everywhere."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous: dict = {}
    stopping: list[int] = []

    def handle(signum, frame):
        stop_now = previous[signum]
        if stopping and callable(stop_now):
            stop_now(signum, frame)
        stopping.append(signum)
        raise _Signalled(signum)

    try:
        for signum in (signal.SIGINT, signal.SIGTERM):
            previous[signum] = signal.signal(signum, handle)
        yield
    except _Signalled as exc:
        raise RunStopped(run_dir, None, exc.signum) from None
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def run_suite(
    profile: str | None = None,
    spec_file: str | None = None,
    spec: dict | None = None,
    store: str | Path = "results/bench",
    jobs: int | None = None,
    dry_run: bool = False,
    report_only: bool = False,
    command: str | None = None,
    stream=None,
    launcher: str = "local",
    address: str | None = None,
    gpus_per_run: float = 0.25,
    device: str | None = None,
    command_problem: Callable[[list[str]], str | None] | None = None,
) -> int:
    """Plan, run what is missing (on the local or the Ray launcher), write the tables and plots; 0 when
    every job succeeded. The spec is a profile, a TOML file or ``spec``, one made in memory (``sweep``);
    ``device``, where given, replaces its [suite] device. ``command_problem`` reads a job's harness words
    as the command line would (the CLI passes its parser), so a spec's check arguments out of bounds are
    refused before any job runs, not when their job's turn comes."""
    stream = stream or sys.stdout  # the stdout of now, not of import time
    from harness.suite.launchers import make_launcher

    if spec is not None:
        data, spec_path = check_spec(spec, "the sweep's spec"), "(made in memory by sweep)"
    else:
        data, spec_path = load_spec(profile, spec_file)
    if device:
        data = {**data, "suite": {**data["suite"], "device": device}}
    name = data["suite"]["name"]
    # absolute: a Ray worker on another node resolves the same path on the shared storage
    store = Path(store).resolve() / name
    problem = path_problem(store / "runs" / CONFIG)  # where the deepest files go
    if problem:
        raise RunError(f"the store {store}: {problem}")
    all_jobs = plan(data, store)
    for job in all_jobs if command_problem else ():
        problem = command_problem(job.argv[3:])  # after "python -m harness"
        if problem:
            raise RunError(f"{spec_path}: job {job.label}: {problem}")
    workers = jobs or int(data["suite"].get("jobs", 1))
    if dry_run:
        for job in all_jobs:
            status = "done" if job.is_done() else ("resume" if (job.output.parent / CONFIG).exists() else "new")
            print(f"{status:6s} ~{duration(job.estimate_s):>8s}  {job.label}", file=stream)
        total = sum(j.estimate_s for j in all_jobs if not j.is_done())
        print(f"{len(all_jobs)} jobs; about {duration(total / max(workers, 1))} on {workers} workers", file=stream)
        return 0
    if not report_only:
        problem = memory_problem(all_jobs, workers, data["suite"].get("device", "cpu")) if launcher == "local" else None
        if problem:
            raise RunError(f"{spec_path}: {problem}")
        _move_damaged_runs(all_jobs, stream)
        runner = make_launcher(
            launcher, jobs if launcher == "ray" else workers, address, data["suite"].get("device", "cpu"), gpus_per_run
        )
        try:
            run_jobs(all_jobs, store, workers, name, stream, launcher=runner)
        finally:
            runner.close()
    else:
        for job in all_jobs:
            job.state = "reused" if job.is_done() else "pending"
        if not any(job.state == "reused" for job in all_jobs):
            damaged = _damaged_outputs(all_jobs)
            raise RunError(
                f"nothing to report in {store}: none of its {len(all_jobs)} jobs has finished"
                + (f" ({len(damaged)} damaged: {'; '.join(damaged)})" if damaged else "")
                + "; run the same command without --report-only"
            )
    return _finish(data, spec_path, store, all_jobs, command, stream)


def _move_damaged_runs(jobs: list[Job], stream) -> None:
    """A run folder whose config.json is damaged is named and moved aside (``NAME.damaged-N``, nothing
    deleted), so its job makes the run again rather than fail on it or pass it over."""
    for job in jobs:
        problem = damage(job.run_dir) if job.kind == "train" else None
        if problem is None:
            continue
        n = 1
        while job.run_dir.with_name(f"{job.run_dir.name}.damaged-{n}").exists():
            n += 1
        aside = job.run_dir.rename(job.run_dir.with_name(f"{job.run_dir.name}.damaged-{n}"))
        print(f"damaged run: {problem}; moved to {aside.name}, its run is made again", file=stream, flush=True)


def _damaged_outputs(jobs: list[Job]) -> list[str]:
    """The finished-looking outputs a report cannot read: run folders with a damaged config.json and
    check files that are not whole JSON, one line each."""
    lines = [problem for j in jobs if j.kind == "train" and (problem := damage(j.run_dir)) is not None]
    for job in jobs:
        if job.kind in CHECK_KINDS and job.output.exists():
            try:
                whole = isinstance(json.loads(job.output.read_text()), dict)
            except (OSError, ValueError):
                whole = False
            if not whole:
                lines.append(f"{job.output}: not a whole check file; made again by the next bench")
    return lines


def _finish(data: dict, spec_path: Path, store: Path, jobs: list[Job], command: str | None, stream) -> int:
    from harness.report import write_bench_report
    from harness.results import harness_command, provenance, shown_path, write_json

    name = data["suite"]["name"]
    runs = [j.run_dir for j in jobs if j.kind == "train" and (j.run_dir / CONFIG).is_file()]
    checks = [j.output for j in jobs if j.kind in CHECK_KINDS and j.output.is_file()]
    out_dir = store
    made_by = provenance(command)
    header = {**made_by, "profile": name, "spec": shown_path(spec_path)}
    failed = [j for j in jobs if j.state in ("failed", "skipped")]
    missing = [j for j in jobs if j.state == "pending"]
    status = {
        "profile": name,
        "spec": shown_path(spec_path),
        "jobs": [
            {
                "label": j.label,
                "kind": j.kind,
                "state": j.state,
                "output": shown_path(j.output),
                "command": harness_command(j.argv[3:]),  # after the interpreter's "python -m harness"
            }
            for j in jobs
        ],
        "provenance": made_by,
    }
    written = write_bench_report(
        runs, checks, out_dir, header, also=lambda folder: [write_json(folder / "jobs.json", status)]
    )
    print(f"\n[bench {name}] wrote {len(written)} files in {out_dir}:", file=stream)
    for path in written:
        print(f"  {path}", file=stream)
    if missing:
        print(f"[bench {name}] {len(missing)} job(s) not run yet: run the same command again", file=stream)
    damaged = _damaged_outputs(jobs)
    if damaged:
        print(f"[bench {name}] {len(damaged)} damaged file(s) left out of the tables:", file=stream)
        for line in damaged:
            print(f"  {line}", file=stream)
        return 1
    if failed:
        print(f"[bench {name}] {len(failed)} job(s) failed or skipped (logs in {store / 'logs'}):", file=stream)
        for job in failed:
            print(f"  {job.state}: {job.label}", file=stream)
        return 1
    return 0 if not missing else 3
