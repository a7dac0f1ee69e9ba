"""One MuJoCo step recomputed in torch at the engine's own state, and its adjoint.

Forward, MuJoCo-Warp steps as always; the adapter records each substep's input ``(qpos, qvel)`` and the
constraint solver's converged acceleration ``a0`` (``Data.qacc``). Backward replays each substep here,
in float64, as a function of its input and the control, and back-propagates through it, last substep
first (:func:`control_step_vjp`). The replay (:func:`substep`) is MuJoCo's step (``forward.py``:
``fwd_position``, ``fwd_velocity``, ``fwd_acceleration``, ``solve``, ``euler``) for the models
:mod:`.tree` admits:

1. kinematics, the mass matrix with armature and the bias forces (:mod:`.dynamics`);
2. ``qfrc_smooth = qfrc_applied - damping qvel - qfrc_bias``;
3. the constraint rows at this state (:mod:`.constraints`): which limits and contacts are active and
   each contact's zone in its friction cone are read from the engine's solution and frozen (a discrete
   choice has no derivative);
4. the constraint solve by implicit differentiation at the converged solution: the solver minimises a
   convex cost whose gradient ``g(a; x) = M a - qfrc_smooth - J^T f(J a - aref)`` vanishes at ``a0``,
   so ``da/dx = -H^-1 dg/dx`` with ``H = dg/da = M + J^T C J`` (``C`` the zones' cost Hessians), the
   matrix MuJoCo's Newton solver factors. ``a = a0 - H^-1 g(a0; x)`` with ``a0`` and ``H`` held constant
   has exactly that derivative, and equals ``a0`` to the solver's tolerance: one linear solve per
   substep in the backward pass, never a pass through the solver's iterations;
5. Euler with implicit damping: ``(M + h B) a_int = M a`` (``a_int = a`` without damping),
   ``qvel' = qvel + h a_int``, then ``qpos' = integrate(qpos, qvel', h)`` (:mod:`.integrate`).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch.profiler import record_function

from backends.mujoco_warp.adjoint import constraints as cons
from backends.mujoco_warp.adjoint import dynamics
from backends.mujoco_warp.adjoint.integrate import integrate_positions
from backends.mujoco_warp.adjoint.tree import RigidTree


def _constraint_force(rows: cons.Rows, qacc: torch.Tensor, zones) -> torch.Tensor:
    """``J^T f`` (N, nv) of every row at ``qacc`` with the zones frozen."""
    limit_f, contact_f = cons.forces(rows, qacc, *zones)
    joint = (rows.limit_jac * limit_f[..., None]).sum(1)
    return joint + (rows.contact_jac * contact_f[..., None]).sum((1, 2))


def _hessian(mass: torch.Tensor, rows: cons.Rows, limit_zone: torch.Tensor, blocks: torch.Tensor) -> torch.Tensor:
    """The solver cost's Hessian ``M + J^T C J`` (N, nv, nv), ``C`` the limits' ``D`` where quadratic and
    the contacts' ``blocks`` (:func:`~backends.mujoco_warp.adjoint.constraints.zones_and_hessian_blocks`)."""
    d = rows.limit_d * (limit_zone == cons.QUADRATIC)
    h = mass + (rows.limit_jac.transpose(1, 2) * d[:, None]) @ rows.limit_jac
    jac = rows.contact_jac.flatten(1, 2)  # (N, C k, nv)
    return h + jac.transpose(1, 2) @ (blocks @ rows.contact_jac).flatten(1, 2)


def substep(
    tree: RigidTree, qpos: torch.Tensor, qvel: torch.Tensor, applied: torch.Tensor, qacc0: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """One MuJoCo step (module docstring) of N worlds: (qpos, qvel) and the generalized applied force
    ``applied`` (N, nv) -> next (qpos, qvel); ``qacc0`` (N, nv) is the engine's converged acceleration."""
    with record_function("adjoint: kinematics"):
        kin = dynamics.kinematics(tree, qpos)
    with record_function("adjoint: mass matrix"):
        mass = dynamics.mass_matrix(tree, kin)
    with record_function("adjoint: bias forces"):
        smooth = applied - dynamics.bias_force(tree, kin, qvel)
        if tree.damped:
            smooth = smooth - tree.damping * qvel
    with record_function("adjoint: constraint rows"):
        rows = cons.constraint_rows(tree, kin, qpos, qvel)
    with record_function("adjoint: constraint solve"):
        qacc0 = qacc0.detach()
        with torch.no_grad():
            limit_zone, contact_zone, blocks = cons.zones_and_hessian_blocks(rows, qacc0)
            hessian = _hessian(mass, rows, limit_zone, blocks)
        zones = (limit_zone, contact_zone)
        residual = (mass @ qacc0[..., None]).squeeze(-1) - smooth - _constraint_force(rows, qacc0, zones)
        qacc = qacc0 - torch.linalg.solve(hessian, residual)
    with record_function("adjoint: integrator"):
        h = tree.timestep
        if tree.damped:
            qacc = torch.linalg.solve(mass + h * torch.diag(tree.damping), (mass @ qacc[..., None]).squeeze(-1))
        qvel_next = qvel + h * qacc
        return integrate_positions(tree, qpos, qvel_next, h), qvel_next


def control_step_vjp(
    tree: RigidTree,
    records: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]],
    control: torch.Tensor,
    applied_of: Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor],
    grad_qpos: torch.Tensor,
    grad_qvel: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Vector-Jacobian product of one control step: ``records`` holds each substep's engine input
    ``(qpos, qvel)`` and converged ``qacc``; ``applied_of(control, qpos, qvel)`` the generalized applied
    force (the torques, or the PD law of a position target, on that substep's state). Returns the
    gradients w.r.t. the first substep's qpos and qvel and w.r.t. ``control`` (float64)."""
    control = control.detach().to(torch.float64).requires_grad_(True)
    grad_control = torch.zeros_like(control)
    for qpos, qvel, qacc in reversed(records):
        q = qpos.to(torch.float64).requires_grad_(True)
        v = qvel.to(torch.float64).requires_grad_(True)
        with torch.enable_grad():
            q_next, v_next = substep(tree, q, v, applied_of(control, q, v), qacc.to(torch.float64))
            grad_qpos, grad_qvel, g_control = torch.autograd.grad(
                (q_next, v_next), (q, v, control), (grad_qpos, grad_qvel), allow_unused=True
            )
        if g_control is not None:
            grad_control = grad_control + g_control
    return grad_qpos, grad_qvel, grad_control
