"""Proposition 1's B_f, measured: how much one step of the dynamics amplifies a perturbation where a
trained policy goes.

Proposition 1 of the ARE paper (shared/paper/ARE-adaptive-td-lambda.md) bounds the pathwise
gradient of the TD-lambda return through the product of one-step Jacobians (eq. 19), each bounded by
B_f (Assumption 1, ``||grad f(s, a)|| <= B_f``): its variance converges as h grows when
``lambda gamma B_f < 1`` (eq. 23). At gamma 0.99 and lambda 0.95 that asks for B_f < 1.063.

The bound is over all states; what matters to training is the states training visits. This module
loads a run's final policy, rolls it out on the run's own task, engine and physics with stochastic
actions (what the actor's windows see), keeps every env's state every ``stride`` control steps, and
at each kept state takes the tape's Jacobian of one control step (one backward pass per output
coordinate, all envs at once; the contract requires the tape to replay its forward). Per state:

* ``state_gain``: the spectral norm of ``d s' / d s`` over the generalized coordinates the
  algorithms see, the root quaternion left out (a perturbation of it leaves the unit sphere); the
  quantity eq. 19 multiplies ``l`` times;
* ``action_gain``: the spectral norm of ``d s' / d a``;
* ``joint_gain``: the spectral norm of ``[d s'/d s, d s'/d a]``, Assumption 1's ``||grad f||``.

A norm of a product is at most the product of the norms, so the per-step gains bound the chain of
eq. 19 from above, often loosely. Beside them, one window of the run's horizon (every env, actions as
the policy takes them) gives the growth the chain actually has: ``||d s_{t+h} / d s_t||^(1/h)``
(:func:`window_gain`), descriptive.

The pre-registered reading (docs/statistics.md): the bound holds on a task when the 95th percentile of
``state_gain`` over states is below ``1 / (gamma lambda)``.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

from algorithms.actor_critic import FirstOrderActorCritic
from harness.envs import make_env, run_task
from harness.results import RunError, provenance, write_json
from harness.run.folder import CHECKPOINT, STEP_GAIN, open_run
from harness.run.train import load_checkpoint

#: the quantile of the per-state gains the verdict reads (docs/statistics.md, Proposition 1)
QUANTILE = 0.95
#: the lambda of the paper's TD variants, whose bound the verdict reads
PAPER_LAMBDA = 0.95


def state_columns(layout) -> list[int]:
    """Columns of ``[joint_q, joint_qd]`` whose perturbation stays a valid state: all but the root quaternion."""
    skip = set(range(3, 7)) if layout.floating_base else set()
    return [i for i in range(layout.nq + layout.nv) if i not in skip]


def step_jacobians(sim, q: torch.Tensor, qd: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """The tape's Jacobian of one control step at ``num_envs`` states: (N, nq + nv, len(cols) + action_dim),
    rows the next ``[joint_q, joint_qd]``, columns :func:`state_columns` then the actions (float64)."""
    nq = sim.layout.nq
    cols = torch.tensor(state_columns(sim.layout))
    x = torch.cat((q, qd), dim=1).detach().clone().requires_grad_(True)
    a = actions.detach().clone().requires_grad_(True)
    nxt = sim.advance(sim.state_from_generalized(x[:, :nq], x[:, nq:]), a)
    out = torch.cat((nxt.joint_q, nxt.joint_qd), dim=1)
    jac = torch.zeros(out.shape[0], out.shape[1], cols.numel() + a.shape[1], dtype=torch.float64)
    for d in range(out.shape[1]):
        # envs are independent, so the sum's gradient is every env's own row d
        gx, ga = torch.autograd.grad(out[:, d].sum(), (x, a), retain_graph=d + 1 < out.shape[1])
        jac[:, d] = torch.cat((gx[:, cols], ga), dim=1).double()
    return jac


def gains(jac: np.ndarray, state_cols: int) -> dict[str, float]:
    """Spectral norms of one state's step Jacobian (:func:`step_jacobians`): state, action and joint."""
    return {
        "state_gain": float(np.linalg.norm(jac[:, :state_cols], 2)),
        "action_gain": float(np.linalg.norm(jac[:, state_cols:], 2)),
        "joint_gain": float(np.linalg.norm(jac, 2)),
    }


