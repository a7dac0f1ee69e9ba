"""SHAC/SAPO/TD-lambda invariants, actor-gradient variance, robustness and resume, on the Newton Ant."""

from __future__ import annotations

import copy
import json

import pytest
import torch

pytest.importorskip("newton")

from algorithms.actor_critic import FirstOrderActorCritic  # noqa: E402
from algorithms.config import ALGORITHMS, preset  # noqa: E402
from algorithms.grad_variance import gradient_statistics, gradient_variance  # noqa: E402
from algorithms.returns import actor_loss_from_returns, critic_targets, segment_starts  # noqa: E402
from backends import make  # noqa: E402
from harness.cli import main as cli  # noqa: E402
from harness.run.train import WALL_TIME_FIELDS, RunError, resume, save_checkpoint, train  # noqa: E402
from tasks import make_task  # noqa: E402
from tasks.env import TaskEnv  # noqa: E402

N, H = 8, 6


@pytest.fixture(scope="module")
def env():
    task = make_task("ant")
    return TaskEnv(task, make("newton", task, num_envs=N, seed=0, max_graph_steps=64))


def _algo(name: str, seed: int = 0, **changes) -> FirstOrderActorCritic:
    torch.manual_seed(seed)
    cfg = preset(name).replace(**{"num_envs": N, "horizon": H, "critic_iterations": 2, "max_epochs": 10, **changes})
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


# ---------------------------------------------------------------- audit fixes (issue 7, 1a-1e)


def test_logged_gradient_variance_is_that_of_the_update(env):
    """1a: the group gradients are taken at the weights that produced the update, not after it."""
    env.reset()
    start = env.state_dict()
    algo = _algo("shac")
    twin = copy.deepcopy(algo)
    torch.manual_seed(5)
    metrics = algo.train_epoch(env)
    env.load_state_dict(start)
    torch.manual_seed(5)
    w = twin.rollout(env)
    twin.actor_opt.zero_grad()
    twin.actor_loss(w).backward()
    groups = twin.group_gradients(w)
    full = torch.cat([p.grad.reshape(-1) for p in twin.actor.parameters()])
    assert torch.allclose(groups.mean(0), full, rtol=1e-4, atol=1e-6 * full.abs().max())
    assert metrics["actor_grad_var"] == pytest.approx(float(gradient_variance(groups)), rel=1e-5)


@pytest.mark.parametrize("scale", [1e-3, 40.0])
def test_scale_free_gradient_statistics_ignore_the_loss_scale(env, scale):
    """Multiplying the actor loss by c scales the group gradients by c: the raw variance by c^2, the
    mean gradient's norm by c, and leaves the noise-to-signal ratio and the cosine as they were."""
    env.reset()
    start = env.state_dict()
    stats = []
    for c in (1.0, scale):
        algo = _algo("shac-tdfixed")
        env.load_state_dict(start)
        torch.manual_seed(3)
        w = algo.rollout(env)
        algo.actor.zero_grad()
        (c * algo.actor_loss(w)).backward()
        stats.append(gradient_statistics(algo.group_gradients(w)))
    base, scaled = stats
    assert scaled["grad_var"] == pytest.approx(scale**2 * base["grad_var"], rel=1e-4)
    assert scaled["grad_mean_norm"] == pytest.approx(scale * base["grad_mean_norm"], rel=1e-4)
    assert scaled["grad_nsr"] == pytest.approx(base["grad_nsr"], rel=1e-4)
    assert scaled["grad_cosine"] == pytest.approx(base["grad_cosine"], rel=1e-4, abs=1e-6)


@pytest.mark.parametrize("name", ["shac", "shac-tdfixed", "sapo-tdfixed"])
def test_effective_reward_weight_is_the_returns_sum_of_weights(env, name):
    """Within one segment the h-step return weights reward l by gamma^l and the truncated TD-lambda
    return by (gamma lambda)^l (the lambda-weights of the n-step returns that hold it sum to lambda^l)."""
    env.reset()
    algo = _algo(name)
    w = algo.rollout(env)
    assert not (w.terminated.any() or w.truncated.any())  # one segment per env: the closed forms hold
    decay = algo.cfg.gamma * (1.0 if name == "shac" else algo.cfg.lam)
    assert algo.reward_weight(w) == pytest.approx(sum(decay**step for step in range(H)), rel=1e-5)
    logged = algo.train_epoch(env)
    assert {"actor_grad_nsr", "actor_grad_cosine", "actor_grad_mean_norm", "actor_reward_weight"} <= set(logged)


