"""The contract suite: the checks every adapter must pass, importable by any package's tests.

Use it from a pytest file by subclassing :class:`ContractSuite` under a name pytest collects::

    from harness.contract_suite import ContractSuite

    class TestMyEngineContract(ContractSuite):
        backend_names = ("my_engine",)  # registry names; empty: every registered adapter

Each named adapter (found through the ``diffsim_bench.backends`` entry points, built-in or plugged
in) runs on each of its ``contract_tasks``. Checked: shapes and dtypes of the backend-neutral state,
seeding and determinism, world-frame root velocities, reset and graph-cut semantics, gradients
against finite differences on a smooth segment, repeated backward passes in contact, per-env NaN
reporting, refusal of unsupported control kinds, of bad actions and of misspelt options, and the
bare engine reference if offered.

Needs pytest, which is in the ``test`` extra (``pip install "diffsim-bench[test]"``), not a runtime
dependency. It lives in ``harness`` because it drives adapters through the harness's gradient check
and the task registry, which adapters themselves never import.
"""

from __future__ import annotations

import dataclasses
import math

import torch

try:
    import pytest
except ImportError as exc:  # pragma: no cover - a runtime install without the test extra
    raise ImportError('harness.contract_suite needs pytest: pip install "diffsim-bench[test]"') from exc

import backends
from backends import BackendError, InvalidActionError, NonFiniteStateError
from harness.checks.gradcheck import DEFAULT_TOLERANCE, gradcheck
from simcore import ControlKind, quat_from_angle_axis, quat_mul
from tasks import make_task

N = 3


def contract_cases(backend_names=(), task_names=(), classes: dict | None = None) -> list[tuple[str, str]]:
    """(adapter, task) pairs: every named adapter (all registered ones if none are named) on each of
    its ``contract_tasks`` (those among ``task_names`` when given); ``classes`` names adapter classes that
    are not registered."""
    names = tuple(backend_names) or tuple(backends.available())
    return [
        (name, task)
        for name in names
        for task in ((classes or {}).get(name) or backends.get(name)).contract_tasks
        if not task_names or task in task_names
    ]


def with_options(cls, options: dict):
    """``cls`` with ``options`` given to every instance (explicit keyword arguments win): the suite run
    on one of an adapter's modes, e.g. another gradient mode."""
    if not options:
        return cls
    fixed = dict(options)

    class Configured(cls):
        def __init__(self, task, **kwargs):
            super().__init__(task, **{**fixed, **kwargs})

    Configured.__name__ = Configured.__qualname__ = f"{cls.__name__}[{', '.join(f'{k}={v}' for k, v in fixed.items())}]"
    return Configured


def _sim(adapter, num_envs=N, seed=0):
    cls, task = adapter
    return cls(task, num_envs=num_envs, seed=seed, max_graph_steps=32)


def _actions(task, n, gen, grad=False):
    return (0.5 * (2 * torch.rand(n, task.action_dim, generator=gen) - 1)).requires_grad_(grad)


