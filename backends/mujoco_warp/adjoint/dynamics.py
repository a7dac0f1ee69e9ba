"""MuJoCo's smooth dynamics for a :class:`~backends.mujoco_warp.adjoint.tree.RigidTree`, in torch.

Spatial vectors are 6-vectors ``(angular, linear)`` in world coordinates about the world origin
(Featherstone's fixed-origin convention): a body's velocity ``V = (w, v_O)`` holds its angular
velocity and the velocity of the body-fixed point at the world origin, ``v_O = v_P + P x w`` for any
point ``P`` of the body. A dof's motion vector ``S`` is the velocity its unit rate gives its body:
a hinge with world axis ``a`` through ``p``: ``(a, p x a)``; a free joint's world translations
``(0, e_k)`` and body-frame rotations ``(R e_k, x x R e_k)`` about the body origin ``x`` (MuJoCo's
free-joint velocity convention). Then, with ``anc[b, j]`` = 1 where dof ``j`` moves body ``b``:

* ``V_b = sum_j anc[b, j] S_j qd_j``;
* the mass matrix ``M_jk = sum_b anc[b, j] anc[b, k] S_j . (I_b S_k) + armature_j delta_jk`` (CRBA
  written as a sum over bodies);
* the bias force ``c_j = S_j . sum_b anc[b, j] f_b`` with ``f_b = I_b A_b + V_b x* (I_b V_b)`` and
  ``A_b = (0, -g) + sum_j anc[b, j] (V_body(j) x S_j) qd_j`` (recursive Newton-Euler at zero joint
  acceleration, gravity as a base acceleration; a free translation's axis does not turn, so its term is
  zero), i.e. MuJoCo's ``qfrc_bias`` (Coriolis, centrifugal and gravity forces).

Everything is batched over worlds and differentiable; the only loop is over the tree's bodies.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from backends.mujoco_warp.adjoint.tree import RigidTree


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) in MuJoCo's w, x, y, z order, normalised first."""
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rows = (
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
    )
    return torch.stack([torch.stack(r, dim=-1) for r in rows], dim=-2)


