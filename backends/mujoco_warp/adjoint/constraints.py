"""MuJoCo's soft constraints for the adjoint's models, in torch: rows, forces and the solver's Hessian.

Rows (MuJoCo-Warp 4.0's ``constraint.py``, for the class :mod:`.tree` admits):

* a hinge limit: ``pos = min(q - low, high - q)``, active where ``pos < 0``, ``J = +-e_dof`` (+ at the
  lower limit), a quadratic row when ``jar = J a - aref < 0``, else satisfied;
* a contact with the z-up plane at each candidate point MuJoCo's collision makes (a sphere's centre, a
  capsule's end centres, a box's corners, a cylinder's rim points): ``dist = z_point - r``, active
  where ``dist < 0``, at the midpoint ``p = c - (r + dist / 2) n``; condim 3 gives a normal row
  and two tangent rows, each the contact frame's axis times the robot body's point Jacobian at ``p``
  (the plane is MuJoCo's geom1, its body the world). The tangent axes are any orthonormal pair: with one
  friction coefficient for both (the models here) every quantity below is invariant to their rotation.

Reference accelerations from the direct-form ``solref = (s0, s1)`` and a constant impedance ``d``:
``aref = (s0 pos + s1 vel) / d`` on normal and limit rows, ``s1 vel / d`` on tangent rows; ``D = 1 / R``,
``R = (1 - d) / d * invweight`` (``body_invweight0`` of the robot body for a contact,
``dof_invweight0`` for a limit), tangent rows ``D_t = D_n impratio``.

The Newton solver's cost in each contact's elliptic cone (``solver.py``): ``mu = friction / sqrt(impratio)``,
``N = mu jar_n``, ``u = friction jar_t``, ``T = |u|``: satisfied (no force) where ``N >= mu T``, quadratic
on all three rows where ``mu N + T <= 0``, else the cone zone with cost ``Dm (N - mu T)^2 / 2``,
``Dm = D_n / (mu^2 (1 + mu^2))``. :func:`forces` gives ``f = -d cost / d jar`` with each contact's zone
frozen, :func:`hessian_blocks` the cost's Hessian in ``jar`` (what MuJoCo's Newton solver factors).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from backends.mujoco_warp.adjoint.dynamics import Kinematics
from backends.mujoco_warp.adjoint.tree import RigidTree

SATISFIED, QUADRATIC, CONE = 0, 1, 2  # a row group's zone at the solution


@dataclass
class Rows:
    """The constraints of N worlds: every hinge limit, and the contacts gathered per world (C the most any
    world has); inactive rows are masked by a zero ``D``."""

    limit_jac: torch.Tensor  # (N, L, nv)
    limit_aref: torch.Tensor  # (N, L)
    limit_d: torch.Tensor  # (N, L) D, zero where inactive
    contact_jac: torch.Tensor  # (N, C, k, nv), k = 3 (normal, two tangents) or 1
    contact_aref: torch.Tensor  # (N, C, k)
    contact_d: torch.Tensor  # (N, C, k) D per row, zero where inactive
    mu: torch.Tensor  # (N, C) the cone's mu = friction / sqrt(impratio)
    friction: torch.Tensor  # (N, C)


def _contact_points(tree: RigidTree, kin: Kinematics) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Every candidate contact point in the world: the geoms' fixed points
    (:func:`~backends.mujoco_warp.adjoint.tree._candidates`), then four per cylinder
    (:func:`_cylinder_points`): points (N, C, 3), radii (C,), geom index into ``tree.geoms`` (C,)."""
    g = tree.geoms
    geom = g["candidate_geom"]
    points = (kin.frame[:, g["candidate_body"]] @ g["candidate_point"][..., None]).squeeze(-1)  # (N, C, 3)
    radii = g["candidate_radius"]
    if len(g["cylinder_geom"]):
        rims = _cylinder_points(tree, kin)
        points = torch.cat((points, rims), dim=1)
        radii = torch.cat((radii, radii.new_zeros(rims.shape[1])))
        geom = torch.cat((geom, g["cylinder_geom"].repeat_interleave(4)))
    return points, radii, geom


