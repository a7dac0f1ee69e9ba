"""The task's penalty constants as MuJoCo soft constraints: one conversion, written down once, for every
adapter of MuJoCo's model family (MuJoCo-Warp here; MuJoCo C or MJX as plug-ins): it imports MuJoCo alone.

Newton (and the task's :class:`simcore.PhysicsSpec`) speaks of penalty springs in force space: a
contact point that penetrates the ground by ``p`` pushes back with ``ke p + kd max(-v_n, 0)``,
slides against a viscous friction ``kf v_t`` capped at Coulomb's ``mu`` times the normal force, and
a joint past its limit by ``delta`` feels ``-(ke_lim delta + kd_lim delta_dot)``. MuJoCo's contacts
and limits are soft constraints instead: per constraint row, the solver pulls the row's acceleration
towards a reference ``a_ref = -B v - K i r`` (``r`` the violation, ``i`` the impedance), with a
regulariser ``R = (1 - i) / i * A_hat`` where ``A_hat`` is MuJoCo's configuration-independent
approximation of the row's inverse inertia: ``body_invweight0`` (translation) of the contacting body
for a contact, ``dof_invweight0`` for a joint limit.

At rest (the row's acceleration zero) the row's force is exactly ``a_ref / R``, whatever the
coupling between rows. With the direct (negative) form of ``solref``, ``K = -solref[0] / d^2`` and
``B = -solref[1] / d``, and a constant impedance ``i = d`` (``solimp = (d, d, ...)``), that force is

    f = (-solref[0] r - solref[1] v) / ((1 - d) A_hat),

a penalty spring-damper in force space. So the conversion is

    solref = (-ke (1 - d) A_hat, -kd (1 - d) A_hat)

for contacts (``A_hat`` of the robot body; the plane adds nothing) and for joint limits
(``solreflimit``, ``A_hat`` of the hinge's dof). Friction: with an elliptic cone the friction rows
share the normal row's ``B`` and have the regulariser ``R / impratio``, so steady sliding inside the
cone feels ``kd impratio v_t``: ``impratio = kf / kd`` gives Newton's viscous slope ``kf``, and the
cone caps it at ``mu`` times the normal force, as Newton's law does. ``kf = 0`` is frictionless
contact (``condim = 1``), ``mu = 0`` likewise.

Away from rest the two laws differ: with impedance ``d`` the constrained row accelerates as
``(1 - d) [a_free - (ke r + kd v) A_hat]``, i.e. MuJoCo runs the contact's transient ``1 / (1 - d)``
times slower in time squared than the penalty spring; a small ``d`` makes them agree, and too small a
one makes the reference stiffness ``K`` overflow the integrator. ``IMPEDANCE`` = 0.1 was chosen by
measurement on MuJoCo C (a 8 kg box on four contacts, ke 4e3, kd 1e2, kf 30): resting penetration
and steady sliding speed equal the penalty law's to three digits for d in [0.05, 0.5]; a 5 cm drop
follows the penalty ODE within 8.5 mm at d = 0.1 (37 mm at 0.5, 115 mm at 0.9), and d = 0.01 stays
stable only for the softer of the tested settings. Newton damps only a contact's approach
(``max(-v_n, 0)``); MuJoCo damps both ways and clips the force at zero: the one difference left at
rest-free contact, named here and measured by ``python -m harness parity``.
"""

from __future__ import annotations

import mujoco

from backends.contract import BackendError

IMPEDANCE = 0.1  # the constant solimp impedance d of every contact and limit row (module docstring)


def penalty_solref(ke: float, kd: float, inverse_weight: float) -> list[float]:
    """``solref`` in MuJoCo's direct form for a penalty spring ``ke`` and damper ``kd`` on a row whose
    inverse inertia MuJoCo approximates by ``inverse_weight`` (module docstring)."""
    scale = (1.0 - IMPEDANCE) * inverse_weight
    return [-ke * scale, -kd * scale]


def constant_solimp() -> list[float]:
    """``solimp`` of a constant impedance ``IMPEDANCE`` (MuJoCo's width/midpoint/power then do nothing)."""
    return [IMPEDANCE, IMPEDANCE, 0.001, 0.5, 2.0]


def apply_penalty_constants(spec: mujoco.MjSpec, phys) -> None:
    """Write the contact and joint-limit constants of ``phys`` onto ``spec`` (module docstring).

    Compiles ``spec`` once to read MuJoCo's inverse weights (which do not depend on solref/solimp).
    Refuses, in one line naming the field, friction without contact damping (``impratio = kf / kd``)."""
    if phys.ground_plane and phys.contact_kf > 0 and phys.contact_mu > 0 and phys.contact_kd <= 0:
        raise BackendError(
            "PhysicsSpec.contact_kf > 0 needs contact_kd > 0 on mujoco_warp: its friction rows take the "
            f"normal row's damping (impratio = kf / kd), got contact_kd={phys.contact_kd}"
        )
    model = spec.compile()
    geoms = list(spec.geoms)
    if len(geoms) != model.ngeom:
        raise BackendError(f"spec has {len(geoms)} geoms, its model {model.ngeom}")
    frictionless = phys.contact_kf <= 0 or phys.contact_mu <= 0
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 1.0 if frictionless else phys.contact_kf / phys.contact_kd
    for index, geom in enumerate(geoms):
        body = int(model.geom_bodyid[index])
        if body == 0:  # the plane: the robot geom's parameters win (priority), nothing to convert
            continue
        geom.solref = penalty_solref(phys.contact_ke, phys.contact_kd, float(model.body_invweight0[body][0]))
        geom.solimp = constant_solimp()
        geom.condim = 1 if frictionless else 3
    for index, joint in enumerate(spec.joints):
        if joint.type != mujoco.mjtJoint.mjJNT_HINGE or not model.jnt_limited[index]:
            continue
        dof = int(model.jnt_dofadr[index])
        joint.solref_limit = penalty_solref(phys.joint_limit_ke, phys.joint_limit_kd, float(model.dof_invweight0[dof]))
        joint.solimp_limit = constant_solimp()
