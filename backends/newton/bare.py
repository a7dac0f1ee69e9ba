"""The bare Newton reference ``throughput`` compares the adapter against (:func:`bare_tape_rollout`)."""

from __future__ import annotations

import contextlib
import time

import numpy as np
import warp as wp


def bare_tape_rollout(sim, horizon: int, repeats: int = 1, seed: int = 0, grad: bool = True) -> float:
    """Seconds per forward+backward of ``horizon`` frames on raw Newton/Warp, no torch involved
    (``grad=False``: the same frames forward only, without a tape).

    The reference for the adapter's overhead: the same model, solver, contact pipeline, substeps
    and fresh state buffers per substep, one tape over the whole window, a loss on the final
    body positions (particle positions for a soft body), ``tape.backward`` and ``tape.zero``.
    Position-target tasks run the same PD kernel per substep as the adapter. Featherstone runs as
    raw Newton does, on the solver's own system-matrix buffers (the adapter points the solver at
    per-frame copies instead, so that its replay is exact; the arithmetic is the same). When the
    adapter captures graphs (option ``graph_capture``), so does this: the whole window is captured
    once and replayed, so that the ratio compares like with like. Returns the best of ``repeats``
    passes after a warm-up pass (the only pass when ``repeats`` is 0).
    """
    family = sim.family
    model, solver, pipeline, phys = family.model, family.solver, family.pipeline, sim.task.physics
    subs = phys.substeps
    states = [model.state(requires_grad=grad) for _ in range(horizon * subs + 1)]
    contacts = [pipeline.contacts() for _ in range(horizon)]
    loss = wp.zeros(1, dtype=float, device=model.device, requires_grad=grad)
    family.load_state(states[0], sim.state.engine, cache=False)
    control = family.bare_controls(horizon, np.random.default_rng(seed), grad, sim.state)

    def window() -> None:
        tape = wp.Tape() if grad else contextlib.nullcontext()
        for t in range(horizon):
            pipeline.collide(states[t * subs], contacts[t])
            with tape:
                for s in range(t * subs, (t + 1) * subs):
                    states[s].clear_forces()
                    solver.step(states[s], states[s + 1], control(t, s, states[s]), contacts[t], phys.sim_dt)
        if not grad:
            return
        with tape:
            family.bare_loss(states[-1], loss)
        tape.backward(loss)
        tape.zero()
        loss.zero_()

    best = float("inf")
    graph = None
    for attempt in range(repeats + 1):  # the first pass warms caches (and captures) and is not counted
        start = time.perf_counter()
        if sim.graph_capture:  # as the adapter runs its frames: the whole window captured once, then replayed
            if graph is None:
                with wp.ScopedCapture(device=model.device) as capture:
                    window()
                graph = capture.graph
            wp.capture_launch(graph)
        else:
            window()
        wp.synchronize_device(model.device)
        if attempt > 0 or repeats == 0:
            best = min(best, time.perf_counter() - start)
    return best