class ContractSuite:
    """The contract checks as pytest tests, parametrised over ``(adapter class, task)`` pairs
    (:func:`contract_cases`); see the module docstring. Not collected itself (its name does not start
    with ``Test``): subclass it."""

    #: the registry names of the adapters to check; empty: every registered adapter
    backend_names: tuple[str, ...] = ()
    #: adapter options every sim of the suite is built with (e.g. ``{"gradients": "adjoint"}``)
    backend_options: dict = {}
    #: the tasks to check, among each adapter's ``contract_tasks``; empty: all of them
    task_names: tuple[str, ...] = ()
    #: adapter classes checked without registering them, by the name ``backend_names`` gives them
    adapter_classes: dict = {}

    def pytest_generate_tests(self, metafunc):
        """pytest calls this for every test of the class: ``adapter`` takes each contract case."""
        if "adapter" in metafunc.fixturenames:
            cases = contract_cases(self.backend_names, self.task_names, self.adapter_classes)
            ids = [f"{b}-{t}" for b, t in cases]
            metafunc.parametrize("adapter", cases, ids=ids, indirect=True, scope="class")

    @pytest.fixture(scope="class")
    @classmethod
    def adapter(cls, request):
        """(adapter class, task instance) of one contract case."""
        name, task_name = request.param
        adapter_class = cls.adapter_classes.get(name) or backends.get(name)
        return with_options(adapter_class, cls.backend_options), make_task(task_name)

    def test_state_shapes_and_dtypes(self, adapter):
        sim = _sim(adapter)
        layout = sim.layout
        assert layout == adapter[1].layout
        with torch.no_grad():
            state = sim.step(torch.zeros(N, adapter[1].action_dim))
        assert state.joint_q.shape == (N, layout.nq) and state.joint_qd.shape == (N, layout.nv)
        assert state.engine.dim() == 2 and state.engine.shape[0] == N
        for value in state.tensors().values():
            assert value.dtype == torch.float32 and value.device == sim.device
        assert state.dof_q(layout).shape == (N, layout.num_dofs)

    def test_seeding_and_determinism(self, adapter):
        task = adapter[1]
        runs = []
        for _ in range(2):
            sim = _sim(adapter, seed=5)
            gen = torch.Generator().manual_seed(0)
            with torch.no_grad():
                for _ in range(3):
                    sim.step(_actions(task, N, gen))
            runs.append(sim.state.engine)
        assert torch.equal(runs[0], runs[1])
        assert not torch.equal(_sim(adapter, seed=5).state.engine, _sim(adapter, seed=6).state.engine)

    def test_floating_base_velocities_are_world_frame(self, adapter):
        """Root linear velocity moves the root along world x; angular velocity turns it about world z,
        with the body tilted so that a body-frame rate would turn it about another axis."""
        cls, task = adapter
        if not task.layout.floating_base:
            pytest.skip("no floating base")
        if task.control_kind == ControlKind.JOINT_POSITION_TARGET:  # no PD torques: a free-flying rigid body
            task = type(task)(dataclasses.replace(task.physics, pd_kp=0.0, pd_kd=0.0))
        sim = _sim((cls, task))
        q, qd = task.sample_initial_state(N, torch.Generator().manual_seed(0))
        q[:, 2] = 2.0  # in the air
        tilt = quat_from_angle_axis(torch.tensor(math.pi / 2), torch.tensor([1.0, 0.0, 0.0]))
        q[:, 0:2], q[:, 3:7] = 0.0, tilt
        qd.zero_()
        qd[:, 0] = 1.0
        qd[:, 5] = 1.0
        with torch.no_grad():
            state = sim.simulate(sim.state_from_generalized(q, qd), torch.zeros(N, task.action_dim))
        dt = task.physics.frame_dt
        assert torch.allclose(state.root_pos[:, 0], torch.full((N,), dt), rtol=0.05)
        assert torch.allclose(state.root_lin_vel[:, 0], torch.ones(N), atol=0.02)
        expected = quat_mul(quat_from_angle_axis(torch.tensor(dt), torch.tensor([0.0, 0.0, 1.0])), tilt)
        dots = (state.root_quat * expected).sum(-1).abs()
        assert torch.all(dots > 1 - 1e-4), dots
        assert torch.allclose(state.root_ang_vel[:, 2], torch.ones(N), atol=0.05)

    def test_reset_touches_only_the_named_envs_and_cuts_only_their_graph(self, adapter):
        task = adapter[1]
        sim = _sim(adapter)
        gen = torch.Generator().manual_seed(1)
        first = _actions(task, N, gen, grad=True)
        sim.step(first)
        before = sim.state.engine.detach().clone()
        sim.reset([1])
        after = sim.state.engine.detach()
        assert torch.equal(after[[0, 2]], before[[0, 2]]) and not torch.equal(after[1], before[1])
        state = sim.step(_actions(task, N, gen))
        state.engine.sum().backward()
        per_env = first.grad.abs().sum(dim=1)
        assert per_env[1] == 0 and per_env[0] > 0 and per_env[2] > 0

    def test_window_cut_leaves_no_path(self, adapter):
        task = adapter[1]
        sim = _sim(adapter)
        gen = torch.Generator().manual_seed(2)
        before = _actions(task, N, gen, grad=True)
        sim.step(before)
        sim.cut_graph()
        after = _actions(task, N, gen, grad=True)
        state = sim.step(after)
        g_before, g_after = torch.autograd.grad(state.engine.sum(), (before, after), allow_unused=True)
        assert g_before is None and g_after.abs().sum() > 0

    def test_gradients_match_finite_differences_on_a_smooth_segment(self, adapter):
        """Two control steps (the chain across a step boundary included): the check costs one rollout pair
        per coordinate, i.e. ~250 control steps on the Go2, which a finite-difference adapter pays in full.
        Longer segments are checked per task: the Ant's tests (8 and 4 steps) and ``tox -e bench``."""
        sim = _sim(adapter, num_envs=2, seed=1)
        airborne = sim.layout.floating_base or sim.layout.num_particles  # a body that can be lifted off the ground
        height = adapter[1].airborne_height if airborne else None
        result = gradcheck(sim, steps=2, seed=0, start_height=height)
        assert result.action_rel_error < DEFAULT_TOLERANCE, result
        assert result.state_rel_error < DEFAULT_TOLERANCE, result

    def test_a_repeated_backward_pass_returns_the_same_gradient_in_contact(self, adapter):
        """torch's ``retain_graph``: a second backward through the same steps must not change the answer.
        Newton's kernels rewrite forward values while their tape replays, so an adapter that replays a tape
        twice without restoring them returns a different gradient the second time, and only where contact
        forces act (the in-contact Jacobian check runs one backward pass per output coordinate)."""
        task = adapter[1]
        sim = _sim(adapter)
        gen = torch.Generator().manual_seed(5)
        with torch.no_grad():  # from the initial states to the ground: the legged robots land within these steps
            for _ in range(20):
                sim.step(torch.zeros(N, task.action_dim))
        actions = [_actions(task, N, gen, grad=True) for _ in range(2)]
        for a in actions:
            state = sim.step(a)
        loss = (state.engine * torch.linspace(-1.0, 1.0, state.engine.shape[1])).sum()
        first = torch.autograd.grad(loss, actions, retain_graph=True)
        second = torch.autograd.grad(loss, actions)
        for g1, g2 in zip(first, second, strict=True):
            assert g1.abs().sum() > 0 and torch.equal(g1, g2), (g1 - g2).abs().max()

    def test_non_finite_simulation_is_reported_per_env(self, adapter):
        task = adapter[1]
        sim = _sim(adapter)
        parts = list(task.sample_initial_state(N, torch.Generator().manual_seed(0)))
        state = sim.state_from_generalized(*parts)  # which refuses non-finite coordinates: poison the engine row
        engine = state.engine.clone()
        engine[1, -1] = float("inf")
        sim.state = dataclasses.replace(state, engine=engine)
        with pytest.raises(NonFiniteStateError) as info, torch.no_grad():
            sim.step(torch.zeros(N, task.action_dim))
        assert info.value.env_ids == [1]

    def test_an_unsupported_control_kind_is_refused_at_build_time_in_one_line(self, adapter):
        cls, task = adapter
        supported = cls.supported_control_kinds()
        assert ControlKind.JOINT_TORQUE in supported or supported, "an adapter must support some control kind"
        missing = [kind for kind in ControlKind if kind not in supported]
        if not missing:
            pytest.skip("this adapter supports every control kind")
        other = type(f"{type(task).__name__}Other", (type(task),), {"control_kind": missing[0]})()
        with pytest.raises(BackendError) as info:
            cls(other, num_envs=1)
        message = str(info.value)
        assert "\n" not in message and missing[0].value in message
        assert all(kind.value in message for kind in supported)

    @pytest.mark.parametrize("kind", ["shape", "dtype", "nan", "inf"])
    def test_bad_actions_are_refused(self, adapter, kind):
        task = adapter[1]
        sim = _sim(adapter)
        actions = torch.zeros(N, task.action_dim)
        if kind == "shape":
            actions = torch.zeros(N, task.action_dim + 1)
        elif kind == "dtype":
            actions = actions.long()
        else:
            actions[2, 0] = float(kind)
        with pytest.raises(InvalidActionError):
            sim.step(actions)

    def test_a_bare_engine_reference_if_offered_times_both_passes_and_leaves_the_envs_alone(self, adapter):
        """``throughput`` divides by these seconds: positive and finite, or None (no reference)."""
        sim = _sim(adapter, num_envs=2)
        before = sim.state.engine.detach().clone()
        for grad in (False, True):
            seconds = sim.bare_engine_rollout(2, grad=grad)
            assert seconds is None or (math.isfinite(seconds) and seconds > 0), (grad, seconds)
        assert torch.equal(sim.state.engine, before)

    def test_a_misspelt_adapter_option_is_refused_in_one_line(self, adapter):
        cls, task = adapter
        if cls.known_options is None:
            pytest.skip(f"the {cls.name} adapter does not declare its options")
        with pytest.raises(BackendError, match=f"the {cls.name} adapter has no option 'no_such_option'; its options: "):
            cls(task, num_envs=1, no_such_option=1)
