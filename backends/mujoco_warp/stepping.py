"""The control-step loop every MuJoCo-Warp model here shares: substeps with a hook before each, each
substep one ``mujoco_warp.step`` run directly or replayed from a captured graph (:class:`SubstepReplay`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco_warp as mjw
import torch
import warp as wp


class SubstepReplay:
    """``mujoco_warp.step(model, data)``, captured into a Warp graph per ``Data`` and replayed.

    One ``mujoco_warp.step`` is ~100 kernel launches; on Warp's CPU device each costs tens of
    microseconds of Python (argument packing) before its kernel runs, which is what makes a step of
    64 Ant worlds launch-bound. ``wp.capture_launch`` replays the same launches on the same buffers
    from C++, bit-identically (tests/test_mujoco_warp_ant.py). A ``Data`` keeps its buffers for
    its lifetime and every input (state, applied forces) is written into them in place, so its graph
    stays valid. The first step of a ``Data`` runs directly (it loads MuJoCo-Warp's kernels), the
    second is captured, the rest replay. ``enabled=False`` (option ``graph_capture=0``) always steps
    directly.
    """

    @dataclass
    class _Entry:
        data: mjw.Data  # held, so that its id is not reused while the entry exists
        model: mjw.Model
        steps: int = 0
        graph: wp.Graph | None = None

    def __init__(self, enabled: bool, wp_device: str):
        self.enabled, self.wp_device = enabled, wp_device
        self._entries: dict[int, SubstepReplay._Entry] = {}  # by id(data)

    def forget(self, data: mjw.Data) -> None:
        """Drop ``data``'s captured graph (and the entry's hold on ``data``), e.g. before freeing it."""
        entry = self._entries.get(id(data))
        if entry is not None and entry.data is data:
            del self._entries[id(data)]

    def step(self, model: mjw.Model, data: mjw.Data) -> None:
        if not self.enabled:
            mjw.step(model, data)
            return
        entry = self._entries.get(id(data))
        if entry is None or entry.data is not data or entry.model is not model:
            entry = self._entries[id(data)] = SubstepReplay._Entry(data, model)
        entry.steps += 1
        if entry.graph is None and entry.steps > 1:
            with wp.ScopedCapture(device=self.wp_device) as capture:  # records, runs nothing
                mjw.step(model, data)
            entry.graph = capture.graph
        if entry.graph is None:
            mjw.step(model, data)
        else:
            wp.capture_launch(entry.graph)


def run_substeps(
    model: mjw.Model,
    data: mjw.Data,
    view: dict[str, torch.Tensor],
    substeps: int,
    stepper: SubstepReplay,
    before_substep: Callable[[], None] | None,
    buffers: tuple[int, int],
    after_substep: Callable[[], None] | None = None,
) -> torch.Tensor:
    """``substeps`` ``mujoco_warp.step`` calls on ``data`` (its inputs already in ``view``), calling
    ``before_substep`` (which may read ``view`` and write ``qfrc_applied``) before each and
    ``after_substep`` (which may read ``data``'s constraint rows) after each; returns the next engine
    rows ``[qpos, qvel]``. A contact or constraint overflow (``buffers`` = (nconmax, njmax)) raises
    instead of returning a state MuJoCo-Warp computed with contacts dropped."""
    from backends.contract import BackendError

    wp_device = stepper.wp_device
    with wp.ScopedDevice(wp_device):
        for _ in range(substeps):
            if before_substep is not None:
                wp.synchronize_device(wp_device)  # the hook reads this substep's state through torch
                before_substep()
            stepper.step(model, data)
            if after_substep is not None:
                wp.synchronize_device(wp_device)
                after_substep()
        wp.synchronize_device(wp_device)
    if bool(view["overflow"].any()):
        nconmax, njmax = buffers
        raise BackendError(
            f"mujoco_warp ran out of contact or constraint buffers (nconmax={nconmax}, "
            f"njmax={njmax}); raise the nconmax / njmax options"
        )
    return torch.cat((view["qpos"], view["qvel"]), dim=1).clone()