def visited_states(env, algo, states: int, stride: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(joint_q, joint_qd, actions) of ``states`` states the policy visits with stochastic actions: every
    env's state every ``stride`` control steps from reset (an env that terminates is reset, as in training)."""
    from backends.contract import NonFiniteStateError

    sim, qs, qds, acts, step = env.sim, [], [], [], 0
    with torch.no_grad():
        while sum(len(q) for q in qs) < states:
            actions = algo.act(env.obs, deterministic=False)
            if step > 0 and step % stride == 0:
                qs.append(sim.state.joint_q.detach().clone())
                qds.append(sim.state.joint_qd.detach().clone())
                acts.append(actions.detach().clone())
            try:
                env.step(actions)
            except NonFiniteStateError as exc:
                raise RunError(f"step gain: the policy's rollout failed: {exc}") from None
            step += 1
    return tuple(torch.cat(parts)[:states] for parts in (qs, qds, acts))


def window_gain(sim, q: torch.Tensor, qd: torch.Tensor, actions: list[torch.Tensor]) -> np.ndarray:
    """Per env, ``||d s_{t+l} / d s_t||^(1/l)`` over the ``l = len(actions)`` steps of a window with the
    actions held as taken: the per-step growth the chain of eq. 19 actually has, which the product of
    per-step gains (a norm of a product is at most the product of the norms) bounds from above."""
    nq = sim.layout.nq
    cols = torch.tensor(state_columns(sim.layout))
    x = torch.cat((q, qd), dim=1).detach().clone().requires_grad_(True)
    state = sim.state_from_generalized(x[:, :nq], x[:, nq:])
    for a in actions:
        state = sim.advance(state, a.detach())
    out = torch.cat((state.joint_q, state.joint_qd), dim=1)
    jac = torch.zeros(out.shape[0], out.shape[1], cols.numel(), dtype=torch.float64)
    for d in range(out.shape[1]):
        (gx,) = torch.autograd.grad(out[:, d].sum(), (x,), retain_graph=d + 1 < out.shape[1])
        jac[:, d] = gx[:, cols].double()
    norms = np.linalg.norm(jac.numpy(), ord=2, axis=(1, 2))
    return norms ** (1.0 / len(actions))


def summarise(values: list[float], bound: float) -> dict:
    """Median, the verdict's quantile, maximum, and the fraction of states above ``bound``."""
    v = np.asarray(values, dtype=np.float64)
    return {
        "median": float(np.median(v)),
        f"p{round(QUANTILE * 100)}": float(np.quantile(v, QUANTILE)),
        "max": float(v.max()),
        "fraction_above_bound": float(np.mean(v > bound)),
    }


def compute_step_gain(
    run_dir, states: int = 256, num_envs: int = 64, stride: int = 8, seed: int = 0, stream=None
) -> dict:
    """The per-state gains of one control step along the final policy of ``run_dir`` (module docstring)."""
    stream = stream or sys.stdout
    run_dir = Path(run_dir)
    for name, value, low in (("states", states, 1), ("num_envs", num_envs, 1), ("stride", stride, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise RunError(f"step gain {name} must be an integer >= {low}, got {value!r}")
    config = open_run(run_dir, (CHECKPOINT,))
    cfg = config["algo_config"]
    start = time.perf_counter()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        env = make_env(run_task(config), config["backend"], num_envs, config["device"], seed, cfg.horizon)
        algo = FirstOrderActorCritic(cfg, env.obs_dim, env.action_dim)
        load_checkpoint(run_dir / CHECKPOINT, algo)
        env.reset()
        q, qd, actions = visited_states(env, algo, states, stride)
        lam = float(algo.lam.detach())
        # one window of the run's horizon from where the rollout stopped, actions as the policy takes them
        start_q, start_qd = env.sim.state.joint_q.detach().clone(), env.sim.state.joint_qd.detach().clone()
        window_actions = []
        with torch.no_grad():
            for _ in range(cfg.horizon):
                window_actions.append(algo.act(env.obs, deterministic=False))
                env.step(window_actions[-1])
    # the bound at the run's own lambda, and at the paper's 0.95 (the pre-registered verdict's)
    bound, paper_bound = 1.0 / (cfg.gamma * lam), 1.0 / (cfg.gamma * PAPER_LAMBDA)
    width = len(state_columns(env.sim.layout))
    rows = []
    for begin in range(0, states, num_envs):
        count = min(num_envs, states - begin)
        pad = num_envs - count  # the sim steps all its envs: fill the last batch with copies
        batch = [torch.cat((t[begin : begin + count], t[begin : begin + 1].expand(pad, -1))) for t in (q, qd, actions)]
        jac = step_jacobians(env.sim, *batch).numpy()
        rows += [gains(jac[i], width) for i in range(count)]
        print(f"step gain {run_dir.name}: {len(rows)}/{states} states", file=stream, flush=True)
    print(f"step gain {run_dir.name}: one window of {cfg.horizon} steps", file=stream, flush=True)
    growth = window_gain(env.sim, start_q, start_qd, window_actions)
    finite = np.isfinite(growth).all() and all(math.isfinite(v) for r in rows for v in r.values())
    if not finite:
        raise RunError(f"step gain {run_dir.name}: a Jacobian is not finite")
    return {
        "run": str(run_dir),
        "task": config["task"],
        "backend": config["backend"],
        "algo": cfg.algo,
        "run_seed": config["seed"],
        "checkpoint": CHECKPOINT,
        "seed": seed,
        "states": states,
        "num_envs": num_envs,
        "stride": stride,
        "sampling": "the final policy's stochastic actions from reset, every env every stride control steps",
        "gamma": cfg.gamma,
        "lambda": lam,
        "bound": bound,
        "paper_lambda": PAPER_LAMBDA,
        "paper_bound": paper_bound,
        "quantile": QUANTILE,
        "summary": {key: summarise([r[key] for r in rows], paper_bound) for key in rows[0]},
        "window": {
            "steps": cfg.horizon,
            "envs": num_envs,
            "per_step_growth": summarise(growth.tolist(), paper_bound),
        },
        "rows": rows,
        "seconds": time.perf_counter() - start,
        "provenance": provenance(),
    }


def write_step_gain(run_dir, result: dict) -> Path:
    """Write ``result`` to ``run_dir/step_gain.json`` atomically."""
    return write_json(Path(run_dir) / STEP_GAIN, result)
