"""What the adjoint reads from a compiled MuJoCo model, and what it refuses.

The adjoint (:mod:`backends.mujoco_warp.adjoint`) recomputes one MuJoCo step in torch for a narrow,
named class of models: a kinematic tree of bodies with one joint each (a free root, hinges below),
the Euler integrator, soft contacts of spheres, capsules, boxes and cylinders with a ground plane in an elliptic cone
(condim 1 or 3), hinge limits, constant impedance, no margin or gap. :func:`rigid_tree` reads that
model into torch tensors and refuses, in one line naming the first thing it does not cover, every
model outside the class, so a gradient is never silently missing a term.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np
import torch

from backends.contract import BackendError

#: geom types whose contact with the plane the adjoint differentiates (mujoco.mjtGeom values)
CONTACT_GEOMS = {
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_BOX): "box",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
}


@dataclass
class RigidTree:
    """A compiled model's arrays the adjoint uses, float64 torch tensors (shapes in comments)."""

    nq: int
    nv: int
    nbody: int  # bodies including the world (index 0)
    parent: list[int]  # (nbody,) parent body of each body
    mass: torch.Tensor  # (nbody,)
    local_inertia: torch.Tensor  # (nbody, 3, 4) rotational inertia about the centre of mass, the centre; body frame
    mass_block: torch.Tensor  # (nbody, 6, 6) the mass on the lower-right diagonal of each spatial inertia
    joint_type: list[int]  # (nbody,) -1 for none (the world), else mjtJoint
    qposadr: list[int]
    dofadr: list[int]
    ancestor: torch.Tensor  # (nbody, nv) 1 where dof j moves body b
    subtree: torch.Tensor  # (nbody, nbody) 1 where body d is body b or below it
    dof_moves: torch.Tensor  # (nv, nv) bool, dof j moves the body of dof k
    levels: list[dict]  # per depth 1, 2, ...: bodies, parent_slot (into the level above), qpos, free
    level_order: torch.Tensor  # (nbody,) each body's place in [world] + levels, concatenated
    dof_order: torch.Tensor  # (nv,) each dof's place in the levels' dofs, concatenated
    dof_body: torch.Tensor  # (nv,) long, the body each dof belongs to
    velocity_map: torch.Tensor  # (nv, nq) 1 from each hinge or free translation dof to its qpos (quaternions: 0)
    moving_axis: torch.Tensor  # (nv,) 1 where the dof's motion axis turns with the body (not a free translation)
    armature: torch.Tensor  # (nv,)
    damping: torch.Tensor  # (nv,)
    damped: bool  # any dof damped: else the step skips the damping terms and the integrator's implicit solve
    gravity: torch.Tensor  # (3,)
    timestep: float
    limits: (
        dict  # hinge limits: dof (L,) long, qpos index (L,), low (L,), high (L,), solref (L, 2), imp, invweight (L,)
    )
    geoms: dict  # robot geoms that touch the plane: body, kind, pos (G, 3), rot (G, 3, 3), radius, half_length, ...
    impratio: float
    condim: int


def _as(x, dtype=torch.float64) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x), dtype=dtype)


def _refuse(what: str) -> BackendError:
    return BackendError(f"gradients=adjoint does not cover {what}; use the finite-difference gradients")


def _check_options(m: mujoco.MjModel) -> None:
    """The model-wide settings outside the adjoint's class (module docstring)."""
    if m.opt.integrator != mujoco.mjtIntegrator.mjINT_EULER:
        raise _refuse(f"integrator {mujoco.mjtIntegrator(m.opt.integrator).name} (only Euler)")
    if m.opt.cone != mujoco.mjtCone.mjCONE_ELLIPTIC:
        raise _refuse("a pyramidal friction cone (only elliptic)")
    if m.opt.disableflags or m.opt.enableflags:
        raise _refuse(f"disable/enable flags {m.opt.disableflags}/{m.opt.enableflags} (only MuJoCo's defaults)")
    if m.opt.noslip_iterations:
        raise _refuse("the noslip solver")
    for name, count in (("tendons", m.ntendon), ("equality constraints", m.neq), ("flexes", m.nflex)):
        if count:
            raise _refuse(f"{count} {name}")
    if np.any(m.body_gravcomp):
        raise _refuse("gravity compensation")
    if np.any(m.dof_frictionloss) or np.any(m.jnt_stiffness):
        raise _refuse("joint friction loss or stiffness")
    if np.any(m.jnt_margin) or np.any(m.geom_margin) or np.any(m.geom_gap):
        raise _refuse("a non-zero contact or limit margin or gap")
    if m.nu:
        raise _refuse(f"{m.nu} actuators (torques enter as qfrc_applied)")


