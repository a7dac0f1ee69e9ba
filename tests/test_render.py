"""``render``: a video and a filmstrip of a run's policy, headless; the frames exist, change over time and
show the robot (pixels that differ from the same view without it)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("newton")
pytest.importorskip("mujoco")

ROOT = Path(__file__).resolve().parents[1]


def _env() -> dict:
    return os.environ | {"MUJOCO_GL": "egl", "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}


@pytest.fixture
def run(one_epoch_ant_run, tmp_path) -> Path:
    shutil.copytree(one_epoch_ant_run, tmp_path / "run")
    return tmp_path / "run"


def _video_frames(video: Path) -> list[np.ndarray]:
    """The frames of a written video, decoded (MP4 by ffmpeg, GIF by Pillow), as int RGB arrays."""
    if video.suffix == ".mp4":
        import imageio_ffmpeg

        reader = imageio_ffmpeg.read_frames(str(video))
        width, height = next(reader)["size"]
        return [np.frombuffer(f, np.uint8).reshape(height, width, 3).astype(int) for f in reader]
    from PIL import Image, ImageSequence

    return [np.asarray(f.convert("RGB"), dtype=int) for f in ImageSequence.Iterator(Image.open(video))]


@pytest.mark.parametrize("encoder", ["mp4", "gif"])
def test_a_video_holds_every_picture_in_order(encoder, tmp_path, monkeypatch):
    """Both encoders, on pictures whose brightness counts the frame: MP4 through ffmpeg (the pinned static
    build when none is installed), an animated GIF where no ffmpeg runs; no temporary file left behind."""
    import harness.run.render as render

    if encoder == "gif":
        monkeypatch.setattr(render, "ffmpeg_executable", lambda: None)
    else:
        assert render.ffmpeg_executable() is not None  # imageio-ffmpeg is a dependency
    pictures = [np.full((48, 64, 3), 20 + 40 * k, np.uint8) for k in range(6)]
    video = render.write_video(pictures, tmp_path / "clip")
    assert video == tmp_path / f"clip.{encoder}" and sorted(tmp_path.iterdir()) == [video]
    frames = _video_frames(video)
    assert len(frames) == 6 and frames[0].shape == (48, 64, 3)
    brightness = [float(f.mean()) for f in frames]
    assert brightness == sorted(brightness) and abs(brightness[-1] - 220) < 8, brightness


def test_render_writes_a_video_and_a_filmstrip_that_move(run):
    from PIL import Image

    out = subprocess.run(
        [sys.executable, "-m", "harness", "render", "--run", str(run), "--max-steps", "30", "--frames", "5"],
        capture_output=True,
        text=True,
        env=_env(),
        cwd=ROOT,
        timeout=600,
    )
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    (video,) = [p for p in run.glob("render_newton.*") if p.suffix in (".gif", ".mp4")]
    assert f"wrote {video}" in out.stdout and video.suffix == ".mp4"  # the pinned ffmpeg build encodes
    frames = _video_frames(video)
    assert len(frames) == 5
    assert np.abs(frames[0] - frames[-1]).sum(-1).astype(bool).mean() > 0.01  # the scene changed
    strip = Image.open(run / "render_newton_filmstrip.png")
    assert strip.size == (5 * 480, 360)


def test_a_rigid_frame_shows_the_robot():
    """The same camera with the robot in view and moved 100 m away: the robot covers pixels."""
    script = """
import json, numpy as np, torch
from backends.render import RigidScene
from tasks import make_task
for name, height in (("ant", 0.6), ("go2", 0.35)):
    task = make_task(name)
    scene = RigidScene(task)
    q = torch.zeros(task.layout.nq, dtype=torch.float64).numpy()
    q[2], q[6] = height, 1.0
    far = q.copy()
    far[0] += 100.0
    seen, empty = scene.frame(q).astype(int), scene.frame(far, lookat=q[:3]).astype(int)
    print(json.dumps({"task": name, "robot": float((np.abs(seen - empty).sum(-1) > 30).mean())}))
"""
    out = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=_env(), cwd=ROOT, timeout=600
    )
    assert out.returncode == 0, out.stderr[-2000:]
    for line in out.stdout.splitlines():
        result = json.loads(line)
        assert result["robot"] > 0.01, result


def test_a_soft_frame_draws_the_meshs_surface():
    from backends.render import SoftScene
    from tasks import make_task

    task = make_task("soft_jumper")
    scene = SoftScene(task)
    rest = task.soft_body.vertices.numpy()
    image = scene.frame(rest)
    assert image.shape == (360, 480, 3)
    orange = (image[..., 0] > 180) & (image[..., 1] > 100) & (image[..., 1] < 170) & (image[..., 2] < 110)
    assert orange.mean() > 0.01  # the body's faces
    assert len(scene.surface) < 4 * task.soft_body.num_tets  # boundary faces only
    lifted = scene.frame(rest + np.array([0.0, 0.0, 0.5]))
    assert np.abs(lifted.astype(int) - image.astype(int)).sum() > 0  # a moved body is drawn elsewhere


def test_a_killed_render_leaves_no_video_and_a_rerun_clears_what_older_ones_left(run):
    """SIGTERM while the video is written: exit 143, no file with a video extension and no partial video
    in the run folder. What earlier interrupted renders left (a partial video of a writer that is gone,
    an older version's ``tmpXXXXXXXX.mp4``) is removed by the next render, and nothing else."""
    import signal
    import time

    (run / "tmpab12cd34.mp4").write_bytes(b"half a video")
    (run / ".render_newton.mp4.999999999.part").write_bytes(b"half a video")  # no such process
    (run / "notes.mp4").write_bytes(b"the user's own")  # not a name a render writes: kept
    command = [sys.executable, "-m", "harness", "render", "--run", str(run), "--max-steps", "4", "--frames", "2"]
    env = _env() | {"DIFFSIM_BENCH_TEST_WRITE_DELAY": "60"}  # the partial video waits a minute for its rename
    proc = subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None and not list(run.glob(f".render_newton.mp4.{proc.pid}.part")):
        time.sleep(0.1)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143 and "stopped: SIGTERM" in err, out[-2000:] + err[-2000:]
    assert "removed tmpab12cd34.mp4" in out and "removed .render_newton.mp4.999999999.part" in out, out
    left = sorted(p.name for p in run.iterdir() if ".mp4" in p.name or p.name.endswith(".part"))
    assert left == ["notes.mp4"], left


def test_compare_picks_the_next_installed_engine_that_drives_the_task():
    """``--compare`` reads the engines from the registry in their adapters' table order: the reference
    engine beside any other, and an engine that cannot drive the task's control kind is passed over."""
    from harness.envs import engines_for
    from harness.run.render import compared_backends

    assert compared_backends("mujoco_warp", "ant") == ["mujoco_warp", "newton"]
    assert compared_backends("newton", "go2") == ["newton", "mujoco_warp"]
    assert "pointmass" not in engines_for("go2")  # position targets: the point mass drives forces only
