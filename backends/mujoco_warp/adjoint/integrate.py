"""MuJoCo's position integration (``mj_integratePos``) in torch: hinges add ``h qvel``; a free joint's
position adds ``h v`` (world frame) and its quaternion turns by the body-frame angular velocity,
``q <- normalise(q * exp(h w / 2))``."""

from __future__ import annotations

import math

import torch

from backends.mujoco_warp.adjoint.tree import RigidTree


def _hamilton_form() -> torch.Tensor:
    """(16, 4) ``W`` with ``a * b = (a b^T) W`` (flattened), the Hamilton product of w, x, y, z quaternions:
    each component of the product is a bilinear form in the two factors."""
    w = torch.zeros(4, 4, 4, dtype=torch.float64)
    # (component, a index, b index, sign): w = aw bw - ax bx - ay by - az bz; x = aw bx + ax bw + ay bz - az by; ...
    for out, a, b, sign in (
        (0, 0, 0, 1), (0, 1, 1, -1), (0, 2, 2, -1), (0, 3, 3, -1),
        (1, 0, 1, 1), (1, 1, 0, 1), (1, 2, 3, 1), (1, 3, 2, -1),
        (2, 0, 2, 1), (2, 1, 3, -1), (2, 2, 0, 1), (2, 3, 1, 1),
        (3, 0, 3, 1), (3, 1, 2, 1), (3, 2, 1, -1), (3, 3, 0, 1),
    ):  # fmt: skip
        w[a, b, out] = sign
    return w.reshape(16, 4)


_HAMILTON = _hamilton_form()


def quat_mul_wxyz(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of (..., 4) quaternions in MuJoCo's w, x, y, z order (:func:`simcore.quat_mul`'s)."""
    return (a[..., :, None] * b[..., None, :]).flatten(-2) @ _HAMILTON.to(a.dtype)


def rotation_quat(rotvec: torch.Tensor) -> torch.Tensor:
    """w, x, y, z quaternions of rotation vectors (..., 3), ``(cos(t / 2), sin(t / 2) / t v)`` with ``t = |v|``;
    smooth through zero (``sin(t / 2) / t`` as torch's ``sinc``, whose derivative is defined there), where
    :func:`simcore.quat_from_rotation_vector`'s gradient is not: the adjoint differentiates at zero."""
    angle = torch.sqrt((rotvec * rotvec).sum(-1, keepdim=True).clamp_min(1e-30))
    return torch.cat((torch.cos(0.5 * angle), 0.5 * torch.sinc(angle / (2 * math.pi)) * rotvec), dim=-1)


def integrate_positions(tree: RigidTree, qpos: torch.Tensor, qvel: torch.Tensor, h: float) -> torch.Tensor:
    """``qpos`` (N, nq) advanced by ``h`` at velocity ``qvel`` (N, nv), MuJoCo's convention: every
    coordinate but the free root's quaternion moves linearly (``tree.velocity_map``), the quaternion turns."""
    moved = qpos + h * (qvel @ tree.velocity_map)
    root = tree.levels[0] if tree.levels else None
    if root is None or not root["free"]:
        return moved
    qa, da = tree.qposadr[root["first"]], tree.dofadr[root["first"]]
    turned = quat_mul_wxyz(qpos[:, qa + 3 : qa + 7], rotation_quat(h * qvel[:, da + 3 : da + 6]))
    return torch.cat((moved[:, : qa + 3], turned / turned.norm(dim=-1, keepdim=True), moved[:, qa + 7 :]), dim=1)
