"""Every training run writes its per-epoch scalars as TensorBoard events beside metrics.jsonl; read back
with TensorBoard's own reader, they are the metrics rows, each epoch once, also across a resume."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("newton")


def test_events_hold_every_epoch_of_the_metrics_once(tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from algorithms.config import preset
    from harness.run.tensorboard import FOLDER, tag
    from harness.run.train import resume, train

    quiet = open("/dev/null", "w")
    run = tmp_path / "run"
    train(run, "ant", "newton", preset("shac-tdadpt").replace(num_envs=4, horizon=2), epochs=2, stream=quiet)
    resume(run, epochs=3, stream=quiet)
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    events = EventAccumulator(str(run / FOLDER))
    events.Reload()
    scalars = events.Tags()["scalars"]
    for name in ("train_reward_per_step", "actor_loss", "critic_loss", "actor_grad_nsr", "lam", "epoch_s", "env_steps"):
        assert tag(name) in scalars, name
        logged = events.Scalars(tag(name))
        assert [e.step for e in logged] == [0, 1, 2], name  # each epoch once, the resume included
        assert [e.value for e in logged] == pytest.approx([row[name] for row in rows], rel=1e-6), name
    assert tag("lam").startswith("adaptation/") and tag("actor_grad_nsr").startswith("gradient/")
