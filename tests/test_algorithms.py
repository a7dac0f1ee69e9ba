"""SHAC/SAPO/TD-lambda invariants, actor-gradient variance, robustness and resume, on the Newton Ant."""

from __future__ import annotations

import json

import pytest
import torch

pytest.importorskip("newton")

from algorithms.actor_critic import FirstOrderActorCritic  # noqa: E402
from algorithms.config import PRESETS, preset  # noqa: E402
from algorithms.grad_variance import gradient_variance  # noqa: E402
from backends import make  # noqa: E402
from harness.cli import main as cli  # noqa: E402
from harness.train import RunError, save_checkpoint, train  # noqa: E402
from tasks import make_task  # noqa: E402
from tasks.env import TaskEnv  # noqa: E402

N, H = 8, 6


@pytest.fixture(scope="module")
def env():
    task = make_task("ant")
    return TaskEnv(task, make("newton", task, num_envs=N, seed=0, max_graph_steps=64))


def _algo(name: str, seed: int = 0, **changes) -> FirstOrderActorCritic:
    torch.manual_seed(seed)
    cfg = preset(name).replace(num_envs=N, horizon=H, critic_iterations=2, max_epochs=10, **changes)
    return FirstOrderActorCritic(cfg, obs_dim=37, act_dim=8)


def _window_loss_grad(algo, env, start_state, seed=1):
    env.load_state_dict(start_state)
    torch.manual_seed(seed)
    w = algo.rollout(env)
    loss = algo.actor_loss(w)
    algo.actor.zero_grad()
    loss.backward()
    grads = torch.cat([p.grad.reshape(-1) for p in algo.actor.parameters()])
    return w, loss.detach(), grads


def test_tdfixed_with_lambda_one_is_shac(env):
    env.reset()
    start = env.state_dict()
    _, loss_shac, grad_shac = _window_loss_grad(_algo("shac"), env, start)
    _, loss_td, grad_td = _window_loss_grad(_algo("shac-tdfixed", lam=1.0), env, start)
    assert torch.allclose(loss_td, loss_shac, rtol=1e-5, atol=1e-6)
    assert torch.allclose(grad_td, grad_shac, rtol=1e-4, atol=1e-6)
    # and lambda < 1 really changes the loss (the comparison above can fail)
    _, loss_095, _ = _window_loss_grad(_algo("shac-tdfixed"), env, start)
    assert not torch.allclose(loss_095, loss_shac, rtol=1e-4)


def test_lambda_update_moves_only_lambda(env):
    env.reset()
    algo = _algo("shac-tdadpt", lambda_lr=1e-1)
    w = algo.rollout(env)
    frozen = {k: v.clone() for k, v in algo.state_dict().items() if k != "phi"}
    lam_before = float(algo.lam.detach())
    algo.update_lambda(w)
    after = algo.state_dict()
    assert all(torch.equal(frozen[k], after[k]) for k in frozen), "actor/critic/normaliser changed"
    assert float(algo.lam.detach()) != lam_before
    assert 0.0 < float(algo.lam.detach()) < 1.0


def test_lambda_stays_strictly_inside_unit_interval(env):
    env.reset()
    algo = _algo("shac-tdadpt", lambda_lr=5.0)  # absurd step size drives phi to its limit
    w = algo.rollout(env)
    for _ in range(200):
        algo.update_lambda(w)
    assert 0.0 < float(algo.lam.detach()) < 1.0


def test_lambda_schedule_every_second_epoch():
    algo = _algo("sapo-tdadpt", lambda_iterations=0.5)
    assert [algo.lambda_update_due(e) for e in range(4)] == [True, False, True, False]
    assert not _algo("sapo-tdfixed").lambda_update_due(0)


def test_group_gradients_sum_to_the_actor_gradient(env):
    env.reset()
    algo = _algo("sapo-tdadpt")
    w, _, full = _window_loss_grad(algo, env, env.state_dict())
    groups = algo.group_gradients(w)
    assert groups.shape == (algo.cfg.grad_var_groups, full.numel())
    assert torch.allclose(groups.mean(0), full, rtol=1e-4, atol=1e-6 * full.abs().max())
    assert gradient_variance(groups) > 0


def test_gradient_variance_is_zero_for_identical_groups(env):
    algo = _algo("shac")
    algo.actor.logstd.data.fill_(-40.0)  # no exploration noise: identical envs stay identical
    env.reset()
    state = env.state_dict()
    for key in ("joint_q", "joint_qd", "engine"):
        state["sim_state"][key][:] = state["sim_state"][key][0]
    state["obs"][:] = state["obs"][0]
    w, _, full = _window_loss_grad(algo, env, state)
    var = float(gradient_variance(algo.group_gradients(w)))
    assert var <= 1e-8 * float(full.pow(2).sum()) * algo.cfg.grad_var_groups