def test_group_gradients_equal_one_backward_per_group(env):
    """The head trick gives exactly the gradients of K separate group losses (reference: K backwards).

    Envs are independent, so group k's loss (the mean over its envs) has the gradient of K times the
    actor loss with every other env's rewards and bootstrap values detached.
    """
    env.reset()
    start = env.state_dict()
    algo = _algo("sapo-tdadpt")
    base = copy.deepcopy(algo)
    k = algo.cfg.grad_var_groups
    torch.manual_seed(2)
    w = algo.rollout(env)
    algo.actor_loss(w).backward()
    fast = algo.group_gradients(w)
    for g in range(k):
        twin = copy.deepcopy(base)
        env.load_state_dict(start)
        torch.manual_seed(2)
        again = twin.rollout(env, track_heads=False)
        mine = _group_mask(N, g, N // k)
        rewards = torch.where(mine, again.rewards, again.rewards.detach())
        values = torch.where(mine, again.actor_next_values, again.actor_next_values.detach())
        starts = segment_starts(again.terminated, again.truncated)
        loss = actor_loss_from_returns(twin.actor_returns(again, rewards, values), starts, H)
        grads = torch.autograd.grad(loss, list(twin.actor.parameters()), allow_unused=True)
        ref = k * torch.cat([gr.reshape(-1) for gr in grads])
        assert torch.allclose(fast[g], ref, rtol=1e-3, atol=1e-5 * ref.abs().max()), g


def _group_mask(n, g, size):
    mask = torch.zeros(n, dtype=torch.bool)
    mask[g * size : (g + 1) * size] = True
    return mask[None, :]


def test_shac_actions_reach_the_simulator_through_tanh(env, monkeypatch):
    """1b: no clamp cuts the gradient; actions the env sees are tanh(u) even when |u| > 1."""
    env.reset()
    algo = _algo("shac")
    with torch.no_grad():
        algo.actor.mu_net[-1].bias.fill_(3.0)  # u around 3: a clamp to [-1, 1] would zero every gradient
    seen = []
    real_step = env.step

    def recording_step(actions):
        seen.append(actions.detach().clone())
        return real_step(actions)

    monkeypatch.setattr(env, "step", recording_step)
    w = algo.rollout(env)
    monkeypatch.undo()
    actions = torch.stack(seen)
    assert torch.all(actions.abs() < 1.0) and float(actions.mean()) > 0.9
    algo.actor_loss(w).backward()
    bias_grad = algo.actor.mu_net[-1].bias.grad
    assert bias_grad is not None and bias_grad.abs().sum() > 0


def test_sapo_entropy_bonus_and_temperature_follow_mineral(env):
    """1c: bonus alpha (H + |T|) / (2|T|) in the return at the rollout's alpha; critic targets at the
    alpha after the temperature update; temperature gradient alpha |T| (H - T)."""
    env.reset()
    algo = _algo("sapo", alpha_grad_clip=1e9)
    t_abs = 0.5 * algo.act_dim
    alpha0 = algo.alpha
    w = algo.rollout(env)
    bonus = (w.rewards.detach() - w.env_rewards) / alpha0
    torch.testing.assert_close(bonus, (w.entropies + t_abs) / (2 * t_abs), rtol=1e-5, atol=1e-5)
    assert w.entropies.std() > 0  # a one-sample estimate per env and step, not a constant
    entropy = float(w.entropies.mean())
    algo.alpha_opt.zero_grad()
    algo.update_alpha(w)
    assert float(algo.log_alpha.grad) == pytest.approx(alpha0 * t_abs * (entropy + t_abs), rel=1e-5)
    alpha1 = algo.alpha
    assert alpha1 != alpha0
    expected = w.env_rewards + alpha1 * (w.entropies + t_abs) / (2 * t_abs)
    torch.testing.assert_close(algo.target_rewards(w), expected)


def test_sapo_critic_loss_is_averaged_over_the_critics(env, monkeypatch):
    """1c: the two critics' squared errors are averaged (Mineral), not summed."""
    env.reset()
    algo = _algo("sapo", critic_iterations=1, critic_minibatches=1, critic_grad_clip=1e9)
    w = algo.rollout(env)
    targets = critic_targets(
        algo.target_rewards(w), w.target_next_values, w.terminated, w.truncated, algo.cfg.gamma, algo.lam.detach()
    )
    predicted = algo.values(w.obs, target=False)
    expected = (predicted - targets).pow(2).mean()
    ref = torch.autograd.grad(expected, list(algo.critics.parameters()))
    captured = []
    monkeypatch.setattr(
        algo.critic_opt, "step", lambda: captured.append([p.grad.clone() for p in algo.critics.parameters()])
    )
    loss, _ = algo.update_critic(w)
    assert loss == pytest.approx(float(expected.detach()), rel=1e-5)
    for got, want in zip(captured[0], ref, strict=True):
        torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-7)


