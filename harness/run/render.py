"""``python -m harness render --run DIR``: a run's final policy, seen.

The policy acts deterministically in one env (evaluation seed 10,000, as ``eval``'s first) on the run's
own backend, another one (``--backend``, sim-to-sim), or both side by side (``--compare``), for at
most ``steps`` control steps or until its episode ends. ``frames`` states evenly spaced over that
window are drawn (:mod:`backends.render`: MuJoCo's offscreen renderer for rigid tasks, the tet mesh's
surface for the SoftJumper) and written as a video (MP4 through ffmpeg: the PATH's, else the static
build of the pinned imageio-ffmpeg; an animated GIF where neither runs) and a PNG filmstrip of six of
them, each labelled with its step and the return so far.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from harness.results import RunError, atomic_write_bytes, out_problem, provenance, slow_write_for_tests, write_json

FILMSTRIP_FRAMES = 6
EVAL_SEED = 10_000  # evaluate()'s first seed


def rollout(run_dir: Path, config: dict, backend: str, steps: int) -> tuple[object, list[np.ndarray], list[float]]:
    """The task, env 0's state before each step (what the scene draws) and the return so far; ``config``:
    the run's, as :func:`harness.run.folder.open_run` checked it for ``backend``."""
    from algorithms.actor_critic import FirstOrderActorCritic
    from backends.render import state_picture_input
    from harness.envs import make_env, run_task
    from harness.run.folder import CHECKPOINT
    from harness.run.train import load_checkpoint

    cfg = config["algo_config"]
    torch.manual_seed(EVAL_SEED)
    options = config.get("backend_options") if backend == config["backend"] else None
    env = make_env(run_task(config), backend, 1, config["device"], EVAL_SEED, cfg.horizon, options=options)
    algo = FirstOrderActorCritic(cfg, env.obs_dim, env.action_dim)
    load_checkpoint(run_dir / CHECKPOINT, algo)
    obs = env.reset()
    states, returns, total = [], [], 0.0
    with torch.no_grad():
        for _ in range(steps):
            states.append(state_picture_input(env.task, env.sim.state))
            returns.append(total)
            step = env.step(algo.act(obs, deterministic=True))
            total += float(step.reward[0])
            obs = step.obs
            if bool(step.done[0]):  # the env has reset: the episode's last state is not drawn twice
                break
    return env.task, states, returns


def _label(image: np.ndarray, text: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    draw.rectangle((0, 0, picture.width, 18), fill=(255, 255, 255))
    draw.text((4, 3), text, fill=(0, 0, 0))
    return np.asarray(picture)


def frames_of(run_dir: Path, config: dict, backend: str, steps: int, frames: int) -> tuple[list[np.ndarray], list[int]]:
    """``frames`` labelled pictures of the policy on ``backend`` and the steps they show."""
    from backends.render import scene_for

    task, states, returns = rollout(run_dir, config, backend, steps)
    picks = sorted(set(np.linspace(0, len(states) - 1, min(frames, len(states))).round().astype(int).tolist()))
    scene = scene_for(task)
    try:
        pictures = [_label(scene.frame(states[k]), f"{backend}  step {k}  return {returns[k]:.1f}") for k in picks]
    finally:
        scene.close()
    return pictures, picks


def ffmpeg_executable() -> str | None:
    """ffmpeg on the PATH, else the static build the pinned imageio-ffmpeg ships, else None."""
    found = shutil.which("ffmpeg")
    if found:
        return found
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):  # not installed, or no build for this platform
        return None


PARTIAL = ".part"  # a video being written: ``.NAME.mp4.PID.part``


def remove_leftovers(folder: Path, stream=None) -> None:
    """Remove what an interrupted render left in ``folder``: partial videos whose writer is gone, and
    the ``tmpXXXXXXXX.mp4`` files earlier versions wrote there (a real video extension on half a video)."""
    from harness.run.folder_claims import process_alive

    for path in folder.glob(f".*{PARTIAL}"):
        pid = path.name.removesuffix(PARTIAL).rpartition(".")[2]
        if pid.isdigit() and not process_alive(int(pid)):
            path.unlink(missing_ok=True)
            print(f"removed {path.name}: a video an interrupted render left", file=stream or sys.stdout)
    for path in folder.glob("tmp*.mp4"):
        if re.fullmatch(r"tmp[a-z0-9_]{8}\.mp4", path.name):
            path.unlink(missing_ok=True)
            print(f"removed {path.name}: a video an interrupted render left", file=stream or sys.stdout)


