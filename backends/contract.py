"""The contract every engine adapter implements.

An adapter is a *batched, differentiable simulator*: ``num_envs`` independent worlds of one
task, advanced together by :meth:`BatchedSim.step`. Everything that crosses this boundary is a
torch tensor in the backend-neutral layout of :class:`SimState`, so algorithms and tasks never
see an engine type.

What an adapter writes (the abstract part, engine-specific):

* :meth:`BatchedSim._build` - build the engine model for ``self.task`` and ``self.num_envs``.
* one method ``_control_<kind>`` per :class:`ControlKind` it supports (``_control_joint_torque``,
  ``_control_joint_position_target``, ``_control_tet_activation``): the task's control tensor ->
  whatever its ``simulate`` consumes. A task whose kind has no such method is refused at build time.
* :meth:`BatchedSim.state_from_generalized` - a :class:`SimState` from generalized coordinates
  (root pose and velocity, joint positions and velocities, optional particles), differentiable.
* :meth:`BatchedSim.simulate` - ``(state, control) -> next state`` for one control step,
  differentiable through torch autograd w.r.t. the incoming state and the control.
* :meth:`BatchedSim.physics_mapping` - how the adapter applies every field of the task's
  :class:`simcore.PhysicsSpec` (engine parameter and conversion), or why a field cannot act on this
  task. The base class refuses, at build time and in one line naming the field, an adapter that
  leaves a field unaccounted for; a field the adapter cannot honour for this task is refused by the
  adapter itself (a :class:`BackendError` naming it). ``tests/test_physics_mapping.py`` perturbs every field
  and checks that what the mapping says acts does change the simulation, and what it calls inert
  does not.

Optional: :meth:`BatchedSim.bare_engine_rollout`, the same model stepped by the engine alone (the
reference ``throughput`` compares the adapter against).

What the base class provides once for every adapter:

* :meth:`BatchedSim.advance` - the pure transition: validates actions, maps them to engine
  controls through the task, simulates, and reports non-finite results per env.
* :meth:`BatchedSim.step` - ``advance`` from the current state, then :meth:`BatchedSim.commit`
  (the new state becomes the current one).
* :meth:`BatchedSim.reset` - fresh randomised initial states for some or all envs; the reset
  rows are detached, so the graph is cut for those envs only.
* :meth:`BatchedSim.cut_graph` - detach all envs (window boundary) or only some.

Every adapter receives ``max_graph_steps``: how many control steps back a backward pass may
reach (the harness passes the window length h). Adapters whose gradients need per-step buffers
(Newton's tapes) keep that many; others may ignore it. The state layout is defined in
:mod:`simcore`.
"""

from __future__ import annotations

import dataclasses
import functools
from abc import ABC, abstractmethod
from typing import ClassVar

import torch

from simcore import ControlKind, PhysicsSpec, SimState, StateLayout, TaskSpec, nonfinite_rows


class BackendError(RuntimeError):
    """Base class for errors raised by the backend layer."""


def option_number(
    options: dict, name: str, default, backend: str, low: float = 0.0, high: float | None = None, integer: bool = False
):
    """A numeric adapter option: ``options[name]`` if given, else ``default``; refused in one line
    (:class:`BackendError`) unless it is a finite number (an integer where ``integer``) in
    [``low``, ``high``] (``high`` None: up to 2**31 - 1 for an integer, any finite value otherwise).
    NaN, infinities, text, booleans and fractions where a count is meant are refused, never rounded."""
    import math

    value = options.get(name, default)
    kind = "an integer" if integer else "a number"
    top = (2**31 - 1 if integer else math.inf) if high is None else high
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if ok and integer:
        ok = float(value).is_integer()
    if not ok or not low <= value <= top:
        shown = (lambda x: f"{int(x):,}") if integer else (lambda x: f"{x:g}")
        span = f"in [{shown(low)}, {shown(top)}]" if math.isfinite(top) else f">= {shown(low)}"
        raise BackendError(f"{backend} option {name} must be {kind} {span}, got {value!r}")
    return int(value) if integer else float(value)


#: how a :meth:`BatchedSim.physics_mapping` entry says that a field cannot act on this task
INERT = "inert: "


MIB = 1 << 20


