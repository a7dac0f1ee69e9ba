"""grad-paths: its "as in training" rollout is training's own window, and each switch removes exactly
the path it names."""

from __future__ import annotations

import pytest

pytest.importorskip("newton")

from harness.checks.grad_paths import grad_paths  # noqa: E402
from harness.cli import main as cli  # noqa: E402


def _run(horizon: int) -> dict:
    return grad_paths("ant", "newton", epochs=1, num_envs=4, horizon=horizon, progress=lambda line: None)


def test_the_training_variant_is_the_gradient_training_logs_and_one_step_has_no_feedback_path():
    one = _run(horizon=1)
    norms = one["rows"][0]["norms"]
    # the same window, the same loss: the norm train_epoch logs before clipping
    assert norms["as in training"] == pytest.approx(one["rows"][0]["logged_actor_grad_norm"], rel=1e-5)
    # one step: the policy reads only the window's first observation, which the graph cut detaches
    assert norms["no feedback"] == norms["as in training"] and norms["neither"] == norms["no bootstrap"]
    # ...but the bootstrap value at the next state depends on the action
    assert norms["no bootstrap"] != norms["as in training"]
    two = _run(horizon=2)["rows"][0]["norms"]
    assert two["no feedback"] != two["as in training"]


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--algo", "ppo"], "ppo"),
        (["--backend-option", "graph_capture=2"], "graph_capture"),
        (["--num-envs", "6"], "num_envs=6"),
    ],
)
def test_bad_input_is_one_line(capsys, extra, needle):
    assert cli(["grad-paths", "--backend", "newton", "--task", "ant", "--epochs", "1", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and needle in err, err
