"""Micro-benchmarks (pytest-benchmark): the hot paths of one training epoch, per backend x task.

Run by ``tox -e microbench``, which saves each run's JSON under ``results/microbench/`` and compares it
with the last saved run (``--benchmark-compare``). Not collected by ``tox -e py`` (outside ``tests/``,
and the project's pytest options skip benchmarks unless ``--benchmark-only`` is given).

Measured, for every registered built-in adapter on every task it runs (sizes kept small so the
whole set takes minutes on a 2-core CPU):

* ``step``: one control step of ``ENVS`` envs, no gradients;
* ``backward_window``: a window of ``WINDOW`` steps with gradients and its backward pass (the loss
  touches every generalized coordinate or particle of every step, as ``throughput`` does);
* ``fd_jacobian``: one finite-difference Jacobian step (adapters whose gradients are finite
  differences: MuJoCo-Warp, articulated tasks);
* ``td_lambda``: the TD-lambda return recursion (eq. 14) on a (h = 32, N = 64) batch, engine-free.
"""

from __future__ import annotations

import pytest
import torch

ENVS = 8
WINDOW = 8
CASES = [
    ("newton", "ant"),
    ("newton", "go2"),
    ("newton", "soft_jumper"),
    ("mujoco_warp", "ant"),
    ("mujoco_warp", "go2"),
]
IDS = [f"{b}-{t}" for b, t in CASES]

_SIMS: dict = {}


def _sim(backend: str, task_name: str):
    """One adapter per case for the whole session (Warp compiles on first use), warmed up."""
    key = (backend, task_name)
    if key not in _SIMS:
        from harness.envs import make_sim
        from tasks import make_task

        task = make_task(task_name)
        sim = make_sim(backend, task, ENVS, seed=0, horizon=WINDOW)
        with torch.no_grad():
            sim.step(torch.zeros(ENVS, task.action_dim))
        _SIMS[key] = sim
    return _SIMS[key]


def _actions(sim, gen):
    return 0.5 * (2.0 * torch.rand(sim.num_envs, sim.task.action_dim, generator=gen) - 1.0)


@pytest.mark.parametrize("backend, task_name", CASES, ids=IDS)
def test_step(benchmark, backend, task_name):
    sim = _sim(backend, task_name)
    gen = torch.Generator().manual_seed(0)

    def one_step():
        with torch.no_grad():
            sim.step(_actions(sim, gen))

    def fresh():
        # pytest-benchmark treats a returned value as (args, kwargs): return nothing.
        sim.reset()

    benchmark.pedantic(one_step, setup=fresh, rounds=5, warmup_rounds=1)


@pytest.mark.parametrize("backend, task_name", CASES, ids=IDS)
def test_backward_window(benchmark, backend, task_name):
    sim = _sim(backend, task_name)
    gen = torch.Generator().manual_seed(0)

    def window():
        loss = 0.0
        for _ in range(WINDOW):
            state = sim.step(_actions(sim, gen).requires_grad_(True))
            loss = loss + state.joint_q.sum() + state.joint_qd.sum()
            if state.particle_q is not None:
                loss = loss + state.particle_q.sum() + state.particle_qd.sum()
        loss.backward()

    def fresh():
        sim.reset()
        sim.cut_graph()

    benchmark.pedantic(window, setup=fresh, rounds=3, warmup_rounds=1)


@pytest.mark.parametrize("backend, task_name", [c for c in CASES if c[0] == "mujoco_warp"])
def test_fd_jacobian(benchmark, backend, task_name):
    sim = _sim(backend, task_name)
    engine = sim.state.engine.detach()
    control = sim.task.actions_to_control(torch.zeros(sim.num_envs, sim.task.action_dim))
    benchmark.pedantic(sim.fd_jacobians, args=(engine, control), rounds=3, warmup_rounds=1)


def test_td_lambda(benchmark):
    from algorithms.returns import td_lambda_returns

    gen = torch.Generator().manual_seed(0)
    horizon, envs = 32, 64
    rewards = torch.randn(horizon, envs, generator=gen)
    next_values = torch.randn(horizon, envs, generator=gen)
    terminated = torch.rand(horizon, envs, generator=gen) < 0.02
    truncated = torch.zeros(horizon, envs, dtype=torch.bool)
    truncated[-1] = True
    benchmark(td_lambda_returns, rewards, next_values, terminated, truncated, 0.99, 0.95)
