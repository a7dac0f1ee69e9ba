"""Check an adapter's autograd gradients against central finite differences.

The loss is the task's own objective over a short rollout plus a stand-in for the critic's
terminal value, ``L = sum_envs (sum_t r_t + w . o_T)`` with a fixed random ``w``, so the check covers
exactly the paths SHAC differentiates: actions -> engine -> state -> observation -> reward and
-> last observation. Gradients are taken w.r.t. every action of every step and w.r.t. the initial generalized
state (root pose and velocity, joint positions and velocities).

Envs are independent, so one perturbation of coordinate ``i`` in *every* env at once gives the
finite difference of each env's own loss: the cost is two rollouts per coordinate of one env,
whatever the number of envs.

The error reported is, per env, ``||g_autograd - g_fd|| / ||g_fd||`` over all coordinates of a
kind (actions or initial state), maximised over envs. A vector norm rather than element-wise
ratios, because the simulation is float32: a coordinate whose true derivative is ~0 has a finite
difference of pure round-off, which an element-wise ratio turns into a meaningless huge error.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch

from backends.contract import BatchedSim
from tasks.rollout import rollout

# Why these numbers: the engines run in float32 (~7 significant digits). With losses of O(1-10)
# and steps of 1e-2 (actions, i.e. 2 N m of torque) and 1e-3 (state), round-off in a central
# difference is ~1e-6 * |L| / eps ~ 1e-4-1e-3 relative, truncation error is O(eps^2). A correct
# adapter lands well below 1e-2 on a contact-free segment; a wrong one (a missing chain-rule term,
# stale tape data) is off by O(1).
DEFAULT_TOLERANCE = 2e-2
ACTION_EPS = 1e-2
STATE_EPS = 1e-3


#: above this many coordinates of one kind (a soft body's ~1,000 particle coordinates, hundreds of
#: activations per step), central differences go along random directions instead of coordinates
MAX_COORDINATES = 128
DIRECTIONS = 16


@dataclass
class GradcheckResult:
    action_rel_error: float
    state_rel_error: float
    steps: int
    num_envs: int
    loss: float
    #: "coordinates" (every coordinate perturbed) or "directions" (DIRECTIONS random +-1 directions)
    action_mode: str = "coordinates"
    state_mode: str = "coordinates"

    @property
    def max_rel_error(self) -> float:
        return max(self.action_rel_error, self.state_rel_error)


def rollout_loss(
    sim: BatchedSim,
    q0: torch.Tensor,
    qd0: torch.Tensor,
    actions: torch.Tensor,
    particle_q0: torch.Tensor | None = None,
    particle_qd0: torch.Tensor | None = None,
    value_probe: torch.Tensor | None = None,
) -> torch.Tensor:
    """Per-env loss (N,): the task's rewards summed over actions (T, N, A) from the initial state
    (q0, qd0[, particle_q0, particle_qd0]), with the env's step semantics (:func:`tasks.rollout.rollout`),
    plus ``value_probe . o_T`` (a linear stand-in for SHAC's terminal value of the last observation)
    when ``value_probe`` (obs_dim,) is given."""
    state = sim.state_from_generalized(q0, qd0, particle_q0, particle_qd0)
    total, last_obs = rollout(sim, state, actions)
    if value_probe is None:
        return total
    return total + last_obs.double() @ value_probe.to(last_obs.device, torch.float64)


def _fd_per_env(fn, x: torch.Tensor, eps: float) -> torch.Tensor:
    """d(fn(x)[n]) / d(x[..., n, i]) by central differences; the env axis of ``x`` is dim -2.

    Each perturbation moves coordinate ``(..., i)`` of every env at once (envs are independent).
    """
    x = x.detach()
    grad = torch.zeros_like(x, dtype=torch.float64)
    lead_shape, width = x.shape[:-2], x.shape[-1]
    for lead in itertools.product(*(range(s) for s in lead_shape)):
        for i in range(width):
            where = (*lead, slice(None), i)
            plus, minus = x.clone(), x.clone()
            plus[where] += eps
            minus[where] -= eps
            with torch.no_grad():
                grad[where] = (fn(plus) - fn(minus)) / (2.0 * eps)
    return grad


def _fd_directional(fn, x: torch.Tensor, eps: float, directions: torch.Tensor) -> torch.Tensor:
    """(N, K) central differences of fn (per env) along ``directions`` (K, N, D) at ``x`` (N, D)."""
    x = x.detach()
    out = torch.zeros(x.shape[0], directions.shape[0], dtype=torch.float64)
    for k, d in enumerate(directions):
        with torch.no_grad():
            out[:, k] = ((fn(x + eps * d) - fn(x - eps * d)) / (2.0 * eps)).cpu()
    return out


def _rel_error(autograd: torch.Tensor, fd: torch.Tensor) -> float:
    """max over envs of ||a - f|| / ||f||; env axis at dim -2."""
    a = autograd.double().movedim(-2, 0).reshape(autograd.shape[-2], -1)
    f = fd.double().movedim(-2, 0).reshape(fd.shape[-2], -1)
    err = (a - f).norm(dim=1) / f.norm(dim=1).clamp_min(1e-12)
    return float(err.max())


def _check_kind(
    fn, x: torch.Tensor, grad: torch.Tensor, eps: float, gen: torch.Generator, max_coordinates: int = MAX_COORDINATES
) -> tuple[float, str]:
    """Relative error of ``grad`` (N, D) against central differences of ``fn`` at ``x`` (N, D):
    per coordinate up to MAX_COORDINATES, else along DIRECTIONS random +-1 directions (the same
    comparison of directional derivatives ``grad . d`` that a broken gradient fails just as surely)."""
    if x.shape[1] <= max_coordinates:
        return _rel_error(grad, _fd_per_env(fn, x, eps)), "coordinates"
    signs = torch.randint(0, 2, (DIRECTIONS, *x.shape), generator=gen).to(x) * 2.0 - 1.0
    fd = _fd_directional(fn, x, eps, signs)
    ad = torch.einsum("knd,nd->nk", signs.double(), grad.double()).cpu()
    return _rel_error(ad, fd), "directions"


def gradcheck(
    sim: BatchedSim,
    steps: int = 8,
    seed: int = 0,
    start_height: float | None = None,
    action_scale: float = 0.5,
    settle_steps: int = 0,
    value_probe: bool = True,
    max_coordinates: int = MAX_COORDINATES,
) -> GradcheckResult:
    """Compare autograd and central-difference gradients of the rollout loss.

    ``start_height`` lifts the body so the whole rollout is in the air: a smooth, contact-free
    segment where finite differences are trustworthy (a floating base's root to that height; a
    soft body's lowest particle). ``None`` keeps the task's own initial state (contact included).
    ``settle_steps`` > 0 first runs that many zero-action steps (no gradient) from the initial state
    and checks the segment that follows: a robot in stance, a soft body resting on the ground.
    ``value_probe=False`` drops the terminal-value stand-in (rewards only). Blocks wider than
    ``max_coordinates`` are checked along random directions (0: always).
    """
    gen = torch.Generator().manual_seed(seed)
    parts = [p.clone() for p in sim.task.sample_initial_state(sim.num_envs, gen)]
    if start_height is not None:
        if sim.layout.floating_base:
            parts[0][:, 2] = start_height
        if sim.layout.num_particles:
            z = parts[2][..., 2]
            parts[2][..., 2] = z + (start_height - z.amin(dim=1, keepdim=True))
    parts = [p.to(sim.device) for p in parts]
    if settle_steps:
        with torch.no_grad():
            state = sim.state_from_generalized(*parts)
            for _ in range(settle_steps):
                state = sim.advance(state, torch.zeros(sim.num_envs, sim.task.action_dim, device=sim.device))
        parts = [state.joint_q, state.joint_qd]
        if sim.layout.num_particles:
            parts += [state.particle_q, state.particle_qd]
        parts = [p.detach().clone() for p in parts]
    n, a_dim = sim.num_envs, sim.task.action_dim
    actions = action_scale * (2.0 * torch.rand(steps, n, a_dim, generator=gen) - 1.0)
    actions = actions.to(sim.device)

    # every initial-state part flattened into one (N, D) block, actions into (N, T * A)
    shapes = [p.shape for p in parts]
    state0 = torch.cat([p.reshape(n, -1) for p in parts], dim=1)
    flat_actions = actions.permute(1, 0, 2).reshape(n, -1)

    def unflatten_state(x: torch.Tensor) -> list[torch.Tensor]:
        chunks = torch.split(x, [int(torch.Size(shape[1:]).numel()) for shape in shapes], dim=1)
        return [c.reshape(shape) for c, shape in zip(chunks, shapes, strict=True)]

    def unflatten_actions(x: torch.Tensor) -> torch.Tensor:
        return x.reshape(n, steps, a_dim).permute(1, 0, 2)

    # SHAC's actor loss ends with the critic's value of the last observation, so the check covers the
    # observation path too: a fixed random linear function of o_T stands in for it (for a soft body in
    # the air it is the only part of the loss that sees the activations: they move no centre of mass)
    probe = torch.randn(sim.task.obs_dim, generator=gen, dtype=torch.float64) / sim.task.obs_dim**0.5
    probe = probe if value_probe else None

    def loss_of(state_flat: torch.Tensor, actions_flat: torch.Tensor) -> torch.Tensor:
        q, qd, *particles = unflatten_state(state_flat)
        return rollout_loss(sim, q, qd, unflatten_actions(actions_flat), *particles, value_probe=probe)

    s_var = state0.clone().requires_grad_(True)
    a_var = flat_actions.clone().requires_grad_(True)
    loss = loss_of(s_var, a_var)
    loss.sum().backward()
    # a missing gradient (no autograd path at all) counts as zero, i.e. 100% error
    g_state = s_var.grad if s_var.grad is not None else torch.zeros_like(s_var)
    g_actions = a_var.grad if a_var.grad is not None else torch.zeros_like(a_var)
    action_err, action_mode = _check_kind(
        lambda a: loss_of(state0, a), flat_actions, g_actions, ACTION_EPS, gen, max_coordinates
    )
    state_err, state_mode = _check_kind(
        lambda s: loss_of(s, flat_actions), state0, g_state, STATE_EPS, gen, max_coordinates
    )
    return GradcheckResult(
        action_rel_error=action_err,
        state_rel_error=state_err,
        steps=steps,
        num_envs=n,
        loss=float(loss.detach().sum()),
        action_mode=action_mode,
        state_mode=state_mode,
    )


# -- the verb and its line in the suite's checks table ---------------------------------------------


def verb(args) -> int:
    """``python -m harness gradcheck``: one segment's gradients against central differences, PASS/FAIL."""
    from harness.inputs import BadInput, make_verb_sim, preflight, sim_physics
    from harness.results import harness_command, write_check

    preflight(
        backends=args.backend, task=args.task, device=args.device, out=args.out, memory=(args.num_envs, args.steps)
    )
    sim = make_verb_sim(args, horizon=args.steps)
    tolerance = args.tolerance or DEFAULT_TOLERANCE
    start_height = None
    lifted = "root" if sim.layout.floating_base else "lowest particle" if sim.layout.num_particles else None
    if not args.with_contact and lifted:
        start_height = sim.task.airborne_height  # high enough that `steps` of free fall never reach the ground
    segment = "with contact" if start_height is None else f"contact-free ({lifted} lifted to {start_height} m)"
    if args.settle:
        if start_height is not None:
            raise BadInput("--settle needs --with-contact (settling in the air would only fall)")
        segment += f", after {args.settle} zero-action steps"
    print(f"gradcheck {args.backend}/{args.task}: {args.num_envs} envs, {args.steps} steps, {segment}", flush=True)
    result = gradcheck(sim, steps=args.steps, seed=args.seed, start_height=start_height, settle_steps=args.settle)
    for label, error, mode in (
        ("d loss / d actions:      ", result.action_rel_error, result.action_mode),
        ("d loss / d initial state:", result.state_rel_error, result.state_mode),
    ):
        print(f"  {label}  max relative error {error:.3e} (central differences per {mode[:-1]})")
    ok = result.max_rel_error <= tolerance
    print(f"max relative error {result.max_rel_error:.3e} (tolerance {tolerance:.1e}): {'PASS' if ok else 'FAIL'}")
    if args.out:
        summary = {
            "backend": args.backend,
            "task": args.task,
            "num_envs": args.num_envs,
            "steps": args.steps,
            "segment": segment,
            "action_rel_error": result.action_rel_error,
            "state_rel_error": result.state_rel_error,
            "max_rel_error": result.max_rel_error,
            "tolerance": tolerance,
            "passed": ok,
            **sim_physics(sim),
        }
        print(f"wrote {write_check(args.out, 'gradcheck', summary, harness_command())}")
    return 0 if ok else 1


_SUMMARY_FIELDS = (
    ("tolerance", "tolerance"),
    ("action_rel_error", "actions"),
    ("state_rel_error", "initial state"),
    ("steps", "steps"),
    ("segment", "segment"),
)


def summary(result: dict, kind: str) -> str:
    from harness.formatting import fmt

    parts = [f"max rel. error {fmt(result.get('max_rel_error'))}"]
    parts += [f"{label} {fmt(result[key])}" for key, label in _SUMMARY_FIELDS if result.get(key) is not None]
    return ", ".join(parts)