def _joints(m: mujoco.MjModel) -> tuple[list[int], list[int], list[int]]:
    """Per body: its joint's type, qpos and dof address (-1 for the world). One joint per body, a free
    joint only on a child of the world, hinges elsewhere."""
    joint_type, qposadr, dofadr = [-1] * m.nbody, [-1] * m.nbody, [-1] * m.nbody
    counts = np.bincount(m.jnt_bodyid, minlength=m.nbody)
    for b in range(1, m.nbody):
        if counts[b] != 1:
            raise _refuse(f"body {b} with {counts[b]} joints (one per body)")
    for j in range(m.njnt):
        b, kind = int(m.jnt_bodyid[j]), int(m.jnt_type[j])
        if kind == mujoco.mjtJoint.mjJNT_FREE:
            if m.body_parentid[b] != 0 or np.any(m.jnt_pos[j]):
                raise _refuse("a free joint below the root or off its body's origin")
        elif kind != mujoco.mjtJoint.mjJNT_HINGE:
            raise _refuse(f"joint type {mujoco.mjtJoint(kind).name} (free root and hinges only)")
        joint_type[b], qposadr[b], dofadr[b] = kind, int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
    return joint_type, qposadr, dofadr


def _mat(quats: np.ndarray) -> np.ndarray:
    out = np.zeros((len(quats), 9))
    for i, q in enumerate(quats):
        mujoco.mju_quat2Mat(out[i], np.asarray(q, dtype=np.float64))
    return out.reshape(-1, 3, 3)


def _limits(m: mujoco.MjModel) -> dict:
    rows = [j for j in range(m.njnt) if m.jnt_limited[j] and m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE]
    for j in rows:
        if m.jnt_solimp[j][0] != m.jnt_solimp[j][1] or m.jnt_solref[j][0] >= 0:
            raise _refuse(f"joint {j}'s limit: only direct-form solref with a constant impedance")
    dofs = [int(m.jnt_dofadr[j]) for j in rows]
    selector = torch.zeros(len(dofs), m.nv, dtype=torch.float64)
    selector[torch.arange(len(dofs)), dofs] = 1.0
    out = {
        "dof": torch.tensor(dofs, dtype=torch.long),
        "selector": selector,  # (L, nv) one at each limit's dof
        "qpos": torch.tensor([int(m.jnt_qposadr[j]) for j in rows], dtype=torch.long),
        "low": _as([m.jnt_range[j][0] for j in rows]),
        "high": _as([m.jnt_range[j][1] for j in rows]),
        "solref": _as([m.jnt_solref[j] for j in rows]).reshape(-1, 2),
        "imp": _as([m.jnt_solimp[j][0] for j in rows]),
        "invweight": _as([m.dof_invweight0[d] for d in dofs]),
    }
    out["d"] = out["imp"] / ((1 - out["imp"]) * out["invweight"])  # D = 1 / R of an active limit
    return out