@dataclasses.dataclass(frozen=True)
class TaskCost:
    """What one task costs on an engine, as the adapter measured it: planning figures for the suite's
    first time estimate and for refusing a size the machine cannot hold, never a result. Memory is the
    growth of peak resident memory per env (docs/performance.md has the command that measures it)."""

    #: seconds per env step of a training epoch (simulation with gradients and the updates)
    train_s: float
    #: seconds per env step of an evaluation (no gradients)
    eval_s: float
    #: bytes one env adds without gradients, with gradients once (finite-difference worlds), and with
    #: gradients per step of the window; None: not measured (no memory estimate, nothing refused)
    bytes_per_env: tuple[float, float, float] | None = None


def inert_by_definition(task: TaskSpec) -> dict[str, str]:
    """The :class:`PhysicsSpec` fields that by the spec's own definition cannot act on ``task``, with
    why: the PD law's constants without position targets, the contact constants without a ground
    plane, the joint constants of a body without joints. Adapters start their mapping from this."""
    phys, inert = task.physics, {}
    if task.control_kind != ControlKind.JOINT_POSITION_TARGET:
        for name in ("pd_kp", "pd_kd", "torque_limits"):
            inert[name] = (
                f"{INERT}the PD law of joint position targets; task {task.name!r} sends {task.control_kind.value}"
            )
    if not phys.ground_plane:
        for name in ("contact_ke", "contact_kd", "contact_kf", "contact_mu"):
            inert[name] = f"{INERT}ground contact; the spec has no ground plane"
    if task.layout.num_dofs == 0:
        for name in ("joint_limit_ke", "joint_limit_kd", "joint_damping", "armature"):
            inert[name] = f"{INERT}task {task.name!r} has no articulated joints"
    return inert


class InvalidActionError(BackendError, ValueError):
    """Actions of the wrong shape or dtype, or with NaN/inf entries."""


class InvalidStateError(BackendError, ValueError):
    """Generalized coordinates of the wrong type or shape, or a root quaternion of zero length."""


class NonFiniteStateError(BackendError, FloatingPointError):
    """The simulation produced NaN or inf for some envs.

    ``env_ids`` lists them, so a caller can reset exactly those worlds.
    """

    def __init__(self, env_ids: list[int], step: int):
        self.env_ids = env_ids
        self.step_index = step
        shown = ", ".join(str(i) for i in env_ids[:16]) + (" ..." if len(env_ids) > 16 else "")
        super().__init__(f"non-finite simulation state in {len(env_ids)} env(s) [{shown}] at step {step}")


