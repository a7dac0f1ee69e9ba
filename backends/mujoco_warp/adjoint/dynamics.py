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


def _quadratic_form() -> torch.Tensor:
    """(16, 9) ``W`` with ``R = (q q^T) W`` the rotation matrix of a unit quaternion ``q`` (w, x, y, z):
    every entry of ``R`` is a quadratic form in ``q`` (``1 - 2 (y^2 + z^2) = w^2 + x^2 - y^2 - z^2``)."""
    w = torch.zeros(4, 4, 3, 3, dtype=torch.float64)
    for i, signs in enumerate(((1, 1, -1, -1), (1, -1, 1, -1), (1, -1, -1, 1))):
        for a, sign in enumerate(signs):
            w[a, a, i, i] = sign
    # off the diagonal: (i, j, a, b, sign) for R_ij += 2 sign q_a q_b, split evenly over q_a q_b and q_b q_a
    for i, j, a, b, sign in (
        (0, 1, 1, 2, 1), (0, 1, 0, 3, -1), (0, 2, 1, 3, 1), (0, 2, 0, 2, 1),
        (1, 0, 1, 2, 1), (1, 0, 0, 3, 1), (1, 2, 2, 3, 1), (1, 2, 0, 1, -1),
        (2, 0, 1, 3, 1), (2, 0, 0, 2, -1), (2, 1, 2, 3, 1), (2, 1, 0, 1, 1),
    ):  # fmt: skip
        w[a, b, i, j] += sign
        w[b, a, i, j] += sign
    return w.reshape(16, 9)


_QUAT_FORM = _quadratic_form()


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) of quaternions (..., 4) in MuJoCo's w, x, y, z order, normalised first."""
    q = q / q.norm(dim=-1, keepdim=True)
    outer = (q[..., :, None] * q[..., None, :]).flatten(-2)
    return (outer @ _QUAT_FORM.to(q.dtype)).unflatten(-1, (3, 3))


def _spatial_map() -> torch.Tensor:
    """(21, 36) ``W`` with a body's 6 x 6 inertia about the world origin (:func:`_spatial_inertia`) equal
    to ``[I_c, m c c^T, m c] W`` (flattened) plus ``m`` on the lower-right diagonal: ``m C C^T = |c|^2 m 1
    - m c c^T`` and ``m C`` with ``C_ij = -eps_ijk c_k``, all linear in those 21 numbers."""
    w = torch.zeros(21, 6, 6, dtype=torch.float64)
    for i in range(3):
        for j in range(3):
            w[3 * i + j, i, j] += 1.0  # I_c
            w[9 + 3 * i + j, i, j] -= 1.0  # - m c c^T
            w[9 + 4 * j, i, i] += 1.0  # + m c_j^2 on the diagonal
            for k in range(3):
                w[18 + k, i, 3 + j] -= _levi_civita(i, j, k)  # m C
                w[18 + k, 3 + i, j] -= _levi_civita(j, i, k)  # m C^T
    return w.reshape(21, 36)


def _levi_civita(i: int, j: int, k: int) -> int:
    return (i - j) * (j - k) * (k - i) // 2


_SPATIAL_MAP = _spatial_map()


@dataclass
class Kinematics:
    """One configuration's kinematics (N worlds): body frames, spatial inertias, dof motion vectors."""

    frame: torch.Tensor  # (N, nbody, 3, 4) each body's rotation and origin, [R | x]
    spatial_inertia: torch.Tensor  # (N, nbody, 6, 6) about the world origin (zero for the world body)
    motion: torch.Tensor  # (N, nv, 6) each dof's motion vector S (module docstring)

    @property
    def rot(self) -> torch.Tensor:
        """(N, nbody, 3, 3) body rotations."""
        return self.frame[..., :3]

    @property
    def origin(self) -> torch.Tensor:
        """(N, nbody, 3) body origins."""
        return self.frame[..., 3]