def _cylinder_points(tree: RigidTree, kin: Kinematics) -> torch.Tensor:
    """(N, 4 Y, 3) MuJoCo-Warp's four plane-cylinder points per cylinder (``plane_cylinder``): with the
    axis ``a`` turned towards the plane (``n . a <= 0``, a frozen choice), ``v`` the rim's radius vector
    nearest the plane (``a (n . a) - n`` scaled to the radius; world x times the radius when the
    cylinder stands upright, another frozen choice), ``A = h a``: ``c + v + A``, ``c + v - A``, and
    ``c + A - v / 2 +- w`` with ``w`` along ``v x A`` of length ``r sqrt(3) / 2``. Each is a contact
    where its height is below zero (radius 0)."""
    g = tree.geoms
    geom = g["cylinder_geom"]
    rot = kin.rot[:, g["body"][geom]] @ g["rot"][geom]  # (N, Y, 3, 3) cylinder frames
    centre = kin.origin[:, g["body"][geom]] + (kin.rot[:, g["body"][geom]] @ g["pos"][geom][..., None]).squeeze(-1)
    radius, half = g["cylinder_size"][:, 0, None], g["cylinder_size"][:, 1, None]
    axis = rot[..., 2]
    normal = torch.tensor([0.0, 0.0, 1.0], dtype=axis.dtype)
    axis = axis * torch.where(axis[..., 2:] > 0, -1.0, 1.0).detach()
    toward = axis * axis[..., 2:] - normal
    length_sq = (toward * toward).sum(-1, keepdim=True)
    upright = (length_sq < 1e-12).detach()
    rim = torch.where(
        upright,
        torch.tensor([1.0, 0.0, 0.0], dtype=axis.dtype) * radius,
        toward * radius / torch.sqrt(length_sq.clamp_min(1e-12)),
    )
    cap = axis * half
    side = torch.linalg.cross(rim, cap, dim=-1)
    side = side / side.norm(dim=-1, keepdim=True) * (radius * 3.0**0.5 / 2.0)
    near = centre + cap - 0.5 * rim
    points = torch.stack((centre + rim + cap, centre + rim - cap, near + side, near - side), dim=2)
    return points.flatten(1, 2)


def _point_jacobian(tree: RigidTree, kin: Kinematics, body: torch.Tensor, point: torch.Tensor) -> torch.Tensor:
    """(N, C, 3, nv) Jacobians of the velocities of body-fixed points ``point`` (N, C, 3) of bodies ``body`` (N, C)."""
    s = kin.motion  # (N, nv, 6)
    lin = s[:, None, :, 3:] + torch.linalg.cross(s[:, None, :, :3], point[:, :, None, :], dim=-1)  # (N, C, nv, 3)
    return (lin * tree.ancestor[body][..., None]).transpose(-1, -2)


def _touching(dist: torch.Tensor) -> torch.Tensor:
    """(N, K) indices of each world's candidates with ``dist < 0`` first, K the most any world has (at
    least 1): the contacts are gathered before their Jacobians are built, so a world's cost is that of
    the contacts the batch has, not of every candidate. Decided without gradient (a frozen choice)."""
    touching = (dist < 0).detach()
    count = max(int(touching.sum(1).max()), 1)
    return torch.argsort((~touching).to(torch.int8), dim=1, stable=True)[:, :count]


def constraint_rows(tree: RigidTree, kin: Kinematics, qpos: torch.Tensor, qvel: torch.Tensor) -> Rows:
    """Every limit and contact row of ``qpos``/``qvel`` (module docstring); which are active is decided
    without gradient, the discrete choice frozen."""
    lim = tree.limits
    q = qpos[:, lim["qpos"]]
    lower, upper = q - lim["low"], lim["high"] - q
    at_lower = (lower < upper).detach()
    pos = torch.where(at_lower, lower, upper)
    sign = torch.where(at_lower, 1.0, -1.0).to(qpos.dtype)
    limit_jac = sign[..., None] * lim["selector"]  # (N, L, nv): +-1 at each limit's dof
    vel = sign * qvel[:, lim["dof"]]
    imp = lim["imp"]
    limit_aref = (lim["solref"][:, 0] * pos + lim["solref"][:, 1] * vel) / imp
    limit_d = (pos < 0).detach().to(qpos.dtype) * lim["d"]

    centre, radius, geom = _contact_points(tree, kin)
    pick = _touching(centre[..., 2] - radius)  # (N, K)
    geom = geom[pick]
    centre = torch.gather(centre, 1, pick[..., None].expand(-1, -1, 3))
    g = tree.geoms
    dist = centre[..., 2] - radius[pick]
    point = torch.cat((centre[..., :2], (0.5 * dist)[..., None]), dim=-1)  # c - (r + dist / 2) n
    jac = _point_jacobian(tree, kin, g["body"][geom], point)  # (N, K, 3, nv), world axes x, y, z
    axes = [2, 1, 0] if tree.condim == 3 else [2]
    contact_jac = jac[:, :, axes]
    if tree.condim == 3:  # frame rows: n = z, t1 = y, t2 = -x
        contact_jac = contact_jac * torch.tensor([1.0, 1.0, -1.0], dtype=qpos.dtype)[:, None]
    velocity = (contact_jac @ qvel[:, None, :, None]).squeeze(-1)  # (N, K, k)
    solref, imp = g["solref"][geom], g["imp"][geom]  # (N, K, 2), (N, K)
    aref = solref[..., 1:] * velocity / imp[..., None]
    aref = torch.cat((aref[..., :1] + (solref[..., 0] * dist / imp)[..., None], aref[..., 1:]), dim=-1)
    d_normal = g["d"][geom]
    scale = torch.tensor([1.0] + [tree.impratio] * (len(axes) - 1), dtype=qpos.dtype)
    contact_d = (dist < 0).detach().to(qpos.dtype)[..., None] * d_normal[..., None] * scale
    friction = g["mu"][geom]
    return Rows(limit_jac, limit_aref, limit_d, contact_jac, aref, contact_d, friction / tree.impratio**0.5, friction)


