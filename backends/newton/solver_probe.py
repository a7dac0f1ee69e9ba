"""Evidence for the Newton solver and contact settings (run by ``python -m harness solver-probe``).

For each configuration: the Ant, ``num_envs`` envs, random joint torques, 32 control steps of
16 substeps recorded on one ``wp.Tape``, then the gradient of the summed final torso x-position
w.r.t. the joint forces of the first step. Reported: whether the forward pass stayed finite, the
torso height range, whether the gradient is finite, and its largest entry. A healthy
configuration has a finite forward pass and a finite gradient of moderate size; an exploding
adjoint shows up as a gradient many orders of magnitude larger than the one-step gradient.

The harness writes the list as JSON; docs/newton.md ("Solver probe") quotes it. This module is
engine code only: it imports neither the harness nor a task (the asset and physics come as arguments).
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import newton  # noqa: E402
import newton.examples  # noqa: E402  (asset lookup for the shipped nv_ant.xml)
import numpy as np
import warp as wp

import backends._warp  # noqa: E402,F401  (quiet Warp before newton starts it)
from simcore import PhysicsSpec


def probe(
    solver: str,
    asset: str,
    density: float | None,
    ke: float,
    kd: float,
    kf: float,
    phys: PhysicsSpec,
    num_envs: int = 64,
    warmup_frames: int = 60,
    frames: int = 32,
    seed: int = 0,
) -> dict:
    """One configuration; ``density`` rewrites every density attribute of the MJCF text."""
    cfg = newton.ModelBuilder.ShapeConfig(ke=ke, kd=kd, kf=kf, mu=phys.contact_mu, gap=0.05)
    xml = Path(asset).read_text()
    if density is not None:
        xml = re.sub(r'density="[^"]*"', f'density="{density}"', xml)
    template = newton.ModelBuilder(gravity=(0.0, 0.0, phys.gravity))
    template.default_shape_cfg = cfg
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # the shipped nv_ant.xml has a y-up floor plane; every run uses our own z-up ground instead
        template.add_mjcf(xml, enable_self_collisions=False, parse_visuals=False, ignore_names=("floor",))
    builder = newton.ModelBuilder(gravity=(0.0, 0.0, phys.gravity))
    builder.replicate(template, num_envs)
    builder.add_ground_plane(cfg=cfg)
    model = builder.finalize(requires_grad=True)
    if solver == "semi_implicit":
        sim_solver = newton.solvers.SolverSemiImplicit(model)
    else:
        sim_solver = newton.solvers.SolverFeatherstone(model)
    pipeline = newton.CollisionPipeline(model, requires_grad=True)
    subs = phys.substeps
    states = [model.state(requires_grad=True) for _ in range(frames * subs + 1)]
    controls = [model.control(requires_grad=True) for _ in range(frames)]
    contacts = [pipeline.contacts() for _ in range(frames)]
    rng = np.random.default_rng(seed)
    nv = model.joint_dof_count // num_envs
    for c in controls:
        f = np.zeros((num_envs, nv), dtype=np.float32)
        f[:, 6:] = 200.0 * rng.uniform(-1.0, 1.0, (num_envs, nv - 6))
        c.joint_f.assign(f.ravel())
    loss = wp.zeros(1, dtype=float, requires_grad=True)
    heights = []

    # untaped warm-up (ping-pong buffers) so the taped window starts in contact-rich, randomised states
    a, b = states[0], states[1]
    newton.eval_fk(model, model.joint_q, model.joint_qd, a)
    for t in range(warmup_frames):
        pipeline.collide(a, contacts[0])
        for _ in range(subs):
            a.clear_forces()
            sim_solver.step(a, b, controls[t % frames], contacts[0], phys.sim_dt)
            a, b = b, a
        heights.append(a.body_q.numpy().reshape(num_envs, -1, 7)[:, 0, 2])
    if a is not states[0]:
        for name in ("body_q", "body_qd", "joint_q", "joint_qd"):
            wp.copy(getattr(states[0], name), getattr(a, name))

    tape = wp.Tape()
    for t in range(frames):
        pipeline.collide(states[t * subs], contacts[t])
        with tape:
            for s in range(t * subs, (t + 1) * subs):
                states[s].clear_forces()
                sim_solver.step(states[s], states[s + 1], controls[t], contacts[t], phys.sim_dt)
        heights.append(states[(t + 1) * subs].body_q.numpy().reshape(num_envs, -1, 7)[:, 0, 2])
    with tape:
        wp.launch(_torso_x, dim=num_envs, inputs=[states[-1].body_q, model.body_count // num_envs], outputs=[loss])
    tape.backward(loss)
    grad = controls[0].joint_f.grad.numpy()
    heights = np.stack(heights)
    finite = np.isfinite(heights)
    return {
        "solver": solver,
        "asset": Path(asset).name,
        "density": density if density is not None else "as in the asset",
        "contact_ke_kd_kf": [ke, kd, kf],
        "warmup_frames": warmup_frames,
        "taped_frames": frames,
        "forward_finite": bool(finite.all()),
        "torso_height_min_max": [float(heights[finite].min()), float(heights[finite].max())] if finite.any() else None,
        "gradient_finite": bool(np.isfinite(grad).all()),
        "gradient_max_abs": float(np.abs(grad).max()) if np.isfinite(grad).all() else None,
    }


@wp.kernel
def _torso_x(body_q: wp.array[wp.transform], bodies_per_env: int, loss: wp.array[float]):
    env = wp.tid()
    wp.atomic_add(loss, 0, wp.transform_get_translation(body_q[env * bodies_per_env])[0])


def probe_all(ant_asset: str, phys: PhysicsSpec, num_envs: int = 64):
    """Every configuration of the table in docs/newton.md, one result dict at a time."""
    shipped = str(newton.examples.get_asset("nv_ant.xml"))
    runs = [
        ("semi_implicit", ant_asset, None, 4e4, 1e3, 3e2),  # the adapter's configuration (the task's PhysicsSpec)
        ("featherstone", ant_asset, None, 4e4, 1e3, 3e2),
        ("semi_implicit", ant_asset, None, 4e4, 1e4, 3e2),  # contact damping at the top of SHAC's range
        ("semi_implicit", ant_asset, None, 4e4, 1e3, 3e3),  # friction slope at the top of SHAC's range
        ("semi_implicit", shipped, None, 4e4, 1e3, 3e2),  # Newton's nv_ant.xml, density 5
        ("semi_implicit", shipped, 1000, 4e4, 1e3, 3e2),  # nv_ant.xml at density 1000
    ]
    for solver, asset, density, ke, kd, kf in runs:
        yield probe(solver, asset, density, ke, kd, kf, phys, num_envs=num_envs)
