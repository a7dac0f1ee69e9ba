"""The control-step loop every MuJoCo-Warp model here shares: substeps with a hook before each."""

from __future__ import annotations

from collections.abc import Callable

import mujoco_warp as mjw
import torch
import warp as wp


def run_substeps(
    model: mjw.Model,
    data: mjw.Data,
    view: dict[str, torch.Tensor],
    substeps: int,
    wp_device: str,
    before_substep: Callable[[], None] | None,
    buffers: tuple[int, int],
) -> torch.Tensor:
    """``substeps`` ``mujoco_warp.step`` calls on ``data`` (its inputs already in ``view``), calling
    ``before_substep`` (which may read ``view`` and write ``qfrc_applied``) before each; returns the
    next engine rows ``[qpos, qvel]``. A contact or constraint overflow (``buffers`` = (nconmax,
    njmax)) raises instead of returning a state MuJoCo-Warp computed with contacts dropped."""
    from backends.contract import BackendError

    with wp.ScopedDevice(wp_device):
        for _ in range(substeps):
            if before_substep is not None:
                wp.synchronize_device(wp_device)  # the hook reads this substep's state through torch
                before_substep()
            mjw.step(model, data)
        wp.synchronize_device(wp_device)
    if bool(view["overflow"].any()):
        nconmax, njmax = buffers
        raise BackendError(
            f"mujoco_warp ran out of contact or constraint buffers (nconmax={nconmax}, "
            f"njmax={njmax}); raise the nconmax / njmax options"
        )
    return torch.cat((view["qpos"], view["qvel"]), dim=1).clone()
