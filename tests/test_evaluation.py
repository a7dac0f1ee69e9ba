"""What an evaluation records beside the return: the forward velocity (tasks.base.Task.forward_velocity),
sampled at the start of every step of each env's first episode and averaged, so that a reset state never
enters it."""

from __future__ import annotations

import dataclasses
import json
import shutil

import pytest
import torch

pytest.importorskip("newton")

from harness.run.train import evaluate  # noqa: E402
from tasks.ant import Ant  # noqa: E402


def test_the_forward_velocity_is_the_first_episodes_mean_from_each_steps_start(
    one_epoch_ant_run, tmp_path, monkeypatch
):
    run = tmp_path / "run"
    shutil.copytree(one_epoch_ant_run, run)
    calls = []

    def counting(self, state):  # the k-th call of an evaluation returns k for every env
        calls.append(None)
        return torch.full((state.joint_q.shape[0],), float(len(calls) - 1))

    steps = 6
    monkeypatch.setattr(Ant, "forward_velocity", counting)
    evaluate(run, seeds=1, num_envs=2, max_steps=steps, stream=open("/dev/null", "w"))
    payload = json.loads((run / "eval.json").read_text())
    # two policies, one seed each, one call per step: the initial policy's calls 0..5, the final's 6..11
    first = payload["initial"]["per_seed"][0]["mean_forward_velocity"]
    assert first == pytest.approx(sum(range(steps)) / steps)
    assert payload["initial"]["mean_forward_velocity"] == first
    assert payload["final"]["mean_forward_velocity"] == pytest.approx(sum(range(steps, 2 * steps)) / steps)
    assert len(calls) == 2 * steps


def test_the_ant_reports_its_roots_velocity_along_x():
    from harness.envs import make_env

    env = make_env("ant", "newton", 2)
    state = env.sim.state
    assert torch.allclose(env.task.forward_velocity(state), state.joint_qd[:, 0])
    qd = state.joint_qd.clone()
    qd[:, 0] = torch.tensor([0.5, -1.0])
    assert env.task.forward_velocity(dataclasses.replace(state, joint_qd=qd)).tolist() == [0.5, -1.0]