def test_nan_gradient_skips_the_update_and_keeps_weights(env, monkeypatch):
    env.reset()
    algo = _algo("shac")
    before = {k: v.clone() for k, v in algo.actor.state_dict().items()}
    original = env.task.reward

    def poisoned(state, obs, actions):
        r = original(state, obs, actions)
        return r + torch.where(torch.arange(N) == 3, torch.tensor(float("nan")), torch.tensor(0.0))

    monkeypatch.setattr(env.task, "reward", poisoned)
    metrics = algo.train_epoch(env)
    monkeypatch.undo()
    assert metrics["actor_update_skipped"] is True
    assert all(torch.equal(before[k], v) for k, v in algo.actor.state_dict().items())
    assert algo.parameters_finite()


def test_checkpoint_refuses_non_finite_weights(tmp_path):
    algo = _algo("shac")
    next(algo.actor.parameters()).data[0] = float("nan")
    with pytest.raises(RunError, match="non-finite"):
        save_checkpoint(tmp_path / "ckpt.pt", algo, None, {})
    assert not (tmp_path / "ckpt.pt").exists()


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_algorithm_runs_an_epoch(env, name):
    env.reset()
    algo = _algo(name)
    metrics = algo.train_epoch(env)
    assert not metrics["actor_update_skipped"]
    assert metrics["actor_grad_var"] > 0
    assert 0.0 < metrics["lam"] < 1.0
    assert (metrics["alpha"] > 0) == name.startswith("sapo")


def _rows(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_resume_continues_the_same_run(tmp_path, monkeypatch):
    cfg = preset("shac-tdadpt").replace(num_envs=4, horizon=4, critic_iterations=2)
    train(tmp_path / "full", "ant", "newton", cfg, epochs=4, seed=3, checkpoint_every=1)

    real_epoch = FirstOrderActorCritic.train_epoch

    def interrupted_at_epoch_3(self, env):
        if self.epoch == 3:
            raise KeyboardInterrupt  # Ctrl-C in the middle of the fourth epoch
        return real_epoch(self, env)

    monkeypatch.setattr(FirstOrderActorCritic, "train_epoch", interrupted_at_epoch_3)
    with pytest.raises(KeyboardInterrupt):
        train(tmp_path / "cut", "ant", "newton", cfg, epochs=4, seed=3, checkpoint_every=2)
    monkeypatch.undo()
    # the last periodic checkpoint was epoch 2; the interrupt wrote one at epoch 3
    assert len(_rows(tmp_path / "cut" / "metrics.jsonl")) == 3
    train(tmp_path / "cut", "", "", cfg, epochs=0, resume=True, checkpoint_every=2)
    full, cut = _rows(tmp_path / "full" / "metrics.jsonl"), _rows(tmp_path / "cut" / "metrics.jsonl")
    assert [r["epoch"] for r in cut] == [0, 1, 2, 3]
    for a, b in zip(full, cut, strict=True):
        for key in ("actor_loss", "critic_loss", "lam", "env_steps", "train_episode_return"):
            expected = pytest.approx(b[key], rel=1e-5) if b[key] is not None else None
            assert a[key] == expected, (a["epoch"], key)


def test_resume_drops_metric_rows_written_after_the_checkpoint(tmp_path):
    cfg = preset("shac").replace(num_envs=4, horizon=4, critic_iterations=1)
    train(tmp_path / "run", "ant", "newton", cfg, epochs=2, seed=0, checkpoint_every=1)
    with (tmp_path / "run" / "metrics.jsonl").open("a") as fh:  # a crash after a row, before its checkpoint
        fh.write(json.dumps({"epoch": 2, "stale": True}) + "\n")
    train(tmp_path / "run", "", "", cfg, epochs=3, resume=True, checkpoint_every=1)
    rows = _rows(tmp_path / "run" / "metrics.jsonl")
    assert [r["epoch"] for r in rows] == [0, 1, 2] and "stale" not in rows[-1]


def test_train_cli_records_every_hyperparameter_and_eval_writes_json(tmp_path):
    out = tmp_path / "run"
    args = ["train", "--task", "ant", "--backend", "newton", "--algo", "sapo-tdadpt", "--epochs", "1"]
    args += ["--num-envs", "4", "--horizon", "4", "--lambda-batches", "2", "--lambda-iterations", "0.5"]
    args += ["--gamma", "0.98", "--critic-iterations", "1", "--out", str(out)]
    assert cli(args) == 0
    config = json.loads((out / "config.json").read_text())
    algo = config["algo"]
    assert (algo["lambda_batches"], algo["lambda_iterations"], algo["gamma"]) == (2, 0.5, 0.98)
    assert algo["critic_lr"] == 5e-4 and algo["num_critics"] == 2  # SAPO preset kept
    assert config["provenance"]["command"].startswith("python -m harness")
    assert (out / "checkpoint.pt").exists() and (out / "checkpoint_init.pt").exists()
    assert (
        cli(["train", "--task", "ant", "--backend", "newton", "--algo", "shac", "--epochs", "1", "--out", str(out)])
        == 2
    )
    assert cli(["eval", "--run", str(out), "--seeds", "2", "--num-envs", "2", "--max-steps", "5"]) == 0
    result = json.loads((out / "eval.json").read_text())
    assert len(result["final"]["per_seed"]) == 2 and result["num_envs"] == 2
