"""MuJoCo's position integration (``mj_integratePos``) in torch: hinges add ``h qvel``; a free joint's
position adds ``h v`` (world frame) and its quaternion turns by the body-frame angular velocity,
``q <- normalise(q * exp(h w / 2))``."""

from __future__ import annotations

import mujoco
import torch

from backends.mujoco_warp.adjoint.tree import RigidTree
from simcore import quat_mul, wxyz_to_xyzw, xyzw_to_wxyz


def quat_mul_wxyz(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of (..., 4) quaternions in MuJoCo's w, x, y, z order (:func:`simcore.quat_mul`'s)."""
    return xyzw_to_wxyz(quat_mul(wxyz_to_xyzw(a), wxyz_to_xyzw(b)))


def rotation_quat(rotvec: torch.Tensor) -> torch.Tensor:
    """w, x, y, z quaternions of rotation vectors (..., 3); smooth through zero (sin(t/2)/t by its series),
    where :func:`simcore.quat_from_rotation_vector`'s gradient is not: the adjoint differentiates at zero."""
    angle_sq = (rotvec * rotvec).sum(-1, keepdim=True)
    angle = torch.sqrt(angle_sq.clamp_min(1e-30))
    small = angle_sq < 1e-8
    half_sinc = torch.where(small, 0.5 - angle_sq / 48.0, torch.sin(0.5 * angle) / angle)
    cos = torch.where(small, 1.0 - angle_sq / 8.0, torch.cos(0.5 * angle))
    return torch.cat((cos, half_sinc * rotvec), dim=-1)


def integrate_positions(tree: RigidTree, qpos: torch.Tensor, qvel: torch.Tensor, h: float) -> torch.Tensor:
    """``qpos`` (N, nq) advanced by ``h`` at velocity ``qvel`` (N, nv), MuJoCo's convention."""
    parts, cursor = [], 0
    for b in sorted(range(1, tree.nbody), key=lambda body: tree.qposadr[body]):
        qa, da = tree.qposadr[b], tree.dofadr[b]
        if tree.joint_type[b] == mujoco.mjtJoint.mjJNT_FREE:
            position = qpos[:, qa : qa + 3] + h * qvel[:, da : da + 3]
            turned = quat_mul_wxyz(qpos[:, qa + 3 : qa + 7], rotation_quat(h * qvel[:, da + 3 : da + 6]))
            parts += [position, turned / turned.norm(dim=-1, keepdim=True)]
            cursor = qa + 7
        else:
            parts.append(qpos[:, qa : qa + 1] + h * qvel[:, da : da + 1])
            cursor = qa + 1
    if cursor != tree.nq:
        raise AssertionError("qpos layout not covered by the tree's joints")
    return torch.cat(parts, dim=1)