def axis_angle_matrix(skew: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotations (N, k, 3, 3) by ``angle`` (N, k) about unit axes whose cross-product matrices are
    ``skew`` (k, 3, 3) (Rodrigues' formula)."""
    s, c = torch.sin(angle)[..., None, None], torch.cos(angle)[..., None, None]
    return torch.eye(3, dtype=skew.dtype) + s * skew + (1 - c) * (skew @ skew)


def _skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrices (..., 3, 3) of vectors (..., 3): ``_skew(a) @ b = a x b``."""
    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack((zero, -z, y, z, zero, -x, -y, x, zero), dim=-1).reshape(*v.shape, 3)


@dataclass
class Kinematics:
    """One configuration's kinematics (N worlds): body frames, spatial inertias, dof motion vectors."""

    rot: torch.Tensor  # (N, nbody, 3, 3) body frames
    origin: torch.Tensor  # (N, nbody, 3) body origins
    spatial_inertia: torch.Tensor  # (N, nbody, 6, 6) about the world origin (zero for the world body)
    motion: torch.Tensor  # (N, nv, 6) each dof's motion vector S (module docstring)


def _free_root(tree: RigidTree, qpos: torch.Tensor, b: int):
    """A free root's frame, origin and its 6 dofs' motion vectors (N, 6, 6)."""
    n, qa = qpos.shape[0], tree.qposadr[b]
    x, r = qpos[:, qa : qa + 3], quat_to_matrix(qpos[:, qa + 3 : qa + 7])
    translations = torch.cat((qpos.new_zeros(3, 3), torch.eye(3, dtype=qpos.dtype)), dim=1).expand(n, 3, 6)
    axes = r.transpose(1, 2)  # rows: the body's axes in world coordinates
    rotations = torch.cat((axes, torch.linalg.cross(x[:, None].expand(n, 3, 3), axes, dim=-1)), dim=-1)
    return r, x, torch.cat((translations, rotations), dim=1)


def kinematics(tree: RigidTree, qpos: torch.Tensor) -> Kinematics:
    """MuJoCo's forward kinematics (``mj_kinematics``, ``mj_comPos``) of ``qpos`` (N, nq), one depth
    level of the tree at a time (every body of a level has a hinge; a free joint is the root's)."""
    n, dtype = qpos.shape[0], qpos.dtype
    rot = {0: torch.eye(3, dtype=dtype).expand(n, 1, 3, 3)}  # per level: (N, k, 3, 3)
    origin = {0: qpos.new_zeros(n, 1, 3)}
    motion = []
    for depth, level in enumerate(tree.levels, start=1):
        parents = level["parent_slot"]
        if level["free"]:
            r, x, s = _free_root(tree, qpos, level["first"])
            rot[depth], origin[depth] = r[:, None], x[:, None]
            motion.append(s)
            continue
        r_parent, x_parent = rot[depth - 1][:, parents], origin[depth - 1][:, parents]
        r = r_parent @ level["body_rot"]
        x = x_parent + (r_parent @ level["body_pos"]).squeeze(-1)
        jnt_pos = level["jnt_pos"]
        anchor = x + (r @ jnt_pos).squeeze(-1)
        axis = (r @ level["jnt_axis"]).squeeze(-1)
        angle = qpos[:, level["qpos"]] - level["qpos0"]
        r = r @ axis_angle_matrix(level["skew"], angle)
        rot[depth], origin[depth] = r, anchor - (r @ jnt_pos).squeeze(-1)
        motion.append(torch.cat((axis, torch.linalg.cross(anchor, axis, dim=-1)), dim=-1))
    rot_t = torch.cat([rot[d] for d in range(len(tree.levels) + 1)], dim=1)[:, tree.level_order]
    origin_t = torch.cat([origin[d] for d in range(len(tree.levels) + 1)], dim=1)[:, tree.level_order]
    motion_t = torch.cat(motion, dim=1)[:, tree.dof_order]
    return Kinematics(rot_t, origin_t, _spatial_inertia(tree, rot_t, origin_t), motion_t)


def _spatial_inertia(tree: RigidTree, rot: torch.Tensor, origin: torch.Tensor) -> torch.Tensor:
    """Each body's 6 x 6 inertia about the world origin: ``[[I_c + m C C^T, m C], [m C^T, m 1]]``, ``C``
    the cross-product matrix of its centre of mass ``c`` (momentum ``(I_c w + c x p, p)``, ``p = m (v + w x c)``)."""
    com = origin + (rot @ tree.ipos[..., None]).squeeze(-1)
    principal = rot @ tree.irot
    inertia = principal @ (tree.inertia[..., None] * principal.transpose(-1, -2))
    mass = tree.mass[:, None, None]
    c = _skew(com)
    top = torch.cat((inertia + mass * (c @ c.transpose(-1, -2)), mass * c), dim=-1)
    bottom = torch.cat((mass * c.transpose(-1, -2), mass * torch.eye(3, dtype=rot.dtype).expand_as(c)), dim=-1)
    return torch.cat((top, bottom), dim=-2)


def cross_motion(v: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Spatial motion cross product ``v x s`` of (..., 6) vectors."""
    w, u = v[..., :3], v[..., 3:]
    a, b = s[..., :3], s[..., 3:]
    return torch.cat(
        (torch.linalg.cross(w, a, dim=-1), torch.linalg.cross(w, b, dim=-1) + torch.linalg.cross(u, a, dim=-1)), -1
    )


def cross_force(v: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
    """Spatial force cross product ``v x* f`` of (..., 6) vectors."""
    w, u = v[..., :3], v[..., 3:]
    n, g = f[..., :3], f[..., 3:]
    return torch.cat(
        (torch.linalg.cross(w, n, dim=-1) + torch.linalg.cross(u, g, dim=-1), torch.linalg.cross(w, g, dim=-1)), -1
    )


def body_velocities(tree: RigidTree, kin: Kinematics, qvel: torch.Tensor) -> torch.Tensor:
    """(N, nbody, 6) spatial velocities of every body."""
    return torch.einsum("bj,njk->nbk", tree.ancestor, kin.motion * qvel[..., None])


def mass_matrix(tree: RigidTree, kin: Kinematics) -> torch.Tensor:
    """(N, nv, nv) joint-space inertia, armature included (MuJoCo's ``qM``, dense), by composite
    inertias: ``M_jk = S_j . I^C_body(k) S_k`` where dof ``j`` moves ``body(k)`` (CRBA)."""
    composite = torch.einsum("bd,ndxy->nbxy", tree.subtree, kin.spatial_inertia)
    force = (composite[:, tree.dof_body] @ kin.motion[..., None]).squeeze(-1)  # (N, nv, 6)
    upper = kin.motion @ force.transpose(1, 2)  # [j, k] = S_j . I^C_body(k) S_k
    moves = tree.dof_moves  # (nv, nv) dof j moves body(k)
    return torch.where(moves, upper, torch.where(moves.T, upper.transpose(1, 2), 0.0)) + torch.diag(tree.armature)


def bias_force(tree: RigidTree, kin: Kinematics, qvel: torch.Tensor) -> torch.Tensor:
    """(N, nv) MuJoCo's ``qfrc_bias``: Coriolis, centrifugal and gravity forces (module docstring)."""
    velocity = body_velocities(tree, kin, qvel)  # (N, nbody, 6)
    turning = cross_motion(velocity[:, tree.dof_body], kin.motion) * (qvel * tree.moving_axis)[..., None]
    base = torch.cat((qvel.new_zeros(3), -tree.gravity))
    accel = base + torch.einsum("bj,njk->nbk", tree.ancestor, turning)
    inertia = kin.spatial_inertia
    momentum = (inertia @ velocity[..., None]).squeeze(-1)
    force = (inertia @ accel[..., None]).squeeze(-1) + cross_force(velocity, momentum)
    per_dof = torch.einsum("bj,nbk->njk", tree.ancestor, force)
    return (kin.motion * per_dof).sum(-1)