class BatchedSim(ABC):
    """A task simulated in ``num_envs`` worlds; see the module docstring."""

    #: registry name of the adapter, set by subclasses
    name: str = ""
    #: the tasks the contract test suite (harness.contract_suite, run by tests/test_contract.py) runs this adapter on
    contract_tasks: tuple[str, ...] = ("ant",)
    #: the keyword options the adapter reads; any other is refused at build time (a misspelt option
    #: would otherwise be silently ignored). ``None``: the adapter does not declare them (unchecked).
    known_options: tuple[str, ...] | None = None
    #: optional planning figures per task name, and per task under one option (``"ant gradients=adjoint"``);
    #: a task without one gets the suite's generic guess and no memory refusal (:meth:`task_cost`)
    costs: ClassVar[dict[str, TaskCost]] = {}
    #: optional: where results tables list this engine among others, lower first
    table_rank: int = 100
    #: optional: what ``contact-jacobians`` compares this adapter's step Jacobians with: "differences"
    #: (its own central differences over a sweep of steps) or "mujoco_c" (MuJoCo C in float64, for an
    #: adapter of MuJoCo's own model)
    contact_reference: str = "differences"

    def __init_subclass__(cls, **kwargs):
        """Every adapter's ``state_from_generalized`` checks its input first (:meth:`check_generalized`)."""
        super().__init_subclass__(**kwargs)
        impl = cls.__dict__.get("state_from_generalized")
        if impl is None or getattr(impl, "checks_input", False):
            return

        @functools.wraps(impl)
        def checked(self, joint_q, joint_qd, particle_q=None, particle_qd=None):
            self.check_generalized(joint_q, joint_qd, particle_q, particle_qd)
            return impl(self, joint_q, joint_qd, particle_q, particle_qd)

        checked.checks_input = True
        cls.state_from_generalized = checked

    def check_generalized(self, joint_q, joint_qd, particle_q=None, particle_qd=None) -> None:
        """Refuse coordinates an engine would misread, with one line naming what is expected."""
        layout, n = self.layout, self.num_envs
        expected = [("joint_q", joint_q, (n, layout.nq)), ("joint_qd", joint_qd, (n, layout.nv))]
        if layout.num_particles:
            p = layout.num_particles
            expected += [("particle_q", particle_q, (n, p, 3)), ("particle_qd", particle_qd, (n, p, 3))]
        elif particle_q is not None or particle_qd is not None:
            raise InvalidStateError(f"task {self.task.name!r} has no particles; particle_q/particle_qd must be None")
        for name, value, shape in expected:
            if not isinstance(value, torch.Tensor) or not value.is_floating_point():
                raise InvalidStateError(f"{name} must be a floating-point torch.Tensor, got {type(value).__name__}")
            if tuple(value.shape) != shape:
                raise InvalidStateError(f"{name} must have shape {shape}, got {tuple(value.shape)}")
        bad = nonfinite_rows(torch.cat((joint_q.detach(), joint_qd.detach()), dim=1))
        if bad:
            raise InvalidStateError(f"joint_q/joint_qd contain NaN or inf in env(s) {bad[:16]}")
        if layout.num_particles:
            bad = nonfinite_rows(torch.cat((particle_q.detach(), particle_qd.detach()), dim=1))
            if bad:
                raise InvalidStateError(f"particle state contains NaN or inf in env(s) {bad[:16]}")
        if layout.floating_base:
            norms = joint_q.detach()[:, 3:7].norm(dim=1)
            bad = (norms < 1e-8).nonzero().flatten().tolist()
            if bad:
                raise InvalidStateError(f"root quaternion (x, y, z, w) has zero length in env(s) {bad[:16]}")

    def __init__(
        self,
        task: TaskSpec,
        num_envs: int,
        device: str = "cpu",
        seed: int = 0,
        max_graph_steps: int = 64,
        **options,
    ):
        for name, value in (("num_envs", num_envs), ("max_graph_steps", max_graph_steps)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        self.task = task
        self.num_envs = num_envs
        self.device = torch.device(device)
        self.seed = int(seed)
        self.max_graph_steps = max_graph_steps
        self.options = self.merged_options(task, options)
        self.generator = torch.Generator(device="cpu").manual_seed(self.seed)
        self.step_count = 0
        supported = self.supported_control_kinds()
        if task.control_kind not in supported:
            raise BackendError(
                f"the {self.name} adapter supports control kinds {', '.join(k.value for k in supported)}; "
                f"task {task.name!r} needs {task.control_kind.value}"
            )
        self._build()
        self._check_physics_mapping()
        self._state: SimState = self._initial_state()

    def _check_physics_mapping(self) -> None:
        """Refuse an adapter that does not say how it applies some field of the task's physics spec."""
        mapping = self.physics_mapping()
        for f in dataclasses.fields(PhysicsSpec):
            if not str(mapping.get(f.name, "")).strip():
                raise BackendError(
                    f"the {self.name} adapter does not say how it applies PhysicsSpec.{f.name} to task "
                    f"{self.task.name!r}; it must map or refuse every field (BatchedSim.physics_mapping)"
                )

    @property
    def integrator(self) -> str:
        """The engine's integrator in words (result files and ``throughput`` name it)."""
        return self.name

    @classmethod
    def merged_options(cls, task, options: dict | None = None) -> dict:
        """The options an adapter of this class is built with for ``task``: the task's validated settings
        for it first, explicit ``options`` on top; a name outside :attr:`known_options` is refused."""
        merged = {**dict(getattr(task, "backend_options", {}).get(cls.name, {})), **(options or {})}
        if cls.known_options is not None:
            unknown = sorted(set(merged) - set(cls.known_options))
            if unknown:
                known = ", ".join(cls.known_options) or "none"
                raise BackendError(f"the {cls.name} adapter has no option {unknown[0]!r}; its options: {known}")
        return merged

    @classmethod
    def gradient_settings(cls, task, options: dict | None = None) -> dict:
        """The settings that make this adapter's gradients for ``task`` as it would be built with the
        explicit ``options`` (on top of its defaults and the task's ``backend_options``): finite-difference
        steps and schemes, for example. Empty for exact gradients. A bench run's and a gradient check's
        address include them, so a changed default is new work rather than a stale result reused."""
        return {}

    def physics_mapping(self) -> dict[str, str]:
        """How this adapter applies each :class:`PhysicsSpec` field to its task: ``{field: text}``, the
        text naming the engine parameter and the conversion, or starting with ``"inert: "`` and saying
        why the field cannot act on this task (:func:`inert_by_definition` gives the spec's own cases).
        A field the adapter cannot honour is refused in :meth:`_build`, not listed. Result files carry
        this mapping. The base class declares nothing, so an adapter that does not override it is
        refused at build time."""
        return {}

    def check_torque_limits(self) -> None:
        """JOINT_POSITION_TARGET tasks: one torque limit per actuated joint, or none."""
        limits = self.task.physics.torque_limits
        if limits and len(limits) != self.layout.num_dofs:
            raise BackendError(
                f"{len(limits)} torque limits for {self.layout.num_dofs} joints of task {self.task.name!r}"
            )

    def checked_soft_body(self):
        """TET_ACTIVATION tasks: the task's ``SoftBodySpec``, refused in one line if it is missing or
        does not match the task's layout."""
        task, layout = self.task, self.task.layout
        body = getattr(task, "soft_body", None)
        if body is None:
            raise BackendError(f"task {task.name!r} asks for tet activations but defines no soft_body")
        if (body.num_particles, body.num_tets) != (layout.num_particles, layout.num_tets):
            raise BackendError(
                f"soft body has {body.num_particles} particles and {body.num_tets} tets, task {task.name!r} "
                f"expects {layout.num_particles} and {layout.num_tets}"
            )
        return body

    @classmethod
    def supported_control_kinds(cls) -> list[ControlKind]:
        """The kinds this adapter has a ``_control_<kind>`` method for."""
        return [kind for kind in ControlKind if callable(getattr(cls, f"_control_{kind.value}", None))]

    def engine_control(self, control: torch.Tensor) -> torch.Tensor:
        """The task's control tensor through this adapter's method for the task's control kind.

        Non-finite controls (a task's mapping gone wrong, or a direct ``simulate`` call) are refused
        here, before any engine sees them."""
        ids = nonfinite_rows(control)
        if ids:
            raise InvalidActionError(
                f"{self.task.control_kind.value} control contains NaN or inf for env(s) {ids[:16]}"
            )
        return getattr(self, f"_control_{self.task.control_kind.value}")(control)

    def bare_engine_rollout(self, horizon: int, grad: bool = True) -> float | None:
        """Seconds for one window of ``horizon`` steps of the same model on the engine alone (no torch,
        no adapter): with ``grad``, the engine's work for a step with gradients (a tape's forward and
        backward; the perturbed worlds of finite differences), else forward only. ``None`` where the
        adapter has no such reference."""
        return None

    def gradient_step_cost(self, sample_worlds: int | None = None) -> dict | None:
        """A measured estimate of one control step with gradients for all envs, for adapters whose
        gradients are expensive enough to plan around (finite differences): ``seconds_per_step`` and
        how it was measured (on ``sample_worlds`` worlds, or the adapter's default). ``None`` where a
        step with gradients costs a few forward steps."""
        return None

    @classmethod
    def task_cost(cls, task: str, options: dict | None = None) -> TaskCost | None:
        """The adapter's planning figures for ``task`` (a preset's suffix ignored: the same robot) built
        with ``options``: those measured under one of the options where there are, else the task's."""
        task = task.split(".")[0]
        for key, value in sorted((options or {}).items()):
            if f"{task} {key}={value}" in cls.costs:
                return cls.costs[f"{task} {key}={value}"]
        return cls.costs.get(task)

    # -- adapter hooks --------------------------------------------------------------------
    @property
    def layout(self) -> StateLayout:
        """Static layout of one env's state: the task's, unless the engine's model lays it out otherwise."""
        return self.task.layout

    @abstractmethod
    def _build(self) -> None:
        """Create the engine model for ``self.task`` x ``self.num_envs``."""

    @abstractmethod
    def state_from_generalized(
        self,
        joint_q: torch.Tensor,
        joint_qd: torch.Tensor,
        particle_q: torch.Tensor | None = None,
        particle_qd: torch.Tensor | None = None,
    ) -> SimState:
        """A full state for all envs from generalized coordinates (differentiable)."""

    @abstractmethod
    def simulate(self, state: SimState, control: torch.Tensor) -> SimState:
        """Advance every env by one control step (``task.physics.frame_dt``), differentiably."""

    # -- the shared stateful API ----------------------------------------------------------
    @property
    def state(self) -> SimState:
        return self._state

    @state.setter
    def state(self, value: SimState) -> None:
        if not isinstance(value, SimState):
            raise InvalidStateError(f"state must be a SimState, got {type(value).__name__}")
        current = self._state.tensors() if getattr(self, "_state", None) is not None else {}
        for name, tensor in value.tensors().items():
            if tensor.shape[0] != self.num_envs:
                raise InvalidStateError(f"state.{name} has {tensor.shape[0]} rows for {self.num_envs} envs")
            mine = current.get(name)
            if mine is not None and (tuple(tensor.shape[1:]) != tuple(mine.shape[1:]) or tensor.dtype != mine.dtype):
                raise InvalidStateError(
                    f"state.{name} has per-env shape {tuple(tensor.shape[1:])} and dtype {tensor.dtype}; this "
                    f"sim's is {tuple(mine.shape[1:])}, {mine.dtype}"
                )
        self._state = value

    def _initial_state(self) -> SimState:
        """Freshly randomised, detached initial states for all envs (callers pick rows)."""
        with torch.no_grad():
            parts = self.task.sample_initial_state(self.num_envs, self.generator)
            return self.state_from_generalized(*(part.to(self.device) for part in parts)).detach()

    def _env_mask(self, env_ids: torch.Tensor | list[int]) -> torch.Tensor:
        env_ids = torch.as_tensor(env_ids, dtype=torch.long, device=self.device)
        if env_ids.numel() and (env_ids.min() < 0 or env_ids.max() >= self.num_envs):
            raise IndexError(f"env ids must lie in [0, {self.num_envs}), got {env_ids.tolist()}")
        mask = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        mask[env_ids] = True
        return mask

    def reset(self, env_ids: torch.Tensor | list[int] | None = None) -> SimState:
        """Re-initialise some envs (all if ``None``); their graph history is dropped."""
        if env_ids is None:
            self._state = self._initial_state()
        else:
            mask = self._env_mask(env_ids)
            if mask.any():
                self._state = self._state.select(mask, self._initial_state())
        return self._state

    def cut_graph(self, env_ids: torch.Tensor | list[int] | None = None) -> SimState:
        """Drop the autograd history of all envs (``None``: a window boundary) or of some."""
        if env_ids is None:
            self._state = self._state.detach()
        else:
            self._state = self._state.select(self._env_mask(env_ids), self._state.detach())
        return self._state

    def validate_actions(self, actions: torch.Tensor) -> torch.Tensor:
        """Check shape, dtype and finiteness before anything reaches the engine."""
        expected = (self.num_envs, self.task.action_dim)
        if not isinstance(actions, torch.Tensor):
            raise InvalidActionError(f"actions must be a torch.Tensor, got {type(actions).__name__}")
        if tuple(actions.shape) != expected:
            raise InvalidActionError(f"actions must have shape {expected}, got {tuple(actions.shape)}")
        if not actions.is_floating_point():
            raise InvalidActionError(f"actions must be a floating-point tensor, got {actions.dtype}")
        ids = nonfinite_rows(actions)
        if ids:
            raise InvalidActionError(f"actions contain NaN or inf for env(s) {ids[:16]}")
        return actions.to(device=self.device, dtype=torch.float32)

    def advance(self, state: SimState, actions: torch.Tensor) -> SimState:
        """The state one control step after ``state`` under ``actions`` (N, action_dim); pure.

        Raises :class:`NonFiniteStateError` naming the envs whose state became NaN/inf.
        """
        actions = self.validate_actions(actions)
        next_state = self.simulate(state, self.task.actions_to_control(actions))
        bad = next_state.nonfinite_envs()
        if bad:
            raise NonFiniteStateError(bad, self.step_count + 1)
        return next_state

    def step(self, actions: torch.Tensor) -> SimState:
        """Apply ``actions`` for one control step from the current state and return the next state.

        On :class:`NonFiniteStateError` the internal state stays at the last finite state, so the
        caller can reset the named envs.
        """
        return self.commit(self.advance(self._state, actions))

    def commit(self, next_state: SimState) -> SimState:
        """Make ``next_state`` (one :meth:`advance` from the current state) the current state."""
        self.step_count += 1
        self._state = next_state
        return next_state
