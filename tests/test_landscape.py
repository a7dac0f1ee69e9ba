"""The loss landscape of Fig. 3 (harness/checks/landscape.py): the roughness statistic, filter-normalised directions,
and an end-to-end landscape of a tiny trained Newton Ant run whose centre must be the trained policy's loss."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import torch

from algorithms.actor_critic import FirstOrderActorCritic
from algorithms.config import preset
from algorithms.returns import actor_loss_from_returns, h_step_returns, segment_starts
from harness.checks.landscape import (
    compute_landscape,
    filter_normalised_directions,
    roughness,
    write_landscape,
)
from harness.report.plots import plot_landscape
from harness.results import RunError


# -- roughness ---------------------------------------------------------------------------------
def test_roughness_of_a_plane_is_one_half():
    # r = G (G-1) (|p| + |q|) / (2 G (G-1) (|p| + |q|)) = 1/2 for any plane p i + q j on a G x G grid
    i, j = np.meshgrid(np.arange(5.0), np.arange(5.0), indexing="ij")
    assert roughness(2.0 * i - 3.0 * j + 7.0) == 0.5
    assert roughness(i) == 0.5  # a ramp along one axis only: its other lines are flat


def test_roughness_by_hand_constant_and_checkerboard():
    # [[0, 1], [3, 0]]: |3-0| + |0-1| down, |1-0| + |0-3| across = 8; range 3; 2 G = 4 -> 8 / 12
    assert roughness(np.array([[0.0, 1.0], [3.0, 0.0]])) == pytest.approx(2.0 / 3.0, abs=1e-15)
    assert roughness(np.full((4, 4), -2.5)) == 0.0
    g = 8
    checker = np.indices((g, g)).sum(axis=0) % 2 * 3.0  # max - min at every step: r = G - 1
    assert roughness(checker) == pytest.approx(g - 1)
    assert roughness(checker) > 5.0


def test_roughness_refuses_non_finite_and_bad_shapes():
    z = np.zeros((3, 3))
    z[0, 1], z[2, 2] = np.nan, np.inf
    with pytest.raises(ValueError, match="2 of 9 surface points are not finite"):
        roughness(z)
    with pytest.raises(ValueError, match="2-D"):
        roughness(np.arange(4.0))
    with pytest.raises(ValueError, match="2-D"):
        roughness(np.zeros((1, 5)))


# -- directions --------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["shac", "sapo"])  # diffrl Gaussian actor (with logstd), mineral squashed actor
def test_directions_are_filter_normalised(name):
    torch.manual_seed(0)
    cfg = preset(name).replace(actor_hidden=(8, 6), critic_hidden=(4,))
    actor = FirstOrderActorCritic(cfg, obs_dim=5, act_dim=3).actor
    d1, d2 = filter_normalised_directions(actor, seed=11)
    params = dict(actor.named_parameters())
    assert set(d1) == set(d2) == set(params)
    matrices = 0
    for key, theta in params.items():
        for d in (d1[key], d2[key]):
            assert d.shape == theta.shape and d.dtype == theta.dtype and not d.requires_grad
            if theta.dim() >= 2:
                rows, theta_rows = d.reshape(d.shape[0], -1), theta.detach().reshape(theta.shape[0], -1)
                torch.testing.assert_close(rows.norm(dim=1), theta_rows.norm(dim=1), rtol=1e-5, atol=1e-7)
            else:  # biases, LayerNorm parameters, logstd: not perturbed
                assert bool((d == 0).all()), key
        if theta.dim() >= 2:
            matrices += 1
            assert not torch.equal(d1[key], d2[key])
    assert matrices == 3  # two hidden layers and the output layer
    if name == "shac":
        assert bool((d1["logstd"] == 0).all())
    again = filter_normalised_directions(actor, seed=11)
    other = filter_normalised_directions(actor, seed=12)
    for key in params:
        assert torch.equal(again[0][key], d1[key]) and torch.equal(again[1][key], d2[key])
    assert any(not torch.equal(other[0][key], d1[key]) for key in params)


# -- end to end on a tiny trained run ----------------------------------------------------------
@pytest.fixture(scope="module")
def run(tmp_path_factory):
    pytest.importorskip("newton")
    from harness.run.train import train

    cfg = preset("shac-tdadpt").replace(num_envs=2, horizon=4, critic_iterations=1, grad_var_groups=2)
    return train(tmp_path_factory.mktemp("landscape") / "run", "ant", "newton", cfg, epochs=1, stream=io.StringIO())


def _unperturbed_losses(run, noise_seed: int, grad: bool) -> tuple[float, float]:
    """The trained policy's (h-step, TD-lambda) actor loss on the landscape's window, computed the
    algorithm's own way: its rollout and its ``actor_loss`` (TD-lambda for TDAdpt)."""
    from harness.envs import make_env
    from harness.run.folder import read_config
    from harness.run.train import load_checkpoint

    cfg = read_config(run)["algo_config"]
    env = make_env("ant", "newton", 2, "cpu", 0, cfg.horizon)
    algo = FirstOrderActorCritic(cfg, env.obs_dim, env.action_dim)
    load_checkpoint(run / "checkpoint.pt", algo)
    env.reset()
    torch.manual_seed(noise_seed)
    with torch.set_grad_enabled(grad):
        w = algo.rollout(env)
        starts = segment_starts(w.terminated, w.truncated)
        h_step = actor_loss_from_returns(
            h_step_returns(w.rewards, w.actor_next_values, w.terminated, w.truncated, cfg.gamma), starts, cfg.horizon
        )
        td = algo.actor_loss(w)
    return float(h_step.detach()), float(td.detach())