def _free_root(tree: RigidTree, qpos: torch.Tensor, b: int):
    """A free root's frame ``[R | x]`` (N, 3, 4) and its 6 dofs' motion vectors (N, 6, 6)."""
    n, qa = qpos.shape[0], tree.qposadr[b]
    x, r = qpos[:, qa : qa + 3], quat_to_matrix(qpos[:, qa + 3 : qa + 7])
    translations = torch.cat((qpos.new_zeros(3, 3), torch.eye(3, dtype=qpos.dtype)), dim=1).expand(n, 3, 6)
    axes = r.transpose(1, 2)  # rows: the body's axes in world coordinates
    rotations = torch.cat((axes, torch.linalg.cross(x[:, None].expand(n, 3, 3), axes, dim=-1)), dim=-1)
    return torch.cat((r, x[..., None]), dim=-1), torch.cat((translations, rotations), dim=1)


def kinematics(tree: RigidTree, qpos: torch.Tensor) -> Kinematics:
    """MuJoCo's forward kinematics (``mj_kinematics``, ``mj_comPos``) of ``qpos`` (N, nq), one depth
    level of the tree at a time (every body of a level has a hinge; a free joint is the root's). A
    body's frame is ``[R | x]`` (3 x 4); a hinge level's frames, anchors and axes are its parents'
    frames times one matrix per body (:func:`~backends.mujoco_warp.adjoint.tree._hinge_local_frames`)."""
    n, dtype = qpos.shape[0], qpos.dtype
    frames = [torch.eye(3, 4, dtype=dtype).expand(n, 1, 3, 4)]  # per level: (N, k, 3, 4)
    motion = []
    for level in tree.levels:
        if level["free"]:
            frame, s = _free_root(tree, qpos, level["first"])
            frames.append(frame[:, None])
            motion.append(s)
            continue
        angle = qpos[:, level["qpos"]] - level["qpos0"]
        weights = torch.stack((torch.ones_like(angle), torch.sin(angle), 1 - torch.cos(angle)), dim=-1)
        local = torch.einsum("nkt,ktij->nkij", weights, level["local"])  # (N, k, 4, 6)
        world = frames[-1][:, level["parent_slot"]] @ local  # (N, k, 3, 6): [R | x | anchor | axis]
        anchor, axis = world[..., 4], world[..., 5]
        frames.append(world[..., :4])
        motion.append(torch.cat((axis, torch.linalg.cross(anchor, axis, dim=-1)), dim=-1))
    frame = torch.cat(frames, dim=1)[:, tree.level_order]
    return Kinematics(frame, _spatial_inertia(tree, frame), torch.cat(motion, dim=1)[:, tree.dof_order])


def _spatial_inertia(tree: RigidTree, frame: torch.Tensor) -> torch.Tensor:
    """Each body's 6 x 6 inertia about the world origin: ``[[I_c + m C C^T, m C], [m C^T, m 1]]``, ``C``
    the cross-product matrix of its centre of mass ``c`` (momentum ``(I_c w + c x p, p)``, ``p = m (v + w x c)``)."""
    rot = frame[..., :3]
    local = rot @ tree.local_inertia  # (N, nbody, 3, 4): R I_body and R ipos
    inertia = local[..., :3] @ rot.transpose(-1, -2)
    com = frame[..., 3] + local[..., 3]
    moment = tree.mass[:, None] * com
    features = torch.cat((inertia.flatten(-2), (moment[..., :, None] * com[..., None, :]).flatten(-2), moment), -1)
    return (features @ _SPATIAL_MAP.to(rot.dtype)).unflatten(-1, (6, 6)) + tree.mass_block


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
    momentum, inertial = (kin.spatial_inertia @ torch.stack((velocity, accel), dim=-1)).unbind(-1)
    force = inertial + cross_force(velocity, momentum)
    per_dof = torch.einsum("bj,nbk->njk", tree.ancestor, force)
    return (kin.motion * per_dof).sum(-1)