def _contact_geoms(m: mujoco.MjModel) -> dict:
    """The robot geoms that can touch the plane (the only collisions the models here allow)."""
    plane = [g for g in range(m.ngeom) if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE]
    if len(plane) != 1 or m.geom_bodyid[plane[0]] != 0:
        raise _refuse(f"{len(plane)} ground planes (one, on the world body)")
    ground = plane[0]
    touching = []
    for g in range(m.ngeom):
        if g == ground:
            continue
        if (m.geom_contype[g] & m.geom_conaffinity[ground]) or (m.geom_conaffinity[g] & m.geom_contype[ground]):
            touching.append(g)
        for h in range(m.ngeom):  # robot-robot pairs would collide outside the adjoint's geometry
            if h != ground and h != g and (m.geom_contype[g] & m.geom_conaffinity[h]):
                raise _refuse("collisions between robot geoms")
    for g in touching:
        if int(m.geom_type[g]) not in CONTACT_GEOMS:
            raise _refuse(f"contacts of a {mujoco.mjtGeom(int(m.geom_type[g])).name} geom with the plane")
        if m.geom_priority[g] <= m.geom_priority[ground] or m.geom_solimp[g][0] != m.geom_solimp[g][1]:
            raise _refuse("contact parameters other than the robot geom's own with a constant impedance")
        if m.geom_solref[g][0] >= 0:
            raise _refuse("contacts with a standard-form solref (only the direct form)")
    condims = {int(m.geom_condim[g]) for g in touching}
    if not condims <= {1, 3} or len(condims) > 1:
        raise _refuse(f"contact dimensions {sorted(condims)} (one of 1 or 3 for every geom)")
    ground_rot = _mat([m.geom_quat[ground]])[0]
    if not np.allclose(ground_rot, np.eye(3)) or np.any(m.geom_pos[ground]):
        raise _refuse("a ground plane other than z-up through the origin")
    if m.geom_solref[ground][0] < 0 or m.geom_solref[ground][1] < 0:
        raise _refuse("a direct-form solref on the plane (MuJoCo would mix it with the robot geom's)")
    bodies = [int(m.geom_bodyid[g]) for g in touching]
    geom_of, offsets, radii = _candidates(m, touching)
    geom_pos = _as([m.geom_pos[g] for g in touching]).reshape(-1, 3)
    geom_rot = _as(_mat([m.geom_quat[g] for g in touching])).reshape(-1, 3, 3)
    in_body = geom_pos[geom_of] + (geom_rot[geom_of] @ _as(offsets).reshape(-1, 3, 1)).squeeze(-1)
    imp = _as([m.geom_solimp[g][0] for g in touching])
    invweight = _as([m.body_invweight0[b][0] for b in bodies])
    return {
        "index": torch.tensor(touching, dtype=torch.long),
        "body": torch.tensor(bodies, dtype=torch.long),
        "pos": geom_pos,
        "rot": geom_rot,
        "mu": _as([m.geom_friction[g][0] for g in touching]),  # the priority geom's (the robot's)
        "solref": _as([m.geom_solref[g] for g in touching]).reshape(-1, 2),
        "imp": imp,
        "invweight": invweight,
        "d": imp / ((1 - imp) * invweight),  # D = 1 / R of a contact's normal row
        "condim": condims.pop() if condims else 1,
        "candidate_geom": torch.tensor(geom_of, dtype=torch.long),  # (C,) into the lists above
        "candidate_radius": _as(radii),  # (C,) dist = height of the point above the plane - radius
        "candidate_body": torch.tensor([bodies[i] for i in geom_of], dtype=torch.long),  # (C,)
        # (C, 4) each point in its body's frame, and a 1: the body's frame [R | x] times it is the point in the world
        "candidate_point": torch.cat((in_body, torch.ones(len(geom_of), 1, dtype=torch.float64)), dim=1),
        # cylinders: their four points move over the rim with the configuration (constraints._cylinder_points)
        "cylinder_geom": torch.tensor([i for i, g in enumerate(touching) if _is_cylinder(m, g)], dtype=torch.long),
        "cylinder_size": _as([m.geom_size[g][:2] for g in touching if _is_cylinder(m, g)]).reshape(-1, 2),
    }


def _is_cylinder(m: mujoco.MjModel, g: int) -> bool:
    return int(m.geom_type[g]) == mujoco.mjtGeom.mjGEOM_CYLINDER


def _candidates(m: mujoco.MjModel, touching: list[int]) -> tuple[list[int], list, list[float]]:
    """Every point MuJoCo's plane collision can make a contact at that is fixed in a geom's frame, with
    a radius: a sphere's centre (radius r), a capsule's two end centres (``(0, 0, +-half length)``,
    radius r), a box's eight corners (radius 0); a cylinder's points follow its rim instead
    (``constraints._cylinder_points``). A contact exists where the point's height minus the radius is
    below zero, at the midpoint of the penetration."""
    geom_of, offsets, radii = [], [], []
    for i, g in enumerate(touching):
        kind, size = int(m.geom_type[g]), m.geom_size[g]
        if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            points, radius = [(0.0, 0.0, 0.0)], size[0]
        elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
            points, radius = [(0.0, 0.0, size[1]), (0.0, 0.0, -size[1])], size[0]
        elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
            continue  # not fixed points: constraints._cylinder_points
        else:  # box
            points = [(x * size[0], y * size[1], z * size[2]) for x in (1, -1) for y in (1, -1) for z in (1, -1)]
            radius = 0.0
        geom_of += [i] * len(points)
        offsets += points
        radii += [float(radius)] * len(points)
    return geom_of, offsets, radii