def write_video(pictures: list[np.ndarray], stem: Path, fps: int = 10) -> Path:
    """MP4 through ffmpeg (:func:`ffmpeg_executable`), else an animated GIF; written whole or not at all."""
    ffmpeg = ffmpeg_executable()
    if ffmpeg:
        out = stem.with_suffix(".mp4")
        height, width = pictures[0].shape[:2]
        partial = out.with_name(f".{out.name}.{os.getpid()}{PARTIAL}")  # no video extension: never taken for one
        command = [ffmpeg, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24"]
        command += ["-s", f"{width}x{height}", "-r", str(fps), "-i", "-", "-pix_fmt", "yuv420p", "-f", "mp4"]
        try:
            subprocess.run([*command, str(partial)], input=b"".join(p.tobytes() for p in pictures), check=True)
            slow_write_for_tests()
            partial.replace(out)
        except BaseException:
            partial.unlink(missing_ok=True)
            raise
        return out
    import io

    from PIL import Image

    first, *rest = [Image.fromarray(p) for p in pictures]
    buffer = io.BytesIO()
    first.save(buffer, format="GIF", save_all=True, append_images=rest, duration=int(1000 / fps), loop=0)
    return atomic_write_bytes(stem.with_suffix(".gif"), buffer.getvalue())


def write_filmstrip(pictures: list[np.ndarray], path: Path) -> Path:
    """Six of the pictures, evenly spaced, in a row (PNG, written whole or not at all)."""
    import io

    from PIL import Image

    picks = np.linspace(0, len(pictures) - 1, min(FILMSTRIP_FRAMES, len(pictures))).round().astype(int)
    buffer = io.BytesIO()
    Image.fromarray(np.concatenate([pictures[k] for k in picks], axis=1)).save(buffer, format="PNG")
    return atomic_write_bytes(path, buffer.getvalue())


def render(run_dir: str | Path, backends: list[str], steps: int, frames: int, stream=None) -> list[Path]:
    """Write the video and filmstrip of the run's final policy on ``backends`` (two: side by side). The run
    folder is checked for every backend before the first frame."""
    from backends.contract import BackendError
    from harness.run.folder import CHECKPOINT, open_run

    run_dir = Path(run_dir)
    stream = stream or sys.stdout
    configs = [open_run(run_dir, (CHECKPOINT,), backend) for backend in backends]
    stem = record_stem(run_dir, backends)
    for path in (stem.with_suffix(".mp4"), stem.with_suffix(".gif"), _filmstrip(stem), stem.with_suffix(".json")):
        problem = out_problem(path, "file", flag="render's output")
        if problem:  # before the first frame, not after the last
            raise RunError(problem)
    remove_leftovers(run_dir, stream)
    panels = []
    for backend, config in zip(backends, configs, strict=True):
        print(f"render {run_dir.name} on {backend}: {steps} steps at most, {frames} frames", file=stream, flush=True)
        try:
            panels.append(frames_of(run_dir, config, backend, steps, frames)[0])
        except (BackendError, ValueError, TypeError) as exc:  # an engine that cannot build the task
            raise RunError(f"render on {backend}: {backend} cannot run {config['task']}: {exc}") from None
    # an episode that ends earlier on one engine keeps showing its last frame beside the other
    longest = max(len(p) for p in panels)
    pictures = [np.concatenate([p[min(k, len(p) - 1)] for p in panels], axis=1) for k in range(longest)]
    written = [write_video(pictures, stem), write_filmstrip(pictures, _filmstrip(stem))]
    record = {"backends": backends, "max_steps": steps, "frames": frames, "steps_shown": [len(p) for p in panels]}
    record |= {"files": [p.name for p in written], "provenance": provenance()}
    written.append(write_json(stem.with_suffix(".json"), record))
    print(f"wrote {', '.join(str(p) for p in written)}", file=stream, flush=True)
    return written


def compared_backends(trained_on: str, task: str) -> list[str]:
    """``--compare``'s engines: the one the run trained on, then the first other installed engine (in the
    adapters' table order) that drives the task's control kind."""
    from harness.envs import engines_for

    others = [name for name in engines_for(task) if name != trained_on]
    if not others:
        raise RunError(f"--compare needs a second installed engine besides {trained_on} that drives {task}")
    return [trained_on, others[0]]


def _filmstrip(stem: Path) -> Path:
    return stem.with_name(stem.name + "_filmstrip.png")


def record_stem(run_dir: Path, backends: list[str]) -> Path:
    """``RUN/render_BACKEND`` or ``RUN/render_compare``: the stem of the video, filmstrip and record."""
    return Path(run_dir) / ("render_compare" if len(backends) > 1 else f"render_{backends[0]}")
