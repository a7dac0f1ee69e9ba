"""The actor's loss landscape around a trained policy: h-step return (eq. 9) vs TD-lambda return (eq. 12).

Fig. 3 of the ARE paper (shared/paper/ARE-adaptive-td-lambda.md) perturbs a trained policy over a
40 x 40 grid spanning [-1, 1] and shows that the h-step actor loss is rugged where the TD-lambda loss
is smooth, with the same optimum. This module recomputes that picture for any run directory:

    L(a, b) = actor loss of the policy with parameters theta + a * d1 + b * d2,   a, b in [-span, span]

with ``d1, d2`` filter-normalised random directions (Li et al. 2018, "Visualizing the Loss Landscape
of Neural Nets"; see :func:`filter_normalised_directions`). Only the actor moves: the critics (whose
values bootstrap both returns), the observation statistics and the SAPO temperature stay as trained.

One grid point is one forward rollout of ``h`` steps (no gradient) from one fixed start state with
one fixed draw of action noise (common random numbers), so neighbouring points differ only by the
parameter change. Both losses come from the same window:

* ``h_step``:    ``actor_loss_from_returns(h_step_returns(...))``, eq. 9 (SHAC and SAPO);
* ``td_lambda``: ``actor_loss_from_returns(td_lambda_returns(..., lambda))``, eq. 12 with the
  recursion of eq. 14, where lambda is the run's final lambda: ``sigmoid(phi)`` for the adaptive
  variants (TDAdpt), the constant ``cfg.lam`` otherwise (TDFixed, and plain SHAC/SAPO, whose
  critic targets use that lambda but whose actor never did).

Rewards are those ``rollout`` returns, i.e. the algorithm's own objective: SAPO's entropy bonus is
included (its noise is the second, independent sample of the same seeded stream).
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from algorithms.actor_critic import FirstOrderActorCritic
from algorithms.returns import actor_loss_from_returns, h_step_returns, segment_starts, td_lambda_returns
from harness.envs import make_env, run_task
from harness.results import RunError, provenance, write_json
from harness.run.folder import CHECKPOINT, LANDSCAPE, open_run
from harness.run.train import load_checkpoint

DIRECTIONS = "filter-normalised Gaussian (Li et al. 2018), rows of weight matrices, biases 0"
SURFACES = ("h_step", "td_lambda")


# -- directions --------------------------------------------------------------------------------
def filter_normalised_directions(module: nn.Module, seed: int, count: int = 2) -> list[dict[str, Tensor]]:
    """``count`` random directions in the parameter space of ``module``, filter-normalised (Li et al. 2018).

    Every direction is drawn from N(0, I) by a ``torch.Generator`` seeded with ``seed`` (directions in
    turn, parameters in ``named_parameters`` order), then, for every parameter with two or more
    dimensions (a weight matrix), each row - one output unit, the "filter" of a fully connected layer -
    is rescaled so its norm equals the norm of the same row of the parameter:

        d[i, :] <- d[i, :] * ||theta[i, :]|| / ||d[i, :]||

    so a step of 1 along d changes every unit by as much as the unit's own weights, whatever its
    scale (without this, layers of small weights would dominate the picture). One-dimensional
    parameters - biases, LayerNorm gains and shifts, the SHAC actor's state-independent ``logstd`` -
    get a zero direction: they are not perturbed (Li et al. do the same for biases and BN parameters).

    Returns a list of ``count`` dicts ``{parameter name: direction tensor}`` (same shapes as the
    parameters, detached).
    """
    generator = torch.Generator(device="cpu").manual_seed(int(seed))
    directions = []
    for _ in range(count):
        direction = {}
        for name, param in module.named_parameters():
            theta = param.detach().to("cpu", torch.float64)
            # draw for every parameter (biases too) so that adding a parameter kind never reshuffles the rest
            d = torch.randn(theta.shape, generator=generator, dtype=torch.float64)
            if theta.dim() < 2:
                d = torch.zeros_like(d)
            else:
                rows, theta_rows = d.reshape(theta.shape[0], -1), theta.reshape(theta.shape[0], -1)
                scale = theta_rows.norm(dim=1, keepdim=True) / rows.norm(dim=1, keepdim=True).clamp_min(1e-30)
                d = (rows * scale).reshape(theta.shape)
            direction[name] = d.to(param.device, param.dtype)
        directions.append(direction)
    return directions


# -- roughness ---------------------------------------------------------------------------------
def roughness(surface: np.ndarray) -> float:
    """Total variation of a loss surface over its range, averaged per grid line.

    For an (R, C) surface L (R = C = G on a landscape grid)::

        r = (sum over all adjacent pairs along both axes of |L_i - L_j|) / ((R + C) * (max L - min L))

    i.e. ``2 G (max - min)`` in the denominator on a G x G grid. Each of the R + C grid lines has a
    total variation of at most the range if it is monotone, so a surface monotone along every line
    gives r <= 1. On a G x G grid a plane ``p i + q j`` gives exactly 1/2: its G lines along one axis
    vary by ``|p| (G - 1)`` each, those along the other by ``|q| (G - 1)``, and the range is the sum
    of the two. A jagged surface gives r >> 1: a checkerboard (max - min at every step) gives G - 1.
    A constant surface gives 0.0.

    Non-finite values are refused (``ValueError`` naming how many): a gap would make the total
    variation of its lines meaningless. :func:`compute_landscape` reports ``None`` for such a surface.
    """
    z = np.asarray(surface, dtype=np.float64)
    if z.ndim != 2 or min(z.shape) < 2:
        raise ValueError(f"roughness needs a 2-D surface of at least 2 x 2 points, got shape {z.shape}")
    bad = int((~np.isfinite(z)).sum())
    if bad:
        raise ValueError(f"roughness: {bad} of {z.size} surface points are not finite")
    span = float(z.max() - z.min())
    if span == 0.0:
        return 0.0
    variation = float(np.abs(np.diff(z, axis=0)).sum() + np.abs(np.diff(z, axis=1)).sum())
    return variation / ((z.shape[0] + z.shape[1]) * span)


# -- evaluation --------------------------------------------------------------------------------
class _Probe:
    """One trained policy, one env at a fixed start state, one seeded noise stream: losses at any theta."""

    def __init__(self, algo: FirstOrderActorCritic, env, noise_seed: int):
        self.algo, self.env, self.noise_seed = algo, env, noise_seed
        self.start = env.state_dict()
        # rollout() updates the running observation statistics; every point must start from the trained ones
        self.rms = {k: v.clone() for k, v in algo.obs_rms.state_dict().items()}
        self.params = dict(algo.actor.named_parameters())
        self.theta = {k: p.detach().clone() for k, p in self.params.items()}
        self.lam = float(algo.lam.detach())  # TDAdpt: sigmoid(phi) as trained; else cfg.lam

    @torch.no_grad()
    def losses(self, shift: dict[str, Tensor] | None = None) -> tuple[float, float]:
        """(h-step loss, TD-lambda loss) of theta + shift from the stored start state and noise.

        A step the simulator cannot take (non-finite state, or actions made non-finite by the
        perturbation) gives (nan, nan).
        """
        from backends.contract import InvalidActionError, NonFiniteStateError

        for name, param in self.params.items():
            param.copy_(self.theta[name] if shift is None else self.theta[name] + shift[name])
        self.algo.obs_rms.load_state_dict(self.rms)
        self.env.load_state_dict(self.start)
        torch.manual_seed(self.noise_seed)  # common random numbers: the same eps at every grid point
        try:
            w = self.algo.rollout(self.env, track_heads=False)
        except (NonFiniteStateError, InvalidActionError):
            return math.nan, math.nan
        cfg = self.algo.cfg
        starts = segment_starts(w.terminated, w.truncated)
        args = (w.rewards, w.actor_next_values, w.terminated, w.truncated, cfg.gamma)
        h_step = actor_loss_from_returns(h_step_returns(*args), starts, cfg.horizon)
        td = actor_loss_from_returns(td_lambda_returns(*args, self.lam), starts, cfg.horizon)
        return float(h_step), float(td)

    def restore(self) -> None:
        with torch.no_grad():
            for name, param in self.params.items():
                param.copy_(self.theta[name])
        self.algo.obs_rms.load_state_dict(self.rms)


def _surface_list(z: np.ndarray) -> list[list[float | None]]:
    """Nested lists for JSON; non-finite points become null (strict JSON has no NaN)."""
    return [[float(v) if math.isfinite(v) else None for v in row] for row in z.tolist()]


def _check_arguments(grid, span, num_envs, warmup_steps) -> None:
    """Refuse a landscape's arguments in one line before any work."""
    if isinstance(grid, bool) or not isinstance(grid, int) or grid < 2:
        raise RunError(f"landscape grid must be an integer >= 2, got {grid!r}")
    if not (isinstance(span, int | float) and math.isfinite(span) and span > 0):
        raise RunError(f"landscape span must be a finite number > 0, got {span!r}")
    if num_envs is not None and (isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1):
        raise RunError(f"landscape num_envs must be an integer >= 1, got {num_envs!r}")
    if isinstance(warmup_steps, bool) or not isinstance(warmup_steps, int) or warmup_steps < 0:
        raise RunError(f"landscape warmup_steps must be an integer >= 0, got {warmup_steps!r}")


