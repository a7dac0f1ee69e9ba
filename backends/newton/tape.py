"""Frames, tapes and graph capture: one control step of any engine family, differentiable in torch.

* One control step is one :class:`Frame`: ``substeps + 1`` fresh ``State`` buffers, its own control
  and contact buffers (and the family's own: :meth:`EngineFamily.add_frame_buffers`), and its own
  tape. Nothing in a frame is overwritten while the torch graph that references it may still call
  ``backward``, so the tape replays the data it recorded.
* Frames live in a ring of ``max_graph_steps`` (grown lazily). A backward that reaches a frame
  already reused by a later step raises instead of returning a wrong gradient; cut the graph at
  window boundaries (``cut_graph()``) or raise ``max_graph_steps``.
* Contact candidates are found once per control step outside the tape (not differentiated: which
  pairs touch is discrete); contact forces are re-evaluated from the current poses at every substep
  inside the tape. A contact gap of ``contact_gap`` metres keeps candidates valid for the motion
  within one control step.
* A tape's backward pass is not read-only: replaying Featherstone's kernels rewrites some of their
  forward outputs in place (the joint forces and accelerations, the external wrenches), so a second
  backward through the same frame would replay from changed values and return a different, wrong
  gradient. Before every backward after a frame's first, the frame's forward runs again from its
  own (unchanged) inputs, so ``retain_graph`` backward passes all return the first one's gradient.
* Without grad (``torch.no_grad()`` or inputs that need none) the step runs without a tape on two
  ping-pong buffers (the scratch frame).
* Graph capture (option ``graph_capture``, on by default on CPU): a frame's Warp work (the loaded
  state's body poses, collision, substeps, IK; then its tape's backward pass and the zeroing of its
  gradients) is captured once, the second time the frame is used, and replayed with
  ``wp.capture_launch`` ever after. Warp's Python-side launch path (argument packing, tape
  bookkeeping) costs ~80 us per kernel launch on this CPU, about as much as the kernels themselves
  at 64 Ant envs; the replay runs the same kernels on the same buffers from C++. A frame's buffers
  never change identity, so its graphs stay valid; what changes per step (the state and control
  tensors, the incoming gradients) is copied into those buffers outside the graphs. Outputs and
  gradients are bit-identical to the uncaptured path (tests/test_newton_ant.py).
"""

from __future__ import annotations

import newton
import torch
import warp as wp

from backends.contract import BackendError
from backends.newton.family import EngineFamily


class TorchViews:
    """(N, -1) torch views of Warp arrays.

    ``views(array)``: for arrays that live as long as the adapter (frames, their gradients, the
    control buffers), made once and cached: frames never swap their buffers, so a view stays valid,
    and a cached view spares ``wp.to_torch`` / ``wp.from_torch`` + ``wp.copy`` on every step (tens of
    microseconds each). ``views(array, cache=False)`` for anyone else's arrays (the bare rollout's,
    forward kinematics'): a plain view, nothing kept.
    """

    def __init__(self, num_envs: int):
        self.num_envs = num_envs
        self._cache: dict[int, tuple[wp.array, torch.Tensor]] = {}

    def __call__(self, array: wp.array, cache: bool = True) -> torch.Tensor:
        # made in grad mode whatever the caller's mode: torch refuses to use in grad mode a view made
        # under no_grad once its base (the tensor wp.to_torch keeps on the array) was written in place
        if not cache:
            with torch.enable_grad():
                return wp.to_torch(array).reshape(self.num_envs, -1)
        entry = self._cache.get(id(array))
        if entry is None or entry[0] is not array:  # holding the array keeps its id from being reused
            with torch.enable_grad():
                entry = self._cache[id(array)] = (array, wp.to_torch(array).reshape(self.num_envs, -1))
        return entry[1]


class Frame:
    """Every Warp buffer one control step touches, so its tape can be replayed later. The engine
    family adds its own (PD targets, per-frame system matrices, IK outputs) as attributes."""

    def __init__(self, family: EngineFamily, num_states: int):
        model = family.model
        self.states = [model.state(requires_grad=True) for _ in range(num_states)]
        self.control = model.control(requires_grad=True)  # one control for the whole step (or per substep: PD)
        self.contacts = family.pipeline.contacts()
        family.add_frame_buffers(self)
        self.tape: wp.Tape | None = None
        self.forward_work = None  # the forward's Warp work, to run again before a repeated backward
        self.backward_passes = 0  # backward passes since the last forward
        self.generation = 0
        # captured once per frame when the adapter captures (see the module docstring)
        self.forward_graph = None
        self.forward_uses = 0
        self.backward_graph = None
        self.zero_graph = None
        self.last: newton.State | None = None  # the state the forward ends in (ping-pong: either buffer)