def rigid_tree(m: mujoco.MjModel) -> RigidTree:
    """The arrays of ``m`` the adjoint needs, or :class:`BackendError` naming what it does not cover."""
    _check_options(m)
    joint_type, qposadr, dofadr = _joints(m)
    parent = [int(p) for p in m.body_parentid]
    ancestor = torch.zeros(m.nbody, m.nv, dtype=torch.float64)
    for b in range(1, m.nbody):
        a = b
        while a:
            width = 6 if joint_type[a] == mujoco.mjtJoint.mjJNT_FREE else 1
            ancestor[b, dofadr[a] : dofadr[a] + width] = 1.0
            a = parent[a]
    dof_body = torch.tensor([int(m.dof_bodyid[d]) for d in range(m.nv)], dtype=torch.long)
    subtree = torch.zeros(m.nbody, m.nbody, dtype=torch.float64)
    for d in range(m.nbody):
        a = d
        while True:
            subtree[a, d] = 1.0
            if a == 0:
                break
            a = parent[a]
    levels, level_order, dof_order = _levels(parent, joint_type, qposadr, dofadr, m.nv)
    for level in levels:  # each level's constants, gathered once
        level["local"] = _hinge_local_frames(m, level["bodies"])
        level["qpos0"] = _as(m.qpos0)[level["qpos"]]
    moving = torch.ones(m.nv, dtype=torch.float64)
    for b in range(1, m.nbody):
        if joint_type[b] == mujoco.mjtJoint.mjJNT_FREE:
            moving[dofadr[b] : dofadr[b] + 3] = 0.0  # world-frame translations: their axes never turn
    geoms = _contact_geoms(m)
    velocity_map = torch.zeros(m.nv, m.nq, dtype=torch.float64)
    for b in range(1, m.nbody):
        width = 3 if joint_type[b] == mujoco.mjtJoint.mjJNT_FREE else 1
        for k in range(width):
            velocity_map[dofadr[b] + k, qposadr[b] + k] = 1.0
    return RigidTree(
        nq=m.nq,
        nv=m.nv,
        nbody=m.nbody,
        parent=parent,
        mass=_as(m.body_mass),
        local_inertia=_local_inertia(m),
        mass_block=torch.diag_embed(torch.cat((torch.zeros(m.nbody, 3), _as(m.body_mass)[:, None].expand(-1, 3)), 1)),
        joint_type=joint_type,
        qposadr=qposadr,
        dofadr=dofadr,
        ancestor=ancestor,
        subtree=subtree,
        dof_moves=ancestor[dof_body].T > 0,
        levels=levels,
        level_order=level_order,
        dof_order=dof_order,
        dof_body=dof_body,
        velocity_map=velocity_map,
        moving_axis=moving,
        armature=_as(m.dof_armature),
        damping=_as(m.dof_damping),
        damped=bool(np.any(m.dof_damping)),
        gravity=_as(m.opt.gravity),
        timestep=float(m.opt.timestep),
        limits=_limits(m),
        geoms=geoms,
        impratio=float(m.opt.impratio),
        condim=int(geoms["condim"]),
    )


def _local_inertia(m: mujoco.MjModel) -> torch.Tensor:
    """(nbody, 3, 4) each body's rotational inertia about its centre of mass, ``Q diag(I) Q^T`` with
    ``Q`` its principal frame, and beside it the centre of mass, both in the body's frame."""
    principal = _as(_mat(m.body_iquat))
    rotational = principal @ (_as(m.body_inertia)[..., None] * principal.transpose(-1, -2))
    return torch.cat((rotational, _as(m.body_ipos)[..., None]), dim=-1)