def _sweep(probe, directions, alphas, betas, label: str, stream) -> dict[str, np.ndarray]:
    """Both losses at every point ``theta + a d1 + b d2`` of the plane, surfaces indexed [a, b]; a progress
    line every tenth of the points."""
    d1, d2 = directions
    surfaces = {name: np.full((len(alphas), len(betas)), np.nan) for name in SURFACES}
    start = time.perf_counter()
    total = len(alphas) * len(betas)
    every = max(1, total // 10)
    for k in range(total):
        i, j = divmod(k, len(betas))
        a, b = float(alphas[i]), float(betas[j])
        shift = {name: a * d1[name] + b * d2[name] for name in d1}
        surfaces["h_step"][i, j], surfaces["td_lambda"][i, j] = probe.losses(shift)
        if (k + 1) % every == 0 or k + 1 == total:
            elapsed = time.perf_counter() - start
            left = elapsed / (k + 1) * (total - k - 1)
            print(f"{label}: {k + 1}/{total} points, {elapsed:.1f} s, ~{left:.0f} s left", file=stream, flush=True)
    return surfaces


def compute_landscape(
    run_dir,
    grid: int = 40,
    span: float = 1.0,
    num_envs: int | None = None,
    seed: int = 0,
    warmup_steps: int = 0,
    checkpoint: str = CHECKPOINT,
    stream=None,
) -> dict:
    """h-step (eq. 9) and TD-lambda (eq. 12) actor losses over a ``grid`` x ``grid`` plane of actor parameters.

    The plane is ``theta + a * d1 + b * d2`` with ``a`` (``alphas``, first index of the surfaces) and
    ``b`` (``betas``, second index) each ``grid`` evenly spaced values in [-span, span], theta the actor
    of ``checkpoint`` and d1, d2 from :func:`filter_normalised_directions` with ``direction_seed = seed``.

    Every point rolls out one window of the run's ``h`` steps in ``num_envs`` envs (default: the run's
    own ``num_envs``) of the run's task, backend and physics, built once with env seed ``seed`` and reset,
    then advanced ``warmup_steps`` steps by the trained policy's deterministic action so that the
    window may start mid-episode; that state is restored before every point, and torch is reseeded with
    ``noise_seed = seed + 1`` so the action noise is identical at every point. ``center`` is the
    unperturbed policy's loss on the same window (on the grid too when ``grid`` is odd). The caller's
    torch random state is left as it was.

    Returns the result dict (see :func:`write_landscape`); ``roughness`` (see :func:`roughness`) is
    ``None`` for a surface with non-finite points, whose count ``nonfinite`` gives.
    """
    stream = stream or sys.stdout  # the stdout of now, not of import time
    run_dir = Path(run_dir)
    _check_arguments(grid, span, num_envs, warmup_steps)
    config = open_run(run_dir, (checkpoint,))
    cfg = config["algo_config"]
    n = num_envs or cfg.num_envs
    start_time = time.perf_counter()

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        env = make_env(run_task(config), config["backend"], n, config["device"], seed, cfg.horizon)
        algo = FirstOrderActorCritic(cfg, env.obs_dim, env.action_dim)
        load_checkpoint(run_dir / checkpoint, algo)  # weights and statistics only: the env is our own
        env.reset()
        if warmup_steps:
            from backends.contract import NonFiniteStateError

            try:
                with torch.no_grad():
                    for _ in range(warmup_steps):
                        env.step(algo.act(env.obs, deterministic=True))
            except NonFiniteStateError as exc:
                raise RunError(f"landscape warm-up of {warmup_steps} steps failed: {exc}") from None
        d1, d2 = filter_normalised_directions(algo.actor, seed)
        probe = _Probe(algo, env, noise_seed=seed + 1)
        alphas = np.linspace(-span, span, grid)
        betas = np.linspace(-span, span, grid)
        center = probe.losses()
        surfaces = _sweep(probe, (d1, d2), alphas, betas, f"landscape {run_dir.name}", stream)
        probe.restore()

    rough, nonfinite = {}, {}
    for name, z in surfaces.items():
        nonfinite[name] = int((~np.isfinite(z)).sum())
        rough[name] = roughness(z) if nonfinite[name] == 0 else None
    return {
        "run": str(run_dir),
        "task": config["task"],
        "backend": config["backend"],
        "algo": cfg.algo,
        "seed": seed,
        "run_seed": config["seed"],
        "checkpoint": checkpoint,
        "horizon": cfg.horizon,
        "num_envs": n,
        "warmup_steps": warmup_steps,
        "grid": grid,
        "span": float(span),
        "directions": DIRECTIONS,
        "direction_seed": seed,
        "noise_seed": seed + 1,
        "lambda": probe.lam,
        "lambda_source": "sigmoid(phi), trained" if cfg.adaptive_lambda else "cfg.lam (constant)",
        "actor_return": cfg.actor_return,
        "gamma": cfg.gamma,
        "alphas": [float(a) for a in alphas],
        "betas": [float(b) for b in betas],
        "losses": {name: _surface_list(z) for name, z in surfaces.items()},
        "roughness": rough,
        "nonfinite": nonfinite,
        "center": {"h_step": center[0], "td_lambda": center[1]},
        "seconds": time.perf_counter() - start_time,
        "provenance": provenance(),
    }


# -- output ------------------------------------------------------------------------------------
def write_landscape(run_dir, result: dict) -> Path:
    """Write ``result`` to ``run_dir/landscape.json`` atomically (:func:`harness.results.write_json`)."""
    return write_json(Path(run_dir) / LANDSCAPE, result)