class FrameStepper:
    """Steps ``family``'s engine one control step at a time: on a ring of taped frames when torch
    wants gradients (:class:`_TapedStep`), else untaped on a scratch frame."""

    def __init__(self, family: EngineFamily, max_graph_steps: int, graph_capture: bool, wp_device: str):
        self.family = family
        self.views = family.views
        self.num_envs = family.num_envs
        self.substeps = family.physics.substeps
        self.max_graph_steps = max_graph_steps
        self.graph_capture = graph_capture
        self.wp_device = wp_device
        self.frames: list[Frame] = []
        self.cursor = 0
        self.scratch = Frame(family, 2)

    def step(self, engine: torch.Tensor, control: torch.Tensor):
        """(next engine rows, joint_q, joint_qd) after one control step; differentiable when needed."""
        if torch.is_grad_enabled() and (engine.requires_grad or control.requires_grad):
            return _TapedStep.apply(self, engine, control)
        return self.forward_no_grad(engine, control)

    def _load_inputs(self, frame: Frame, engine: torch.Tensor, control: torch.Tensor) -> None:
        """Copy the step's inputs into the frame; what the engine derives from them (Featherstone's body
        poses) is the first thing the step's Warp work does, so a captured step replays it too."""
        self.family.load_state(frame.states[0], engine, complete=False)
        with torch.no_grad():
            self.views(self.family.control_array(frame)).copy_(control.reshape(self.num_envs, -1))

    def _replay(self, frame: Frame, name: str, work) -> None:
        """Run ``work()`` directly, or from the graph ``frame.<name>`` (captured on the spot if missing).

        A frame's forward runs directly on its first use and is captured on its second: capturing costs
        two to three eager runs (Warp records every launch), so a frame used once (a short test, an
        unrolled graph longer than any window) is not made slower. Its backward and zeroing graphs are
        captured from the tape the forward graph recorded, so they follow the forward.
        """
        if name == "forward_graph":
            frame.forward_uses += 1
            use_graph = self.graph_capture and frame.forward_uses > 1
        else:
            use_graph = frame.forward_graph is not None
        if not use_graph:
            work()
            return
        graph = getattr(frame, name)
        if graph is None:
            with wp.ScopedCapture(device=self.wp_device) as capture:  # records; runs nothing yet
                work()
            graph = capture.graph
            setattr(frame, name, graph)
        wp.capture_launch(graph)

    def forward_no_grad(self, engine: torch.Tensor, control: torch.Tensor):
        family, frame = self.family, self.scratch
        self._load_inputs(frame, engine, control)

        def work() -> None:
            a, b = frame.states
            family.complete_loaded_state(a)
            family.pipeline.collide(a, frame.contacts)
            for s in range(self.substeps):
                family.substep(a, b, frame, s)
                a, b = b, a
            family.finish_step(frame, a)
            frame.last = a

        self._replay(frame, "forward_graph", work)
        return family.outputs(frame, frame.last)

    def _next_frame(self) -> Frame:
        if len(self.frames) < self.max_graph_steps:
            self.frames.append(Frame(self.family, self.substeps + 1))
            frame = self.frames[-1]
        else:
            frame = self.frames[self.cursor % self.max_graph_steps]
        self.cursor += 1
        frame.generation += 1
        return frame

    def forward_taped(self, engine: torch.Tensor, control: torch.Tensor) -> Frame:
        family, frame = self.family, self._next_frame()
        self._load_inputs(frame, engine, control)

        def work() -> None:
            states = frame.states
            family.complete_loaded_state(states[0])  # outside the tape, as the engine rows' copy is
            family.pipeline.collide(states[0], frame.contacts)  # discrete: outside the tape
            tape = wp.Tape()
            with tape:
                for s in range(self.substeps):
                    family.substep(states[s], states[s + 1], frame, s, tape)
                family.finish_step(frame, states[-1])
            frame.tape = tape  # a captured frame keeps the tape its graphs were recorded from

        frame.forward_work, frame.backward_passes = work, 0
        self._replay(frame, "forward_graph", work)
        return frame

    def backward_taped(self, frame: Frame, generation: int, grad_engine, grad_q, grad_qd):
        if frame.generation != generation:
            raise BackendError(
                f"backward reached a step more than max_graph_steps={self.max_graph_steps} steps old whose "
                "buffers were reused; call cut_graph() at window boundaries or raise max_graph_steps"
            )
        if frame.backward_passes:  # the last backward rewrote forward values: restore them (module docstring)
            self._replay(frame, "forward_graph", frame.forward_work)
        frame.backward_passes += 1
        family = self.family
        # the incoming gradients go into the outputs' own gradient buffers (zero until now: each
        # backward ends by zeroing the frame's gradients), which is what tape.backward(grads=...) does
        for array, g in family.output_seeds(frame, grad_engine, grad_q, grad_qd):
            self.views(array.grad).copy_(g)
        self._replay(frame, "backward_graph", frame.tape.backward)
        grad_engine_in = family.join_engine(*(a.grad for a in family.state_arrays(frame.states[0])))
        grad_control = self.views(family.control_array(frame).grad).clone()
        # the backward registered every gradient buffer it touched with the tape: zero them all
        self._replay(frame, "zero_graph", frame.tape.zero)
        return grad_engine_in, grad_control


class _TapedStep(torch.autograd.Function):
    """(engine state, engine control) -> (next engine state, joint_q, joint_qd) for one control step."""

    @staticmethod
    def forward(ctx, stepper: FrameStepper, engine: torch.Tensor, control: torch.Tensor):
        frame = stepper.forward_taped(engine, control)
        ctx.stepper, ctx.frame, ctx.generation = stepper, frame, frame.generation
        return stepper.family.outputs(frame, frame.states[-1])

    @staticmethod
    def backward(ctx, grad_engine, grad_q, grad_qd):
        grads = ctx.stepper.backward_taped(ctx.frame, ctx.generation, grad_engine, grad_q, grad_qd)
        return None, *grads
