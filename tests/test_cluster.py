"""Scale-out: run-folder claims, two suites racing for one spec, and the Ray launcher against a real Ray head.

The claim tests use plain processes (milliseconds). The race runs two local suites on the point-mass
plug-in. The Ray test starts a Ray head on 127.0.0.1 (``ray start --head``, its own session, token
authentication with a token made for the test), runs a spec through ``bench --launcher ray``, SIGKILLs
the Ray worker running one of its runs mid-training, and checks that Ray retried it, that the retry
resumed from the last checkpoint, and that every table and metric equals the local launcher's.
"""

from __future__ import annotations

import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

import backends
from harness.run.folder_claims import LOST_CLAIM_EXIT, PREFIX, Claim, generations, holder
from harness.run.train import WALL_TIME_FIELDS

POINTMASS = pytest.mark.skipif("pointmass" not in backends.available(), reason="the point-mass plug-in is absent")


def _env(**extra) -> dict:
    return dict(os.environ, OMP_NUM_THREADS="1", PYTHONUNBUFFERED="1", **extra)


def _hold(run_dir: Path, seconds: float, heartbeat: float = 5.0) -> subprocess.Popen:
    """A process that claims ``run_dir``, says so, holds it ``seconds``, and releases it."""
    code = (
        "import sys, time\n"
        "from harness.run.folder_claims import Claim\n"
        f"c = Claim({str(run_dir)!r}, heartbeat_s={heartbeat}).acquire()\n"
        "print('held', flush=True)\n"
        f"time.sleep({seconds})\n"
        "c.release()\n"
        "print('released', time.time(), flush=True)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=_env())
    assert proc.stdout.readline().strip() == "held"
    return proc


# -- claims -----------------------------------------------------------------------------------------


def test_claim_is_exclusive_and_released(tmp_path):
    run = tmp_path / "run"
    with Claim(run) as claim:
        assert generations(run) == [1] and claim.generation == 1
        assert holder(run)["pid"] == os.getpid()
    assert generations(run) == []
    with Claim(run):  # free again: the same generation is taken anew
        assert generations(run) == [1]


def test_a_signal_while_the_claim_is_released_still_removes_it(tmp_path, monkeypatch):
    """A second Ctrl-C that lands while the heartbeat winds down raises out of the release: the claim
    file must go all the same, or the run stays held until another worker judges it stale."""
    run = tmp_path / "run"
    claim = Claim(run).acquire()
    heartbeat = claim._thread

    def interrupted_join(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(heartbeat, "join", interrupted_join)
    with pytest.raises(KeyboardInterrupt):
        claim.release()
    assert generations(run) == []
    monkeypatch.undo()
    heartbeat.join(timeout=30)
    assert not heartbeat.is_alive()


def test_a_live_holder_makes_the_next_worker_wait(tmp_path):
    run = tmp_path / "run"
    proc = _hold(run, seconds=2.0)
    log = []

    class Stream:
        def write(self, text):
            log.append(text)

        def flush(self):
            pass

    start = time.monotonic()
    with Claim(run, poll_s=0.1, stream=Stream()):
        waited, taken_at = time.monotonic() - start, time.time()
    word, released_at = proc.stdout.readline().split()
    # the holder's own clock says it had let go (its exit may come later on a loaded machine)
    assert word == "released" and taken_at >= float(released_at), "took the claim while its holder held it"
    assert waited > 1.0
    assert "waiting for it to finish or die" in "".join(log)
    proc.wait(timeout=10)


def test_a_dead_holder_on_this_machine_is_taken_over_at_once(tmp_path):
    run = tmp_path / "run"
    proc = _hold(run, seconds=60.0)
    proc.kill()
    proc.wait()
    start = time.monotonic()
    with Claim(run, stale_s=300.0, poll_s=0.1) as claim:  # no waiting for a heartbeat to age
        assert time.monotonic() - start < 5.0
        assert claim.generation == 2 and generations(run) == [1, 2]
    assert generations(run) == []  # the dead worker's claim goes with the new holder's release


def test_a_claim_from_another_machine_is_stale_only_when_its_heartbeat_stops(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    foreign = run / f"{PREFIX}1"
    foreign.write_text(json.dumps({"host": "elsewhere", "machine": "elsewhere/boot", "pid": 1, "since": "earlier"}))

    # a live worker elsewhere: its heartbeat moves, so the claim is never taken over
    import threading

    stop = threading.Event()

    def beat():
        while not stop.wait(0.1):
            os.utime(foreign)

    threading.Thread(target=beat, daemon=True).start()
    claim = Claim(run, stale_s=1.5, poll_s=0.05)
    taken = threading.Event()

    def take():
        claim.acquire()
        taken.set()

    threading.Thread(target=take, daemon=True).start()
    assert not taken.wait(3.0), "a claim whose heartbeat moves was taken over"
    stop.set()  # the worker elsewhere dies: its heartbeat stops
    assert taken.wait(5.0), "a claim whose heartbeat stopped was never taken over"
    assert claim.generation == 2
    claim.release()


def test_a_holder_presumed_dead_stops_without_writing(tmp_path):
    """A holder that finds a newer generation (another worker took over) exits with 75 at its next beat."""
    run = tmp_path / "run"
    proc = _hold(run, seconds=30.0, heartbeat=0.1)
    (run / f"{PREFIX}2").write_text("{}")  # another worker's takeover
    assert proc.wait(timeout=10) == LOST_CLAIM_EXIT


def test_racing_workers_never_hold_a_run_together(tmp_path):
    """Eight processes race for one run folder; each appends enter/leave lines while holding it."""
    run = tmp_path / "run"
    journal = tmp_path / "journal"
    code = (
        "import os, sys, time\n"
        "from harness.run.folder_claims import Claim\n"
        f"with Claim({str(run)!r}, poll_s=0.01):\n"
        f"    with open({str(journal)!r}, 'a') as fh: fh.write(f'enter {{os.getpid()}}\\n'); fh.flush()\n"
        "    time.sleep(0.05)\n"
        f"    with open({str(journal)!r}, 'a') as fh: fh.write(f'leave {{os.getpid()}}\\n'); fh.flush()\n"
    )
    procs = [subprocess.Popen([sys.executable, "-c", code], env=_env()) for _ in range(8)]
    assert all(p.wait(timeout=120) == 0 for p in procs)
    lines = journal.read_text().split()
    events = list(zip(lines[0::2], lines[1::2], strict=True))
    assert len(events) == 16
    for i in range(0, 16, 2):  # strictly enter, leave of the same process, one after the other
        assert events[i][0] == "enter" and events[i + 1] == ("leave", events[i][1]), events
    assert generations(run) == []


# -- two suites racing for one spec -----------------------------------------------------------------

RACE_SPEC = """
[suite]
name = "race"
jobs = 2

[eval]
seeds = 1
num_envs = 4

[[train]]
backends = ["pointmass"]
tasks = ["pointmass"]
algos = ["shac", "shac-tdadpt"]
seeds = [0]
horizons = [4]
epochs = 12
num_envs = 4
"""


def _rows(run: Path) -> list[dict]:
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    return [{k: v for k, v in row.items() if k not in WALL_TIME_FIELDS} for row in rows]


@POINTMASS
def test_two_suites_racing_for_one_spec_train_each_run_once(tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text(RACE_SPEC)
    store = tmp_path / "store"
    command = [sys.executable, "-m", "harness", "bench", "--spec", str(spec), "--store", str(store)]
    env = _env(DIFFSIM_BENCH_TEST_WRITE_DELAY="0.1")  # over a second per run, so the two really overlap
    first = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    second = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    outs = [p.communicate(timeout=600)[0] for p in (first, second)]
    assert first.returncode == 0 and second.returncode == 0, outs[0][-2000:] + outs[1][-2000:]
    runs = sorted((store / "race" / "runs").iterdir())
    assert len(runs) == 2
    logs = "".join(p.read_text() for p in (store / "race" / "logs").iterdir())
    assert "waiting for it to finish or die" in logs, "the suites never met on a run: nothing was tested"
    for run in runs:
        config = json.loads((run / "config.json").read_text())
        assert "resumed" not in config, f"{run.name} was trained by both suites"
        assert [r["epoch"] for r in _rows(run)] == list(range(12))
        assert (run / "eval.json").is_file() and generations(run) == []


# -- the Ray launcher against a real Ray head -------------------------------------------------------

# one critic pass per epoch: the launcher's mechanics are under test with Ray, not the critic
FAST_CRITIC = "\nhyperparameters = { critic_iterations = 1 }"
RAY_SPEC = (
    RACE_SPEC.replace('name = "race"', 'name = "cluster"').replace("epochs = 12", "epochs = 24" + FAST_CRITIC)
    + """
[[check]]              # fails when it runs (FAIL, exit 1; the spec is valid): the progress must name it
kind = "gradcheck"
backends = ["pointmass"]
tasks = ["pointmass"]
args = ["--tolerance", "1e-30"]
"""
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _session_of(pid: int) -> int | None:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[3])
    except (OSError, ValueError, IndexError):
        return None


@pytest.fixture(scope="module")
def ray_head():
    """A Ray head on 127.0.0.1 in a session of its own; every process of that session is killed after."""
    pytest.importorskip("ray", reason="the [ray] extra is not installed (tox -e py installs it)")
    ray_cli = Path(sys.executable).parent / "ray"
    port = _free_port()
    temp_dir = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths have a length limit
    env = _env(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32), RAY_USAGE_STATS_ENABLED="0")
    argv = [str(ray_cli), "start", "--head", "--node-ip-address", "127.0.0.1", "--port", str(port)]
    argv += ["--num-cpus", "2", "--include-dashboard", "false", "--temp-dir", temp_dir, "--disable-usage-stats"]
    start = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env,
                             start_new_session=True)  # fmt: skip
    session = start.pid
    try:
        out, _ = start.communicate(timeout=120)
        assert start.returncode == 0, out[-3000:]
        yield {"address": f"127.0.0.1:{port}", "env": env}
    finally:
        for _ in range(3):  # the head's daemons and workers all live in the session `ray start` opened
            pids = [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit()]
            members = [pid for pid in pids if _session_of(pid) == session]
            if not members:
                break
            for pid in members:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            time.sleep(1.0)


def _tables(store: Path) -> dict[str, str]:
    """The tables whose content is the runs' results (wall time and throughput differ by nature)."""
    return {
        name: (store / name).read_text()
        for name in ("returns.csv", "grad_variance_vs_h.csv", "grad_variance_vs_h_growth.csv")
    }


@POINTMASS
def test_ray_launcher_matches_local_and_survives_a_killed_worker(tmp_path, ray_head):
    spec = tmp_path / "spec.toml"
    spec.write_text(RAY_SPEC)
    local_store, ray_store = tmp_path / "local", tmp_path / "ray"
    local = subprocess.run(
        [sys.executable, "-m", "harness", "bench", "--spec", str(spec), "--store", str(local_store)],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=600,
    )
    assert local.returncode == 1, local.stdout[-2000:] + local.stderr[-2000:]  # the failing check

    env = dict(ray_head["env"], DIFFSIM_BENCH_TEST_WRITE_DELAY="0.1")  # ~0.1 s per epoch: time to kill mid-run
    command = [sys.executable, "-m", "harness", "bench", "--spec", str(spec), "--store", str(ray_store)]
    command += ["--launcher", "ray", "--address", ray_head["address"]]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    runs_dir = ray_store / "cluster" / "runs"
    victim, worker = None, None
    deadline = time.time() + 300
    while time.time() < deadline and victim is None:
        for run in runs_dir.glob("*") if runs_dir.exists() else []:
            info = holder(run)
            metrics = run / "metrics.jsonl"
            if info and "pid" in info and metrics.exists() and len(metrics.read_text().splitlines()) >= 5:
                stat = Path(f"/proc/{info['pid']}/stat").read_text()
                worker = int(stat.rsplit(")", 1)[1].split()[1])  # the Ray worker that runs the job's process
                victim = run
                break
        time.sleep(0.1)
    assert victim is not None, "no run reached epoch 5 under Ray"
    os.kill(worker, signal.SIGKILL)
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 1, out[-3000:]  # everything done but the failing check
    assert "start (ray at 127.0.0.1" in out and "running" in out
    failed = [line for line in out.splitlines() if "failed gradcheck pointmass/pointmass" in line]
    assert failed and "(exit 1; see " in failed[0], out[-3000:]

    # Ray retried the run and the retry resumed it from its checkpoint: every epoch once, in order
    config = json.loads((victim / "config.json").read_text())
    assert len(config.get("resumed", [])) == 1, "the killed run was not resumed from its checkpoint"
    log = next((ray_store / "cluster" / "logs").glob(f"{victim.name}*.log")).read_text()
    assert log.count("[ray worker") == 2, log[-2000:]
    assert generations(victim) == []

    # the same folders, and every result equal to the local launcher's uninterrupted runs
    local_runs = sorted(p.name for p in (local_store / "cluster" / "runs").iterdir())
    assert sorted(p.name for p in runs_dir.iterdir()) == local_runs
    for name in local_runs:
        assert _rows(runs_dir / name) == _rows(local_store / "cluster" / "runs" / name), name
        ray_eval = json.loads((runs_dir / name / "eval.json").read_text())
        local_eval = json.loads((local_store / "cluster" / "runs" / name / "eval.json").read_text())
        assert ray_eval["final"] == local_eval["final"], name
    assert _tables(ray_store / "cluster") == _tables(local_store / "cluster")


SWEEP = ["--backend", "pointmass", "--task", "pointmass", "--algos", "shac", "shac-tdadpt", "--seeds", "0"]
SWEEP += ["--epochs", "3", "--num-envs", "4", "--horizon", "4", "--eval-seeds", "1"]


def _sweep(out: Path, *extra: str, env: dict | None = None) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "harness", "sweep", *SWEEP, "--out", str(out), *extra],
        capture_output=True,
        text=True,
        env=env or _env(),
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return done.stdout


def _sweep_runs(out: Path) -> list[str]:
    """The sweep's run folders: the suite's addressed runs (``OUT/runs/TASK_BACKEND_ALGO_hH_sS_KEY``)."""
    return sorted(p.name for p in (out / "runs").iterdir() if (p / "config.json").is_file())


@pytest.fixture(scope="module")
def sweep_in_one_process(tmp_path_factory) -> Path:
    """The reference: the sweep's runs trained one after another (one job at a time)."""
    out = tmp_path_factory.mktemp("sweep") / "one"
    _sweep(out)
    return out


@POINTMASS
def test_sweep_is_a_suite_and_two_jobs_give_the_runs_of_one(tmp_path, sweep_in_one_process):
    stdout = _sweep(tmp_path / "pool", "--jobs", "2")
    assert "jobs 2/2 (runs 2/2; 0 running" in stdout  # the suite's runner, two processes
    names = _sweep_runs(sweep_in_one_process)
    assert len(names) == 2 and _sweep_runs(tmp_path / "pool") == names  # the same addresses
    for name in names:
        assert _rows(tmp_path / "pool" / "runs" / name) == _rows(sweep_in_one_process / "runs" / name)
    assert (tmp_path / "pool" / "logs").is_dir() and (tmp_path / "pool" / "returns.md").is_file()


@POINTMASS
def test_sweep_on_ray_writes_the_same_runs(tmp_path, ray_head, sweep_in_one_process):
    _sweep(tmp_path / "ray", "--launcher", "ray", "--address", ray_head["address"], env=ray_head["env"])
    for name in _sweep_runs(sweep_in_one_process):
        assert _rows(tmp_path / "ray" / "runs" / name) == _rows(sweep_in_one_process / "runs" / name)
        ray_eval = json.loads((tmp_path / "ray" / "runs" / name / "eval.json").read_text())
        local_eval = json.loads((sweep_in_one_process / "runs" / name / "eval.json").read_text())
        assert ray_eval["final"] == local_eval["final"]


@POINTMASS
def test_ctrl_c_stops_a_ray_suite_resumably(tmp_path, ray_head):
    """SIGINT to the driver: the jobs on the Ray workers checkpoint and stop (exit 130), claims are released,
    and the same command finishes every run with each epoch once."""
    spec = tmp_path / "spec.toml"
    spec.write_text(RACE_SPEC.replace("epochs = 12", "epochs = 40" + FAST_CRITIC))
    store = tmp_path / "store"
    command = [sys.executable, "-m", "harness", "bench", "--spec", str(spec), "--store", str(store)]
    command += ["--launcher", "ray", "--address", ray_head["address"]]
    env = dict(ray_head["env"], DIFFSIM_BENCH_TEST_WRITE_DELAY="0.1")
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    runs = store / "race" / "runs"
    deadline = time.time() + 300
    while time.time() < deadline:
        metrics = list(runs.glob("*/metrics.jsonl")) if runs.exists() else []
        if len(metrics) == 2 and min(len(m.read_text().splitlines()) for m in metrics) >= 3:
            break
        time.sleep(0.1)
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 130, out[-3000:]
    for run in runs.iterdir():
        assert not (run / "eval.json").exists(), "a run finished before the signal: nothing was interrupted"
        assert generations(run) == [], "a stopped job kept its claim"
        assert "SIGINT: finishing this epoch" in next((store / "race" / "logs").glob(f"{run.name}*.log")).read_text()
    again = subprocess.run(command, capture_output=True, text=True, env=ray_head["env"], timeout=600)
    assert again.returncode == 0, again.stdout[-3000:]
    for run in runs.iterdir():
        assert [r["epoch"] for r in _rows(run)] == list(range(40)), run.name
        assert (run / "eval.json").is_file()


def _listener(answer: bytes | None):
    """A TCP server on 127.0.0.1 that is not a Ray head: it sends ``answer`` to whoever connects (None:
    stays silent) and keeps the connection open."""
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    held = []

    def serve():
        conn, _ = server.accept()
        held.append(conn)
        if answer is not None:
            conn.recv(64)
            conn.sendall(answer)

    threading.Thread(target=serve, daemon=True).start()
    return server, held, f"127.0.0.1:{server.getsockname()[1]}"


@pytest.mark.parametrize(
    "answer, needle",
    [(None, "no answer within 1 s"), (b"HTTP/1.0 400 Bad Request\r\n\r\n", "not a Ray head (no gRPC answer)")],
    ids=["silent", "a web server"],
)
def test_an_address_where_no_ray_head_listens_is_refused_in_one_line_within_the_timeout(
    answer, needle, tmp_path, monkeypatch, capsys
):
    pytest.importorskip("ray", reason="the [ray] extra is not installed (tox -e py installs it)")
    from harness.cli import main
    from harness.suite import launchers

    monkeypatch.setattr(launchers, "CONNECT_TIMEOUT_S", 1.0)
    server, held, address = _listener(answer)  # ``held``: the accepted connection, open until the test ends
    started = time.monotonic()
    with server:
        argv = ["bench", "--profile", "smoke", "--launcher", "ray", "--address", address, "--store", str(tmp_path)]
        code = main(argv)
    assert held and code == 2 and time.monotonic() - started < 30
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err, err