def _hinge_local_frames(m: mujoco.MjModel, bodies: torch.Tensor) -> torch.Tensor:
    """(k, 3, 4, 6) what a hinge level's kinematics multiply into the parent's frame ``[R | x]``, as three constant
    parts weighted by ``(1, sin t, 1 - cos t)`` of each hinge's angle ``t``. With the body's rest frame
    ``B``, offset ``b``, joint anchor ``p`` and unit axis with cross-product matrix ``K`` (all in the
    parent's frame but ``p`` and the axis, in the body's), the hinge turns the body by
    ``R = 1 + sin t K + (1 - cos t) K^2`` (Rodrigues) about ``p``, so in the parent's frame the body's
    rotation is ``B R``, its origin ``b + B (1 - R) p``, the anchor ``b + B p`` and the axis ``B a``: the
    six columns ``[B R | b + B (1 - R) p | b + B p | B a]``, each linear in ``(1, sin t, 1 - cos t)``,
    with a fourth row ``(0, 0, 0, 1, 1, 0)`` so that the parent's ``x`` moves the two points only."""
    index = bodies.numpy()
    rest = _as(_mat(m.body_quat))[bodies]
    offset = _as(m.body_pos)[bodies][..., None]
    anchor = _as(m.jnt_pos)[m.body_jntadr[index]][..., None]
    axis = _as(m.jnt_axis)[m.body_jntadr[index]]
    x, y, z = axis.unbind(-1)
    zero = torch.zeros_like(x)
    skew = torch.stack((zero, -z, y, z, zero, -x, -y, x, zero), dim=-1).reshape(-1, 3, 3)
    none = torch.zeros_like(offset)
    constant = torch.cat((rest, offset, offset + rest @ anchor, rest @ axis[..., None]), dim=-1)
    turning = [torch.cat((rest @ k, -(rest @ k @ anchor), none, none), dim=-1) for k in (skew, skew @ skew)]
    # a fourth row, so that the parent's frame [R | x] adds its origin x to the two points, not to directions
    points = torch.tensor([0.0, 0.0, 0.0, 1.0, 1.0, 0.0], dtype=torch.float64).expand(len(bodies), 1, 6)
    constant = torch.cat((constant, points), dim=1)
    turning = [torch.cat((t, torch.zeros_like(points)), dim=1) for t in turning]
    return torch.stack([constant, *turning], dim=1)


def _depth(parent: list[int], b: int) -> int:
    depth = 0
    while b:
        b, depth = parent[b], depth + 1
    return depth


def _levels(parent, joint_type, qposadr, dofadr, nv):
    """The tree by depth, for level-at-a-time kinematics: per level its bodies, each body's slot in the
    level above, its hinges' qpos addresses, and whether it is the free root; then each body's place
    in ``[world] + levels`` and each dof's place in the levels' dofs, both concatenated."""
    depth = {b: _depth(parent, b) for b in range(1, len(parent))}
    levels, slots, place, dof_place = [], {0: 0}, {0: 0}, []
    cursor, dof_cursor = 1, 0
    for d in range(1, max(depth.values(), default=0) + 1):
        bodies = [b for b in range(1, len(parent)) if depth[b] == d]
        free = any(joint_type[b] == mujoco.mjtJoint.mjJNT_FREE for b in bodies)
        if free and len(bodies) > 1:
            raise _refuse("a free joint beside other bodies at the root")
        for i, b in enumerate(bodies):
            slots[b], place[b] = i, cursor + i
            width = 6 if free else 1
            dof_place += [(dofadr[b] + k, dof_cursor + k) for k in range(width)]
            dof_cursor += width
        cursor += len(bodies)
        levels.append(
            {
                "bodies": torch.tensor(bodies, dtype=torch.long),
                "parent_slot": torch.tensor([slots[parent[b]] for b in bodies], dtype=torch.long),
                "qpos": torch.tensor([qposadr[b] for b in bodies], dtype=torch.long),
                "free": free,
                "first": bodies[0],  # the free root's body, as a plain int
            }
        )
    level_order = torch.tensor([place[b] for b in range(len(parent))], dtype=torch.long)
    dof_order = torch.zeros(nv, dtype=torch.long)
    for dof, at in dof_place:
        dof_order[dof] = at
    return levels, level_order, dof_order
