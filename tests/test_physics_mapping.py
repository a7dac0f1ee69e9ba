"""Every adapter applies every PhysicsSpec field or refuses it; none is silently ignored.

For every registered adapter (plug-ins included) on each of its contract tasks, each field of the
task's physics spec is perturbed in turn: a field the adapter's :meth:`physics_mapping` says acts
must change the simulated states (two scenarios: random actions through ground contact, and joints
pushed past their limits), a field it calls inert must leave them bit-identical, and an adapter may
instead refuse the perturbed spec with a :class:`BackendError` that names the field.
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

import backends
from backends import BackendError
from backends.contract import INERT
from simcore import PhysicsSpec
from tasks import make_task

CASES = [(name, task) for name in backends.available() for task in backends.get(name).contract_tasks]
FIELDS = [f.name for f in dataclasses.fields(PhysicsSpec)]


def _perturbed(phys: PhysicsSpec, name: str) -> PhysicsSpec:
    """``phys`` with field ``name`` changed by enough to show in a short rollout."""
    value = getattr(phys, name)
    changes = {
        "frame_dt": lambda: value * 1.5,
        "substeps": lambda: value * 2,
        "gravity": lambda: value * 0.5 - 1.0,
        "ground_plane": lambda: not value,
        "contact_mu": lambda: 0.05 if value > 0.05 else 0.5,
        "joint_damping": lambda: value * 2.0 + 0.5,
        "armature": lambda: (value or 0.05) * 3.0,
        "torque_limits": lambda: tuple(0.5 * limit for limit in value),
    }
    new = changes[name]() if name in changes else (1.0 if value == 0 else value * 3.0)
    return dataclasses.replace(phys, **{name: new})


def _rollouts(sim, task) -> list[torch.Tensor]:
    """The neutral states of two scenarios: through ground contact, and from joints past their limits,
    the first from ``sim`` as constructed (``cls(task, num_envs=1, seed=1, max_graph_steps=1)``, unstepped)."""
    gen = torch.Generator().manual_seed(3)
    actions = 0.8 * (2.0 * torch.rand(40, 1, task.action_dim, generator=gen) - 1.0)
    out = []
    with torch.no_grad():
        for a in actions:
            state = sim.step(a)
        out.append(torch.cat([v.flatten() for k, v in state.tensors().items() if k != "engine"]))
        if task.layout.num_dofs:
            sim.reset()
            q, qd = sim.state.joint_q.clone(), sim.state.joint_qd.clone()
            q[:, task.layout.nq - task.layout.num_dofs :] += 1.5
            sim.state = sim.state_from_generalized(q, qd)
            for a in actions[:3]:
                state = sim.step(a)
            out.append(torch.cat([v.flatten() for k, v in state.tensors().items() if k != "engine"]))
    return out


@pytest.mark.parametrize("backend, task_name", CASES, ids=[f"{b}-{t}" for b, t in CASES])
def test_every_physics_field_is_applied_or_refused(backend, task_name):
    cls = backends.get(backend)
    base_task = make_task(task_name)
    sim = cls(base_task, num_envs=1, seed=1, max_graph_steps=1)
    mapping = sim.physics_mapping()
    assert set(FIELDS) <= set(mapping), f"unmapped fields: {sorted(set(FIELDS) - set(mapping))}"
    reference = _rollouts(sim, base_task)
    for name in FIELDS:
        task = type(base_task)(_perturbed(base_task.physics, name))
        try:
            perturbed = cls(task, num_envs=1, seed=1, max_graph_steps=1)
        except BackendError as exc:
            assert name in str(exc), f"refusing a changed {name} must name it: {exc}"
            continue
        moved = [not torch.equal(a, b) for a, b in zip(reference, _rollouts(perturbed, task), strict=True)]
        if mapping[name].startswith(INERT):
            assert not any(moved), f"{backend}/{task_name}: {name} is declared inert but changed the simulation"
        else:
            assert any(moved), f"{backend}/{task_name}: {name} changed but the simulation did not ({mapping[name]})"


def test_an_adapter_that_does_not_map_its_physics_is_refused_in_one_line():
    base = backends.get("newton")

    class Unmapped(base):
        name = "newton"

        def physics_mapping(self):
            return {k: v for k, v in super().physics_mapping().items() if k != "contact_kf"}

    with pytest.raises(BackendError, match=r"PhysicsSpec\.contact_kf") as info:
        Unmapped(make_task("ant"), num_envs=1)
    assert "\n" not in str(info.value)


def test_newton_semi_implicit_refuses_an_armature_it_cannot_simulate():
    with pytest.raises(BackendError, match=r"PhysicsSpec\.armature"):
        backends.get("newton")(make_task("ant"), num_envs=1, solver="semi_implicit")
    sim = backends.get("newton")(make_task("ant", preset="bench_semi_implicit"), num_envs=1)
    assert sim.integrator == "newton SolverSemiImplicit"