def _cone(rows: Rows, jar: torch.Tensor):
    """Per contact (N, C): N, u (N, C, 2), T, r = N - mu T and the zone of ``jar`` (N, C, 3)."""
    mu, fr = rows.mu, rows.friction
    normal = mu * jar[..., 0]
    u = fr[..., None] * jar[..., 1:]
    t = u.norm(dim=-1).clamp_min(1e-15)
    top = (normal >= mu * t) | (rows.contact_d[..., 0] == 0)
    bottom = mu * normal + t <= 0
    zone = torch.where(top, SATISFIED, torch.where(bottom, QUADRATIC, CONE))
    return normal, u, t, normal - mu * t, zone


def _limit_jar(rows: Rows, qacc: torch.Tensor) -> torch.Tensor:
    """``J a - aref`` of every limit row (N, L)."""
    return (rows.limit_jac @ qacc[..., None]).squeeze(-1) - rows.limit_aref


def _contact_jar(rows: Rows, qacc: torch.Tensor) -> torch.Tensor:
    """``J a - aref`` of every contact row (N, C, k)."""
    return (rows.contact_jac @ qacc[:, None, :, None]).squeeze(-1) - rows.contact_aref


def zones_and_hessian_blocks(rows: Rows, qacc: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """At the solver's acceleration ``qacc`` (N, nv): each limit's (N, L) and contact's (N, C) zone, and
    each contact's cost Hessian in ``jar`` (N, C, k, k), zero where satisfied (what MuJoCo's Newton
    solver factors). Without gradient: the zones are frozen, the Hessian held constant (step.py)."""
    limit_jar = _limit_jar(rows, qacc)
    limit_zone = torch.where((limit_jar < 0) & (rows.limit_d > 0), QUADRATIC, SATISFIED)
    jar = _contact_jar(rows, qacc)
    if rows.contact_jac.shape[2] == 1:
        zone = torch.where((jar[..., 0] < 0) & (rows.contact_d[..., 0] > 0), QUADRATIC, SATISFIED)
        return limit_zone, zone, torch.diag_embed(rows.contact_d) * (zone == QUADRATIC)[..., None, None]
    normal, u, t, _, zone = _cone(rows, jar)
    return limit_zone, zone, _cone_hessian(rows, normal, u, t, zone)


def forces(rows: Rows, qacc: torch.Tensor, limit_zone: torch.Tensor, contact_zone: torch.Tensor):
    """Row forces ``f = -d cost / d jar`` at ``qacc`` with the zones frozen: limits (N, L), contacts (N, C, k)."""
    limit_jar = _limit_jar(rows, qacc)
    limit_f = -(limit_zone == QUADRATIC).to(qacc.dtype) * rows.limit_d * limit_jar
    jar = _contact_jar(rows, qacc)
    quadratic = -rows.contact_d * jar * (contact_zone == QUADRATIC)[..., None]
    if jar.shape[-1] == 1:
        return limit_f, quadratic
    mu, fr = rows.mu, rows.friction
    _, u, t, r, _ = _cone(rows, jar)
    dm = rows.contact_d[..., 0] / (mu**2 * (1 + mu**2))
    scale = dm * mu * r
    cone = torch.cat(((-scale)[..., None], (scale / t)[..., None] * u * fr[..., None]), dim=-1)
    return limit_f, quadratic + cone * (contact_zone == CONE)[..., None]


def _cone_hessian(rows: Rows, normal: torch.Tensor, u: torch.Tensor, t: torch.Tensor, zone: torch.Tensor):
    """(N, C, 3, 3) each condim-3 contact's cost Hessian in ``jar`` given its cone terms (:func:`_cone`)."""
    mu = rows.mu
    blocks = torch.diag_embed(rows.contact_d) * (zone == QUADRATIC)[..., None, None]
    dm = rows.contact_d[..., 0] / (mu**2 * (1 + mu**2))
    direction = u / t[..., None]
    ratio = (mu * normal / t)[..., None, None]
    side = -mu[..., None] * direction  # (N, C, 2)
    corner = ratio * direction[..., :, None] * direction[..., None, :] + (mu[..., None, None] ** 2 - ratio) * torch.eye(
        2, dtype=u.dtype
    )
    top = torch.cat((torch.ones_like(side[..., :1]), side), dim=-1)  # (N, C, 3)
    hu = torch.cat((top[..., None, :], torch.cat((side[..., :, None], corner), dim=-1)), dim=-2)
    p = torch.stack((rows.mu, rows.friction, rows.friction), dim=-1)  # jar -> (N, u)
    cone = dm[..., None, None] * p[..., :, None] * hu * p[..., None, :]
    return blocks + cone * (zone == CONE)[..., None, None]
