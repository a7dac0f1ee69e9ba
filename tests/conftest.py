"""Shared fixtures. Engine-backed fixtures are module-scoped: Warp compiles kernels on first use."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared"

# The longest test files by far: whole suites, Ray clusters, killed training processes, and every physics
# field on every engine's models. tox runs the tests with `--dist loadfile --no-loadscope-reorder`, so
# xdist hands out files in collection order; handing these out first keeps any of them from starting last
# while the other workers sit idle.
LONGEST_FIRST = ("test_bench.py", "test_cluster.py", "test_interruptions.py", "test_physics_mapping.py")


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int | None:
    """``-n auto``: one worker more than the machine has cores (tox caps it with ``--maxprocesses``).

    Many tests wait on processes they started (a suite's jobs, a Ray head's daemons, a run to be killed at
    a random moment); a worker that waits leaves its core idle unless another worker is ready to use it.
    ``PYTEST_XDIST_AUTO_NUM_WORKERS`` still decides where it is set."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    return len(os.sched_getaffinity(0)) + 1 if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1) + 1


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Order the collected tests file by file: LONGEST_FIRST, then the rest as collected (a stable sort,
    so the tests inside a file keep their order)."""

    def rank(item: pytest.Item) -> int:
        name = item.path.name
        return LONGEST_FIRST.index(name) if name in LONGEST_FIRST else len(LONGEST_FIRST)

    items.sort(key=rank)


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.skip("../shared is not present beside the checkout")
    return SHARED


@pytest.fixture(scope="session")
def one_epoch_ant_run(tmp_path_factory) -> Path:
    """A finished one-epoch Newton Ant run (4 envs, h 4); tests that change a run copy it first."""
    pytest.importorskip("newton")
    from algorithms.config import preset
    from harness.run.train import train

    run = tmp_path_factory.mktemp("one_epoch_ant") / "run"
    cfg = preset("shac").replace(num_envs=4, horizon=4, critic_iterations=1)
    train(run, "ant", "newton", cfg, epochs=1, seed=0, stream=open("/dev/null", "w"))
    return run
