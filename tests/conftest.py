"""Shared fixtures. Engine-backed fixtures are module-scoped: Warp compiles kernels on first use."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared"


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