def test_landscape_end_to_end(run, tmp_path):
    rng_before = torch.get_rng_state()
    out = io.StringIO()
    result = compute_landscape(run, grid=3, span=0.5, num_envs=2, stream=out)
    assert torch.equal(torch.get_rng_state(), rng_before)  # the caller's random stream is untouched
    assert "9/9 points" in out.getvalue()
    assert result["alphas"] == result["betas"] == [-0.5, 0.0, 0.5]
    assert result["algo"] == "shac-tdadpt" and result["num_envs"] == 2 and result["horizon"] == 4
    assert 0.0 < result["lambda"] < 1.0 and result["lambda_source"].startswith("sigmoid")
    h, td = (np.array(result["losses"][k], dtype=np.float64) for k in ("h_step", "td_lambda"))
    assert h.shape == td.shape == (3, 3)
    assert np.isfinite(h).all() and np.isfinite(td).all()
    assert result["nonfinite"] == {"h_step": 0, "td_lambda": 0}

    # perturbation 0 is the trained policy: the same loss as the algorithm computes on that window and noise
    center = (result["center"]["h_step"], result["center"]["td_lambda"])
    assert (h[1, 1], td[1, 1]) == center
    assert _unperturbed_losses(run, result["noise_seed"], grad=False) == center
    # ... and as its training path (with the autograd graph through the simulator) computes
    assert _unperturbed_losses(run, result["noise_seed"], grad=True) == pytest.approx(center, rel=1e-5, abs=1e-6)
    assert center[0] != center[1]  # lambda < 1: TD-lambda and h-step returns differ
    assert not np.array_equal(h, td)
    assert h[0, 0] != h[1, 1] and td[2, 0] != td[1, 1]  # moving the actor moves the loss

    for name, z in (("h_step", h), ("td_lambda", td)):
        assert result["roughness"][name] == roughness(z) and result["roughness"][name] > 0.0

    # common random numbers: a second call sees the same start state and noise, so the same surfaces
    again = compute_landscape(run, grid=3, span=0.5, num_envs=2, stream=io.StringIO())
    assert again["losses"] == result["losses"] and again["center"] == result["center"]

    path = write_landscape(run, result)
    assert path == run / "landscape.json"
    stored = json.loads(path.read_text(), parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    assert stored["losses"] == result["losses"] and stored["provenance"]["packages"]
    png = plot_landscape(result, tmp_path / "fig" / "landscape.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_landscape_warmup_moves_the_window(run):
    plain = compute_landscape(run, grid=2, span=0.5, num_envs=2, stream=io.StringIO())
    warm = compute_landscape(run, grid=2, span=0.5, num_envs=2, warmup_steps=3, stream=io.StringIO())
    assert np.isfinite(np.array(warm["losses"]["h_step"], dtype=np.float64)).all()
    assert warm["warmup_steps"] == 3 and warm["center"] != plain["center"]


def test_landscape_refuses_bad_requests(run, tmp_path):
    with pytest.raises(RunError, match="no missing.pt"):
        compute_landscape(run, grid=3, checkpoint="missing.pt")
    with pytest.raises(RunError, match="grid must be an integer >= 2"):
        compute_landscape(run, grid=1)
    with pytest.raises(RunError, match="span must be a finite number > 0"):
        compute_landscape(run, span=0.0)
    with pytest.raises(RunError, match="not a run directory"):
        compute_landscape(tmp_path / "nothing")