def test_tdfixed_with_lambda_one_trains_and_starts_like_shac(tmp_path):
    """1d: --lam 1.0 stores no infinite phi, and its first actor loss is SHAC's."""
    common = ["--task", "ant", "--backend", "newton", "--epochs", "1", "--num-envs", "4", "--horizon", "4"]
    common += ["--critic-iterations", "1", "--seed", "7"]
    assert cli(["train", "--algo", "shac", *common, "--out", str(tmp_path / "shac")]) == 0
    assert cli(["train", "--algo", "shac-tdfixed", "--lam", "1.0", *common, "--out", str(tmp_path / "td1")]) == 0
    first = [_rows(tmp_path / name / "metrics.jsonl")[0]["actor_loss"] for name in ("shac", "td1")]
    assert first[1] == pytest.approx(first[0], rel=1e-5)
    assert _rows(tmp_path / "td1" / "metrics.jsonl")[0]["lam"] == 1.0


def test_lambda_optimiser_has_no_hidden_weight_decay():
    """1e: with a zero gradient phi stays put (torch's AdamW default would pull it towards 0)."""
    algo = _algo("shac-tdadpt")
    before = float(algo.phi.detach())
    algo.phi.grad = torch.zeros_like(algo.phi)
    algo.lambda_opt.step()
    assert float(algo.phi.detach()) == before
    assert algo.lambda_opt.param_groups[0]["weight_decay"] == 0.0 == algo.cfg.lambda_weight_decay


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

    def poisoned(state, obs, actions, prev_actions):
        r = original(state, obs, actions, prev_actions)
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


@pytest.mark.parametrize("name", sorted(ALGORITHMS))
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
    # an immediate stop takes no checkpoint of a half-done epoch: the last one is epoch 2's
    assert len(_rows(tmp_path / "cut" / "metrics.jsonl")) == 3
    assert torch.load(tmp_path / "cut" / "checkpoint.pt", weights_only=False)["epoch"] == 2
    resume(tmp_path / "cut", checkpoint_every=2)
    full, cut = _rows(tmp_path / "full" / "metrics.jsonl"), _rows(tmp_path / "cut" / "metrics.jsonl")
    assert [r["epoch"] for r in cut] == [0, 1, 2, 3]
    for a, b in zip(full, cut, strict=True):
        for key in ("actor_loss", "critic_loss", "lam", "env_steps", "train_episode_return"):
            expected = pytest.approx(b[key], rel=1e-5) if b[key] is not None else None
            assert a[key] == expected, (a["epoch"], key)


def test_the_same_seed_gives_identical_metrics_on_one_machine(tmp_path):
    cfg = preset("sapo-tdadpt").replace(num_envs=4, horizon=4, critic_iterations=1)
    rows = []
    for name in ("a", "b"):
        train(tmp_path / name, "ant", "newton", cfg, epochs=2, seed=5)
        rows.append(
            [
                {k: v for k, v in r.items() if k not in WALL_TIME_FIELDS}
                for r in _rows(tmp_path / name / "metrics.jsonl")
            ]
        )
    assert rows[0] == rows[1] and len(rows[0]) == 2


def test_resume_drops_metric_rows_written_after_the_checkpoint(tmp_path):
    cfg = preset("shac").replace(num_envs=4, horizon=4, critic_iterations=1)
    train(tmp_path / "run", "ant", "newton", cfg, epochs=2, seed=0, checkpoint_every=1)
    with (tmp_path / "run" / "metrics.jsonl").open("a") as fh:  # a crash after a row, before its checkpoint
        fh.write(json.dumps({"epoch": 2, "stale": True}) + "\n")
    resume(tmp_path / "run", epochs=3, checkpoint_every=1)
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
    assert cli(["eval", "--run", str(out), "--eval-seeds", "2", "--num-envs", "2", "--max-steps", "5"]) == 0
    result = json.loads((out / "eval.json").read_text())
    assert len(result["final"]["per_seed"]) == 2 and result["num_envs"] == 2
