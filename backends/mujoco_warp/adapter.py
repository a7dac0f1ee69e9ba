"""MuJoCo-Warp adapter: MuJoCo's dynamics batched on Warp, gradients from batched finite differences.

MuJoCo-Warp 4.0 compiles its kernels without backward passes, so there is no tape to replay.
Gradients here are honest central finite differences of one control step, computed for every
env at once in one large batch of worlds and chained by torch autograd (a vector-Jacobian
product per step).

Model (:func:`build_spec`): the task's MJCF or URDF through ``mujoco.MjSpec``, plus a z-up ground
plane (the asset has none). A URDF is read without its ``<visual>``/``<material>`` elements and its
root link gets a free joint (for a floating-base task; MuJoCo reads URDFs as fixed bases), the same
free joint Newton's importer adds. The asset's motors are removed: joint torques enter as
``qfrc_applied`` on the hinge dofs, so nothing is applied twice; ``JOINT_POSITION_TARGET`` computes
that torque from the task's PD law (``PhysicsSpec.pd_torque``) before every substep, from the
substep's own joint positions and velocities, as Newton's adapter does on its tape. Timestep
``physics.sim_dt`` (1/960 s) with ``physics.substeps`` (16) MuJoCo steps per control step, Euler
integrator (MuJoCo's default; joint damping implicit). Friction ``physics.contact_mu`` on every geom
and the plane; joint damping ``physics.joint_damping`` on the hinges; armature ``physics.armature``
(or the asset's when ``None``) and ranges from the asset. Self-collisions are off
(``contype``/``conaffinity``), as in the Newton adapter: only geom-ground contacts exist.

Contacts and joint limits: MuJoCo's are soft constraints, Newton's (and the task's) penalty springs.
:mod:`backends.mujoco_penalty` converts the task's ``contact_ke/kd/kf`` and ``joint_limit_ke/kd``
into direct-form ``solref``/``solreflimit`` with a constant impedance and an elliptic friction cone
with ``impratio = kf / kd``, so that at rest and in steady sliding MuJoCo's forces are the penalty
law's (``python -m harness parity`` measures it: probe penetration and limit deflection agree to
0.1%); :meth:`MujocoWarpSim.physics_mapping` lists every field's mapping. MuJoCo also honours the
armature, which Newton's semi-implicit solver cannot (that solver refuses a non-zero one).

Engine state (N, D), D = nq + nv = 29 for the Ant (37 for the Go2; a fixed base has hinges only):
MuJoCo's ``qpos`` (root position, root quaternion w-x-y-z, hinges) and ``qvel`` (root linear
velocity of the body origin in the world frame, root angular velocity in the *body* frame, hinge
velocities). The backend-neutral fields
are computed from it in torch (differentiable): quaternion reordered to x-y-z-w, angular velocity
rotated to the world frame, linear velocity moved to the root's centre of mass
(``v_com = v_origin + w_world x R c`` with ``c = body_ipos`` of the root).
:meth:`MujocoWarpSim.state_from_generalized` does the inverse (normalising the quaternion).

One control step is a pure function of (qpos, qvel, torque): ``qacc_warmstart`` (the constraint
solver's warm start, MuJoCo's only other carried state here) is zeroed at the start of each
control step and carried only across its substeps.

Gradients, option ``gradients``: ``fd``, the default, batched finite differences (below); or ``adjoint``,
the analytic adjoint of MuJoCo's step (:mod:`backends.mujoco_warp.adjoint`; :class:`_AdjointStep`): the
forward steps the nominal worlds only, recording each substep's input and converged acceleration, and
the backward replays each substep in torch at those states. It covers rigid trees of spheres,
capsules, boxes and cylinders on the plane (the Ant, the Go2) and refuses every other model when the
adapter is built.

Finite differences (:meth:`MujocoWarpSim.fd_jacobians`, :class:`_MujocoWarpStep`):

* Tangent coordinates per env: 2 * nv = 28 state coordinates (root position, root rotation,
  hinges, all of qvel) and nu = 8 torques. The rotation is perturbed on the manifold,
  ``q' = q * exp(delta / 2)`` with ``delta`` a body-frame rotation vector (MuJoCo's own tangent
  convention, that of ``mj_integratePos`` and ``mjd_transitionFD``); everything else additively.
* One batch of ``1 + 2 * (2 nv + nu)`` = 73 worlds per env (nominal, +eps and -eps for each
  coordinate) runs through the same ``substeps`` ``mujoco_warp.step`` calls. The nominal world is
  the forward result (bit-identical to the no-grad path); central differences of the others give
  per-env Jacobians of the next engine state (ambient, D rows) w.r.t. the tangent state (2 nv
  columns) and the torques (nu columns).
* Backward is a vector-Jacobian product. Tangent gradients map to the ambient input as follows:
  identity for positions, hinges and velocities; for the quaternion, MuJoCo normalises ``q``
  before use, so the step depends on ``q`` only through ``q^ = q / |q|`` and, to first order,
  ``delta = 2 Im(conj(q^) * dq) / |q|`` (the radial part of ``dq`` gives ``delta = 0``). Hence
  ``dL/dq = (2 / |q|) E(conj(q^))^T dL/d delta`` where ``E(p) r = Im(p * r)``; the gradient
  along ``q`` itself is zero.
* Schemes (option ``fd_scheme``): ``one_sided`` (the default) on central's worlds, 1 + 2P per env
  (73 on the Ant, 97 on the Go2): per env and coordinate the central quotient where the forward and
  backward quotients agree, and where they disagree (a contact made or broken inside the stencil,
  where a finite step's quotient is the jump over the step and no derivative) the smaller of the two,
  the one-sided derivative on the side without the switch; ``central`` as above without that choice;
  ``forward``, ``(f(x + eps e_i) - f(x)) / eps`` from the nominal world, 1 + P worlds per env (37,
  49). ``one_sided`` is the default because it is the most accurate in contact and, unlike forward
  differences, keeps training's actor gradients near Newton's exact ones at twice forward's cost
  (docs/mujoco-warp.md has the measurements). ``adaptive`` makes ``one_sided``'s choice of side
  from the constraint sets instead of the quotients, and pays for the second side only where it is
  needed: forward's 1 + P worlds, each recording at every substep which constraints it used
  (:mod:`backends.mujoco_warp.switches`); the forward quotient where the +eps world kept the
  nominal's constraint set at every substep, and for each (env, coordinate) where it did not (a
  contact made or broken, friction starting or stopping to slide inside the stencil), a -eps world
  in a second batch: its backward quotient where that world kept the set, else the smaller of the
  two. Exact in the limit wherever the step is differentiable; off the switches it is forward
  differences (first order), so its smooth-region error is forward's, not central's.
* Steps, one per kind of coordinate: ``fd_eps_state`` (positions, metres and radians),
  ``fd_eps_velocity`` (velocities) and ``fd_eps_control`` (torques in N m, or PD targets in rad).
  Their defaults were chosen where training runs, in contact, against float64 MuJoCo C at the same
  cost (``harness fd-schemes``, run by the perf profile; docs/mujoco-warp.md): a state step straddles
  a contact's switches the more often the larger it is, and a quotient across a switch is a jump over
  the step, no derivative, so positions and velocities take one small step (:data:`FD_EPS_STATE`);
  controls take 1 N m or 1e-2 rad, the most accurate measured.
  The perturbed worlds' solver settings (``fd_warmstart``: the nominal world's warm start carried
  into them; ``fd_tolerance``: their solver tolerance) change no error measurably and cost more, so
  they stay off.
* Cost: the scheme's worlds per env for a step with grad (1 + 2P by default), 1 without;
  ``fd_chunk_envs`` (default: all envs) bounds how many envs share one batch, i.e. memory, without
  changing the result.

Soft bodies (``TET_ACTIVATION``, the SoftJumper; :mod:`backends.mujoco_warp.soft`): the tet mesh as a
``dim = 3`` flex, one compiled model per env (each env's body has its own size), engine state
``[qpos, qvel]`` = vertex displacements from rest and velocities, activations as nodal forces every
substep. Finite differences perturb all ``2 * 3P + T`` coordinates additively (3109 worlds per env
for the SoftJumper), env by env, in chunks of ``fd_chunk_worlds``; state step 1e-3 m, activation
step 1e-2.
"""

from __future__ import annotations

import math
from xml.etree import ElementTree

import mujoco
import mujoco_warp as mjw
import torch
import warp as wp

from backends._warp import option_flag, warp_device
from backends.contract import MIB, BackendError, BatchedSim, TaskCost, inert_by_definition, option_number
from backends.mujoco_penalty import IMPEDANCE, apply_penalty_constants
from backends.mujoco_warp.adjoint.step import control_step_vjp
from backends.mujoco_warp.adjoint.tree import rigid_tree
from backends.mujoco_warp.soft import SoftEnvModels
from backends.mujoco_warp.stepping import SubstepReplay, run_substeps
from backends.mujoco_warp.switches import ConstraintSignature
from simcore import (
    ControlKind,
    SimState,
    StateLayout,
    activation_nodal_forces,
    quat_conjugate,
    quat_from_rotation_vector,
    quat_mul,
    quat_rotate,
    wxyz_to_xyzw,
    xyzw_to_wxyz,
)

#: the ``gradients`` option: batched finite differences, or the analytic adjoint (:mod:`.adjoint`)
GRADIENT_MODES = ("fd", "adjoint")
FD_SCHEMES = ("central", "forward", "one_sided", "adaptive")  # schemes of the ``fd_scheme`` option
#: each scheme's default position step (articulated tasks; module docstring, "Steps")
FD_EPS_STATE = {"central": 5e-4, "forward": 2.5e-4, "one_sided": 5e-4, "adaptive": 2.5e-4}
#: a scheme's default velocity step where it is not the position step's: ``adaptive`` handles the
#: switches a large step straddles, so its velocities take the step float32 favours (docs/mujoco-warp.md)
FD_EPS_VELOCITY = {"adaptive": 1e-2}
#: ``one_sided``: a coordinate whose forward and backward quotients differ by more than this fraction of
#: the larger has a switch (a contact made or broken) inside its stencil
SWITCH_DISAGREEMENT = 0.5

_ROOT_Q = 7  # free joint: position (3) + quaternion w, x, y, z (4)
_ROOT_V = 6  # free joint: linear velocity (3, world frame) + angular velocity (3, body frame)


def build_spec(task) -> mujoco.MjSpec:
    """The task's asset as an ``MjSpec`` set up for this adapter (see the module docstring).

    MJCF loads as it is. URDF loads after its ``<visual>`` and ``<material>`` elements are dropped
    (MuJoCo's URDF reader rejects repeated materials, and this adapter never renders), and the root
    link gets a free joint: MuJoCo reads a URDF as a fixed base, Newton's importer adds the same
    free joint with ``floating=True``. Returned uncompiled so tests can build variants of exactly
    this model (e.g. with gear-1 motors).
    """
    phys = task.physics
    if task.asset_format not in ("mjcf", "urdf"):
        raise BackendError(f"the mujoco_warp adapter cannot load {task.asset_format!r} assets yet")
    try:
        if task.asset_format == "urdf":
            spec = mujoco.MjSpec.from_string(_urdf_without_visuals(task.asset_path))
            roots = list(spec.worldbody.bodies)
            if len(roots) != 1:
                raise BackendError(f"URDF {task.asset_path.name} has {len(roots)} root links; one is expected")
            if task.layout.floating_base:
                roots[0].add_freejoint()
        else:
            spec = mujoco.MjSpec.from_file(str(task.asset_path))
    except BackendError:
        raise
    except Exception as exc:  # the parsers raise assorted types for malformed files
        raise BackendError(f"cannot load {task.asset_format} asset {task.asset_path}: {exc}") from exc
    spec.option.timestep = phys.sim_dt
    spec.option.gravity = [0.0, 0.0, phys.gravity]
    for actuator in list(spec.actuators):  # torques go through qfrc_applied instead
        spec.delete(actuator)
    for geom in spec.geoms:
        geom.friction[0] = phys.contact_mu
        geom.contype, geom.conaffinity = 1, 0  # collide with the ground only, never with each other
        geom.priority = 1  # a robot geom's contact parameters win over the plane's (backends.mujoco_penalty)
    for joint in spec.joints:
        if joint.type == mujoco.mjtJoint.mjJNT_HINGE:
            joint.damping[0] = phys.joint_damping
            if phys.armature is not None:
                joint.armature = phys.armature
    if phys.ground_plane:
        spec.worldbody.add_geom(
            name="ground",
            type=mujoco.mjtGeom.mjGEOM_PLANE,
            size=[0.0, 0.0, 1.0],  # infinite plane through the origin, normal +z
            friction=[phys.contact_mu, 0.005, 0.0001],
            contype=0,
            conaffinity=1,
        )
    apply_penalty_constants(spec, phys)
    return spec


def _urdf_without_visuals(path) -> str:
    """The URDF's text with every ``<visual>`` and ``<material>`` element removed."""
    root = ElementTree.parse(path).getroot()
    for parent in list(root.iter()):
        for child in list(parent):
            if child.tag in ("visual", "material"):
                parent.remove(child)
    return ElementTree.tostring(root, encoding="unicode")


def fd_settings(task, options: dict) -> dict:
    """The finite-difference settings of ``task`` under adapter ``options``: each option's value, or
    its default (module docstring), validated. Articulated tasks: ``fd_scheme`` (one_sided),
    ``fd_eps_state`` (positions), ``fd_eps_velocity`` (default: the positions' step; adaptive: 1e-2),
    ``fd_eps_control``, ``fd_warmstart`` and ``fd_tolerance`` (the perturbed worlds' solves); soft
    bodies: central differences, ``fd_eps_state`` and ``fd_eps_control``."""
    soft = task.control_kind == ControlKind.TET_ACTIVATION
    position_control = task.control_kind == ControlKind.JOINT_POSITION_TARGET
    mode = str(options.get("gradients", "fd"))
    if mode not in GRADIENT_MODES:
        raise ValueError(f"gradients must be one of {', '.join(GRADIENT_MODES)}, got {mode!r}")
    if mode == "adjoint":
        stray = sorted(name for name in options if name.startswith("fd_"))
        if stray:
            raise ValueError(f"{', '.join(stray)} set the finite differences; gradients=adjoint takes none")
        if soft:
            raise ValueError("gradients=adjoint covers rigid articulated models; soft bodies take gradients=fd")
        return {"gradients": "adjoint"}
    scheme = str(options.get("fd_scheme", "central" if soft else "one_sided"))
    if scheme not in FD_SCHEMES:
        raise ValueError(f"fd_scheme must be one of {', '.join(FD_SCHEMES)}, got {scheme!r}")
    if soft and scheme == "adaptive":
        raise ValueError("fd_scheme adaptive reads the constraint rows of articulated models; soft bodies take central")
    if soft:  # not measured against a reference for soft bodies: kept central
        settings = {
            "fd_scheme": scheme,
            "fd_eps_state": float(options.get("fd_eps_state", 1e-3)),
            "fd_eps_control": float(options.get("fd_eps_control", 1e-2)),
        }
    else:
        eps_state = float(options.get("fd_eps_state", FD_EPS_STATE[scheme]))
        tolerance = options.get("fd_tolerance")
        settings = {
            "fd_scheme": scheme,
            "fd_eps_state": eps_state,
            "fd_eps_velocity": float(options.get("fd_eps_velocity", FD_EPS_VELOCITY.get(scheme, eps_state))),
            # 1 N m of torque, or 1e-2 rad of PD target (x kp = 0.3 N m on the Go2); module docstring
            "fd_eps_control": float(options.get("fd_eps_control", 1e-2 if position_control else 1.0)),
            "fd_warmstart": str(options.get("fd_warmstart", "zero")),
            "fd_tolerance": None if tolerance is None else float(tolerance),
        }
        if settings["fd_warmstart"] not in ("zero", "nominal"):
            raise ValueError(f"fd_warmstart must be zero or nominal, got {settings['fd_warmstart']!r}")
        if settings["fd_tolerance"] is not None and not settings["fd_tolerance"] >= 0:
            raise ValueError(f"fd_tolerance must be >= 0, got {tolerance!r}")
    for name in ("fd_eps_state", "fd_eps_velocity", "fd_eps_control", "fd_tolerance"):
        if settings.get(name) is not None and not (math.isfinite(settings[name]) and settings[name] >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {settings[name]!r}")
        if name != "fd_tolerance" and name in settings and not settings[name] > 0:
            raise ValueError(f"{name} must be positive, got {settings[name]!r}")
    return settings


class MujocoWarpSim(BatchedSim):
    """A task on MuJoCo-Warp with finite-difference gradients; see the module docstring.

    Options: the finite-difference settings of :func:`fd_settings` (``fd_scheme``, ``fd_eps_state``,
    ``fd_eps_velocity``, ``fd_eps_control``, ``fd_warmstart``, ``fd_tolerance``); ``fd_chunk_envs``
    (default: all envs) envs per finite-difference batch; ``nconmax`` (default 32) contacts and
    ``njmax`` (default 160) constraint rows per world (the Ant's 13 geoms on the plane make at most 25
    contacts, 4 rows each in the pyramidal cone, plus 8 joint-limit rows; an overflow raises
    :class:`BackendError`). The contract's ``max_graph_steps`` is not needed: the Jacobians
    live in the autograd graph, so there is no buffer ring to size. Control kinds: joint torques,
    joint position targets (the PD law per substep) and tet activations (soft bodies: options
    ``fd_chunk_worlds``, default 256, and ``nconmax`` 128 / ``njmax`` 512 per world).
    """

    name = "mujoco_warp"
    contract_tasks = ("ant", "go2")
    table_rank = 1
    contact_reference = "mujoco_c"
    # Planning figures on a 2-core CPU (as Newton's; the adjoint's from results/adjoint/, scaled for the
    # updates). Finite differences hold every perturbed world once: the memory with gradients per env;
    # the adjoint holds no perturbed world (its replay's per-step records counted as the forward's).
    costs = {
        "ant": TaskCost(train_s=4e-2, eval_s=5e-3, bytes_per_env=(0.04 * MIB, 3.0 * MIB, 0.05 * MIB)),
        "go2": TaskCost(train_s=6e-2, eval_s=6e-3, bytes_per_env=(0.05 * MIB, 5.0 * MIB, 0.05 * MIB)),
        "soft_jumper": TaskCost(train_s=3e3, eval_s=1.0),
        "ant gradients=adjoint": TaskCost(train_s=5e-3, eval_s=5e-3, bytes_per_env=(0.04 * MIB, 0.0, 0.05 * MIB)),
        "go2 gradients=adjoint": TaskCost(train_s=8e-3, eval_s=6e-3, bytes_per_env=(0.05 * MIB, 0.0, 0.05 * MIB)),
    }
    known_options = (
        "gradients",
        "fd_scheme",
        "fd_eps_state",
        "fd_eps_velocity",
        "fd_eps_control",
        "fd_warmstart",
        "fd_tolerance",
        "fd_chunk_envs",
        "fd_chunk_worlds",
        "nconmax",
        "njmax",
        "graph_capture",
    )

    # -- construction ---------------------------------------------------------------------
    def _build(self) -> None:
        task = self.task
        self.wp_device = warp_device(self.device)
        capture = option_flag(self.options, "graph_capture", self.device.type == "cpu", self.name)
        self.stepper = SubstepReplay(capture, self.wp_device)
        self.soft = task.control_kind == ControlKind.TET_ACTIVATION
        if self.soft:
            return self._build_soft()
        if task.layout.num_particles:
            raise BackendError("the mujoco_warp adapter runs particles only as a soft body (tet activations)")
        settings = fd_settings(task, self.options)
        self.gradients = settings.pop("gradients", "fd")
        for name, value in (settings or fd_settings(task, {})).items():
            setattr(self, name, value)  # the adjoint keeps the defaults, unused, so fd_jacobians stays callable
        self.position_control = task.control_kind == ControlKind.JOINT_POSITION_TARGET
        self.fd_chunk_envs = option_number(self.options, "fd_chunk_envs", self.num_envs, self.name, 1, integer=True)
        self.nconmax = option_number(self.options, "nconmax", 32, self.name, 1, integer=True)
        self.njmax = option_number(self.options, "njmax", 160, self.name, 1, integer=True)

        self.mjm = build_spec(task).compile()
        layout = task.layout
        root_is_free = self.mjm.njnt > 0 and self.mjm.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
        if root_is_free != layout.floating_base or self.mjm.nq != layout.nq or self.mjm.nv != layout.nv:
            raise BackendError(
                f"asset {task.asset_path.name} has nq={self.mjm.nq}, nv={self.mjm.nv} (free root: {root_is_free}); "
                f"task {task.name!r} expects nq={layout.nq}, nv={layout.nv} (free root: {layout.floating_base})"
            )
        if self.position_control:
            self.check_torque_limits()
        self.tree = rigid_tree(self.mjm) if self.gradients == "adjoint" else None  # refuses what it does not cover
        self._com_offset = None  # fixed base: the generalized coordinates are MuJoCo's own
        if layout.floating_base:
            root_body = int(self.mjm.jnt_bodyid[0])
            self._com_offset = torch.tensor(self.mjm.body_ipos[root_body], dtype=torch.float32, device=self.device)
        with wp.ScopedDevice(self.wp_device):
            self.model = mjw.put_model(self.mjm)
        self._data: dict[int, tuple[mjw.Data, dict[str, torch.Tensor]]] = {}
        self._signatures: dict[int, ConstraintSignature] = {}
        self._fd_models: dict[int, mjw.Model] = {}
        self.second_side_share: float | None = None  # adaptive: the last step's share of -eps worlds
        self._second_sizes: list[int] = []  # adaptive: the second batches' sizes held, latest last

        # the step of every tangent coordinate: nv positions, nv velocities, then the controls
        eps = [self.fd_eps_state] * layout.nv + [self.fd_eps_velocity] * layout.nv
        eps += [self.fd_eps_control] * layout.num_dofs
        self._fd_steps = torch.tensor(eps, dtype=torch.float64, device=self.device)

    def _build_soft(self) -> None:
        """Soft bodies (:mod:`backends.mujoco_warp.soft`): one compiled flex model per env (each env's
        body has its own size), finite differences env by env in chunks of ``fd_chunk_worlds`` worlds."""
        task, layout = self.task, self.task.layout
        self.checked_soft_body()
        self.position_control = False
        self.gradients, self.tree = "fd", None
        for name, value in fd_settings(task, self.options).items():
            setattr(self, name, value)
        self.fd_chunk_worlds = option_number(self.options, "fd_chunk_worlds", 256, self.name, 1, integer=True)
        self.nconmax = int(self.options.get("nconmax", 128))
        self.njmax = int(self.options.get("njmax", 512))
        if self.fd_chunk_worlds < 1 or self.nconmax < 1 or self.njmax < 1:
            raise ValueError("fd_chunk_worlds, nconmax and njmax must be >= 1")
        self.soft_models = SoftEnvModels(task, self.num_envs, self.stepper, self.device, self.nconmax, self.njmax)
        if self.soft_models.mjm[0].nv != 3 * layout.num_particles:
            raise BackendError(f"flex model has nv={self.soft_models.mjm[0].nv}, expected {3 * layout.num_particles}")
        self._com_offset = None
        dofs = 3 * layout.num_particles
        eps = [self.fd_eps_state] * (2 * dofs) + [self.fd_eps_control] * layout.num_tets
        self._fd_steps = torch.tensor(eps, dtype=torch.float64, device=self.device)

    @property
    def integrator(self) -> str:
        return "mujoco_warp Euler (soft constraints, elliptic cone)"

    def physics_mapping(self) -> dict[str, str]:
        """How each :class:`PhysicsSpec` field reaches MuJoCo (see :meth:`BatchedSim.physics_mapping`;
        the penalty conversion is :mod:`backends.mujoco_penalty`)."""

        def penalty(element: str, weight: str) -> str:
            conversion = f"(-ke (1 - d) A, -kd (1 - d) A), d = {IMPEDANCE} constant impedance"
            return f"{element} = {conversion}, A = {weight} (penalty.py)"

        contact_weight = "1 / mean vertex mass (one flex solref)" if self.soft else "body_invweight0"
        mapping = {
            "frame_dt": "opt.timestep = frame_dt / substeps",
            "substeps": "mujoco_warp.step calls per control step",
            "gravity": "opt.gravity = (0, 0, gravity)",
            "ground_plane": "a z-up plane geom through the origin",
            "contact_ke": penalty("geom solref", contact_weight),
            "contact_kd": "geom solref[1] as contact_ke's; both ways (Newton damps the approach only)",
            "contact_kf": "elliptic cone, opt.impratio = kf / kd (friction rows take the normal row's damping); "
            "kf = 0: condim 1",
            "contact_mu": "geom friction[0] (sliding) of every geom and the plane",
        }
        if not self.soft:
            mapping.update(
                {
                    "joint_limit_ke": penalty("jnt solreflimit", "dof_invweight0"),
                    "joint_limit_kd": "jnt solreflimit[1] as joint_limit_ke's",
                    "joint_damping": "dof_damping of every hinge (MuJoCo integrates it implicitly)",
                    "armature": "dof_armature of every hinge (the asset's when None)",
                    "pd_kp": "qfrc_applied before every substep from the substep's state (PhysicsSpec.pd_torque)",
                    "pd_kd": "as pd_kp",
                    "torque_limits": "as pd_kp (the clip of PhysicsSpec.pd_torque)",
                }
            )
        mapping.update(inert_by_definition(self.task))
        return mapping

    @classmethod
    def gradient_settings(cls, task, options: dict | None = None) -> dict:
        """:meth:`BatchedSim.gradient_settings`: the finite-difference settings (:func:`fd_settings`)."""
        return fd_settings(task, {**dict(getattr(task, "backend_options", {}).get(cls.name, {})), **(options or {})})

    @property
    def layout(self) -> StateLayout:
        return self.task.layout

    @property
    def worlds_per_env_with_grad(self) -> int:
        """Worlds one env costs in a step with grad: the nominal world plus one (forward differences)
        or two (central) per tangent coordinate; ``adaptive`` adds one -eps world per coordinate whose
        stencil holds a switch (``second_side_share`` of them in the last step), at most 1 + 2P. The
        adjoint steps the nominal world only."""
        return 1 if self.gradients == "adjoint" else self._fd_deltas().shape[0]

    def _fd_deltas(self) -> torch.Tensor:
        """(K, P) tangent perturbations, one per world: row 0 nominal, then +eps e_i (P rows), then
        for central differences -eps e_i (P rows). ``adaptive`` steps the -eps worlds in a second
        batch, only where needed (:meth:`_adaptive_jacobians`)."""
        steps = self._fd_steps
        rows = [steps.new_zeros(1, steps.numel()), torch.diag(steps)]
        if self.fd_scheme not in ("forward", "adaptive"):
            rows.append(-torch.diag(steps))
        return torch.cat(rows)

    def _fd_quotients(self, y: torch.Tensor) -> torch.Tensor:
        """Difference quotients from the K outputs ``y`` (K, ..., D) of :meth:`_fd_deltas`' worlds: (P, ..., D)."""
        num_coords = self._fd_steps.numel()
        steps = self._fd_steps.reshape(-1, *([1] * (y.dim() - 1)))
        plus = y[1 : 1 + num_coords]
        if self.fd_scheme == "forward":
            return (plus - y[:1]) / steps
        if self.fd_scheme == "central":
            return (plus - y[1 + num_coords :]) / (2.0 * steps)
        ahead, behind = (plus - y[:1]) / steps, (y[:1] - y[1 + num_coords :]) / steps
        size_ahead, size_behind = ahead.norm(dim=-1, keepdim=True), behind.norm(dim=-1, keepdim=True)
        switch = (ahead - behind).norm(dim=-1, keepdim=True) > SWITCH_DISAGREEMENT * torch.maximum(
            size_ahead, size_behind
        )
        smaller = torch.where(size_ahead <= size_behind, ahead, behind)
        return torch.where(switch, smaller, 0.5 * (ahead + behind))

    def _data_for(self, nworld: int) -> tuple[mjw.Data, dict[str, torch.Tensor]]:
        """A Warp ``Data`` with ``nworld`` worlds (cached) and torch views of the arrays we set and read."""
        if nworld not in self._data:
            with wp.ScopedDevice(self.wp_device):
                data = mjw.make_data(self.mjm, nworld=nworld, nconmax=self.nconmax, njmax=self.njmax)
            names = ("qpos", "qvel", "qacc", "qfrc_applied", "qacc_warmstart", "time", "overflow")
            self._data[nworld] = (data, {k: wp.to_torch(getattr(data, k)) for k in names})
        return self._data[nworld]

    # -- simulation -----------------------------------------------------------------------
    def _fd_model(self, blocks: int, envs: int) -> mjw.Model:
        """The model of a finite-difference batch of ``blocks`` x ``envs`` worlds (perturbation-major):
        the adapter's own, or with ``fd_tolerance`` a shallow copy whose per-world solver tolerance is
        ``fd_tolerance`` in the perturbed worlds and the model's own in the nominal block (whose
        output is the forward result, bit-identical to a step without gradients)."""
        if self.fd_tolerance is None:
            return self.model
        worlds = blocks * envs
        if worlds not in self._fd_models:
            import copy

            model = copy.copy(self.model)
            model.opt = copy.copy(self.model.opt)
            own = float(self.mjm.opt.tolerance)
            values = torch.full((worlds,), self.fd_tolerance, dtype=torch.float32)
            values[:envs] = own
            with wp.ScopedDevice(self.wp_device):
                model.opt.tolerance = wp.array(values.numpy(), dtype=float)
            self._fd_models[worlds] = model
        return self._fd_models[worlds]

    def _run_worlds(
        self,
        qpos: torch.Tensor,
        qvel: torch.Tensor,
        torque: torch.Tensor,
        blocks: int = 1,
        signatures: list[torch.Tensor] | None = None,
        records: list[tuple[torch.Tensor, ...]] | None = None,
    ) -> torch.Tensor:
        """One control step of ``W`` independent worlds: (W, nq), (W, nv), (W, J) -> next engine (W, D).

        ``torque`` is the joint torque, or for position control the PD target the torque is computed
        from at every substep (``PhysicsSpec.pd_torque``, applied as ``qfrc_applied``). ``blocks`` > 1:
        a finite-difference batch, ``blocks`` perturbations of W / blocks envs, the nominal first,
        solved with the options ``fd_warmstart`` and ``fd_tolerance``. ``signatures``: a list that
        receives each substep's (W, 2) constraint signatures (:mod:`backends.mujoco_warp.switches`);
        ``records`` each substep's input ``(qpos, qvel)`` and converged ``qacc`` (the adjoint's replay)."""
        worlds = qpos.shape[0]
        data, view = self._data_for(worlds)
        root = self.layout.nv - self.layout.num_dofs
        view["qpos"].copy_(qpos)
        view["qvel"].copy_(qvel)
        view["qfrc_applied"][:, :root] = 0.0
        view["qfrc_applied"][:, root:] = torque
        view["qacc_warmstart"].zero_()
        view["time"].zero_()
        view["overflow"].zero_()
        phys = self.task.physics
        envs = worlds // blocks
        carry = blocks > 1 and self.fd_warmstart == "nominal"
        warm = view["qacc_warmstart"].view(blocks, envs, -1)
        substep = [0]

        def before_substep() -> None:
            if records is not None:
                records.append((view["qpos"].clone(), view["qvel"].clone()))
            if carry and substep[0] > 0:  # every perturbed world starts its solve where the nominal's did
                warm[1:] = warm[:1]
            substep[0] += 1
            if self.position_control:  # on this substep's state, as Newton's adapter does
                hinges = view["qpos"][:, self.layout.nq - self.layout.num_dofs :]
                view["qfrc_applied"][:, root:] = phys.pd_torque(torque, hinges, view["qvel"][:, root:])

        hook = before_substep if (self.position_control or carry or records is not None) else None
        record = None
        if records is not None:

            def record() -> None:
                records[-1] += (view["qacc"].clone(),)

        elif signatures is not None:
            if worlds not in self._signatures:
                self._signatures[worlds] = ConstraintSignature(data, self.mjm.ngeom)
            signature = self._signatures[worlds]

            def record() -> None:
                signatures.append(signature())

        model = self._fd_model(blocks, envs) if blocks > 1 else self.model
        buffers = (self.nconmax, self.njmax)
        return run_substeps(model, data, view, phys.substeps, self.stepper, hook, buffers, record)

    def _split(self, engine: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return engine[:, : self.layout.nq], engine[:, self.layout.nq :]

    def _control_joint_torque(self, control: torch.Tensor) -> torch.Tensor:
        """JOINT_TORQUE: the hinge torques, applied as ``qfrc_applied`` at every substep."""
        expected = (self.num_envs, self.layout.num_dofs)
        if tuple(control.shape) != expected:
            raise BackendError(f"control must have shape {expected}, got {tuple(control.shape)}")
        return control.to(self.device, torch.float32)

    def _control_tet_activation(self, control: torch.Tensor) -> torch.Tensor:
        """TET_ACTIVATION: (N, T) activations, applied as nodal forces every substep (module ``soft``)."""
        expected = (self.num_envs, self.layout.num_tets)
        if tuple(control.shape) != expected:
            raise BackendError(f"tet activations must have shape {expected}, got {tuple(control.shape)}")
        return control.to(self.device, torch.float32)

    def _control_joint_position_target(self, control: torch.Tensor) -> torch.Tensor:
        """JOINT_POSITION_TARGET: the (N, J) targets; the PD torque is evaluated per substep in :meth:`_run_worlds`."""
        return self._control_joint_torque(control)

    def simulate(self, state: SimState, control: torch.Tensor) -> SimState:
        control = self.engine_control(control)
        if torch.is_grad_enabled() and (state.engine.requires_grad or control.requires_grad):
            step = _AdjointStep if self.gradients == "adjoint" else _MujocoWarpStep
            engine = step.apply(self, state.engine, control)
        elif self.soft:
            engine = self._run_soft_envs(state.engine.detach(), control.detach())
        else:
            qpos, qvel = self._split(state.engine.detach())
            engine = self._run_worlds(qpos, qvel, control.detach())
        return self._state_from_engine(engine)

    def gradient_step_cost(self, sample_worlds: int | None = None) -> dict:
        """Time one control step of ``sample_worlds`` copies of env 0 (after a warm-up step, which
        compiles kernels) and scale it to the ``worlds_per_env_with_grad * num_envs`` worlds of a step
        with gradients (the adjoint: its step and backward replay). Default sample: the whole batch up
        to 256 worlds for articulated tasks (a fraction of a second), 16 worlds for a soft body (~0.5 s
        per world on this CPU). Per-world cost falls as batches grow while the CPU is launch-bound, so a
        partial sample over-estimates."""
        import time

        worlds = self.worlds_per_env_with_grad * self.num_envs
        sample_worlds = sample_worlds or min(worlds, 16 if self.soft else 256)
        engine = self.state.engine.detach()
        width = self.layout.num_tets if self.soft else self.layout.num_dofs
        control = torch.zeros(sample_worlds, width, device=self.device)
        rows = engine[:1].repeat(sample_worlds, 1)
        half = engine.shape[1] // 2 if self.soft else self.layout.nq

        def run() -> float:
            start = time.perf_counter()
            if self.soft:
                self.soft_models.run(0, rows[:, :half], rows[:, half:], control)
            elif self.gradients == "adjoint":  # the nominal step and its backward replay
                _, records = self.adjoint_step(rows, control)
                ones = torch.ones(sample_worlds, self.layout.nq + self.layout.nv, dtype=torch.float64)
                split = (ones[:, : self.layout.nq], ones[:, self.layout.nq :])
                control_step_vjp(self.tree, records, control, self.applied_force, *split)
            else:
                self._run_worlds(rows[:, :half], rows[:, half:], control)
            return time.perf_counter() - start

        run()
        seconds = run()
        return {
            "seconds_per_step": seconds / sample_worlds * worlds,
            "worlds_per_step": worlds,
            "sample_worlds": sample_worlds,
            "sample_seconds": seconds,
        }

    def bare_engine_rollout(self, horizon: int, grad: bool = True) -> float | None:
        """Seconds for ``horizon`` control steps of MuJoCo-Warp alone: ``substeps`` ``mujoco_warp.step``
        calls each (replayed from captured graphs when the adapter captures, as its own steps are), no
        torch in between, on the worlds the adapter steps: N for a forward step, N x
        ``worlds_per_env_with_grad`` for a step with gradients (every env's nominal and perturbed worlds,
        the batch :meth:`fd_jacobians` steps). The worlds start from the current states (each env's state
        in all its worlds) with a fixed applied force: the joint torques of random actions, or for
        position targets the PD torque of random targets at the start. The adapter's per-substep PD law
        and activation forces (torch) and its difference quotients and vector-Jacobian products count as
        adapter time. A soft body's step with gradients (3109 worlds per env) is out of reach: ``None``
        (:meth:`gradient_step_cost` estimates it)."""
        import time

        if self.soft and grad:
            return None
        gen = torch.Generator().manual_seed(0)
        actions = 2.0 * torch.rand(self.num_envs, self.task.action_dim, generator=gen) - 1.0
        control = self.task.actions_to_control(actions).to(self.device, torch.float32)
        engine = self.state.engine.detach()
        if self.soft:  # each env on its own model, one world each, activation forces of the start fixed
            batches = []
            for e in range(self.num_envs):
                data, view = self.soft_models._data_for(e, 1)
                half = engine.shape[1] // 2
                view["qpos"].copy_(engine[e : e + 1, :half])
                view["qvel"].copy_(engine[e : e + 1, half:])
                positions = self.soft_models.rest[e : e + 1] + engine[e : e + 1, :half].reshape(1, -1, 3)
                forces = activation_nodal_forces(
                    positions, self.soft_models.tets, control[e : e + 1], self.task.soft_body.k_lambda
                )
                view["qfrc_applied"].copy_(forces.reshape(1, -1))
                batches.append((self.soft_models.models[e], data))
        else:
            copies = self.worlds_per_env_with_grad if grad else 1
            data, view = self._data_for(self.num_envs * copies)
            qpos, qvel = self._split(engine)
            layout = self.layout
            root = layout.nv - layout.num_dofs
            torque = control
            if self.position_control:
                torque = self.task.physics.pd_torque(control, qpos[:, layout.nq - layout.num_dofs :], qvel[:, root:])
            view["qpos"].copy_(qpos.repeat(copies, 1))
            view["qvel"].copy_(qvel.repeat(copies, 1))
            view["qfrc_applied"].zero_()
            view["qfrc_applied"][:, root:] = torque.repeat(copies, 1)
            view["qacc_warmstart"].zero_()
            batches = [(self.model, data)]
        substeps = self.task.physics.substeps * horizon
        with wp.ScopedDevice(self.wp_device):
            # untimed: each Data's first steps load kernels and (graph_capture) capture its graph, as
            # they did in the adapter's own warm-up; the timed steps start from what these two left
            for model, data in batches:
                for _ in range(2):
                    self.stepper.step(model, data)
            wp.synchronize_device(self.wp_device)
            start = time.perf_counter()
            for model, data in batches:
                for _ in range(substeps):
                    self.stepper.step(model, data)
            wp.synchronize_device(self.wp_device)
            return time.perf_counter() - start

    def _run_soft_envs(self, engine: torch.Tensor, control: torch.Tensor) -> torch.Tensor:
        """One control step of every env's soft body (each on its own model), no gradient."""
        half = engine.shape[1] // 2
        rows = [
            self.soft_models.run(e, engine[e : e + 1, :half], engine[e : e + 1, half:], control[e : e + 1])
            for e in range(self.num_envs)
        ]
        return torch.cat(rows)

    def _soft_fd_jacobians(self, engine: torch.Tensor, control: torch.Tensor):
        """:meth:`fd_jacobians` for soft bodies: env by env, perturbations in chunks of fd_chunk_worlds."""
        half = engine.shape[1] // 2
        deltas = self._fd_deltas()
        outputs, jac = [], []
        for e in range(engine.shape[0]):
            x = torch.cat((engine[e], control[e])).unsqueeze(0) + deltas  # (K, 2 dofs + T), all additive
            chunks = torch.split(x.float(), self.fd_chunk_worlds)
            run = self.soft_models.run
            y = torch.cat([run(e, c[:, :half], c[:, half : 2 * half], c[:, 2 * half :]) for c in chunks]).double()
            outputs.append(y[0].float())
            jac.append(self._fd_quotients(y).T)  # (D, P)
        jac = torch.stack(jac)
        return torch.stack(outputs), jac[:, :, : 2 * half].contiguous(), jac[:, :, 2 * half :].contiguous()

    def step_jacobians(self, engine: torch.Tensor, control: torch.Tensor):
        """:meth:`fd_jacobians`' triple from this adapter's gradient mode: finite differences, or the
        adjoint's (:meth:`adjoint_jacobians`)."""
        if self.gradients == "adjoint":
            return self.adjoint_jacobians(engine, control)
        return self.fd_jacobians(engine, control)

    def applied_force(self, control: torch.Tensor, qpos: torch.Tensor, qvel: torch.Tensor) -> torch.Tensor:
        """The generalized applied force (N, nv) of ``control`` on a substep's state: the hinge torques,
        or the PD law of position targets (zero on a free root), as :meth:`_run_worlds` applies it."""
        layout = self.layout
        root = layout.nv - layout.num_dofs
        torque = control
        if self.position_control:
            torque = self.task.physics.pd_torque(control, qpos[:, layout.nq - layout.num_dofs :], qvel[:, root:])
        return torch.cat((torque.new_zeros(torque.shape[0], root), torque), dim=1)

    def adjoint_step(self, engine: torch.Tensor, control: torch.Tensor):
        """Forward step of N worlds recording what the adjoint replays: (next engine (N, D), records)."""
        qpos, qvel = self._split(engine.detach())
        records: list = []
        next_engine = self._run_worlds(qpos.float(), qvel.float(), control.detach().float(), records=records)
        return next_engine, records

    def adjoint_jacobians(self, engine: torch.Tensor, control: torch.Tensor):
        """The adjoint's Jacobians in :meth:`fd_jacobians`' form (tangent state columns, ambient rows):
        one vector-Jacobian product per output row, all rows of all envs in one batch."""
        n, width = engine.shape
        next_engine, records = self.adjoint_step(engine, control)
        rows = [tuple(t.repeat(width, 1) for t in record) for record in records]  # row-major: k * n + e
        basis = torch.eye(width, dtype=torch.float64).repeat_interleave(n, dim=0)
        nq = self.layout.nq
        g_qpos, g_qvel, g_control = control_step_vjp(
            self.tree, rows, control.repeat(width, 1), self.applied_force, basis[:, :nq], basis[:, nq:]
        )
        g_qpos = self.ambient_to_tangent_grad(engine.repeat(width, 1), g_qpos)
        jac_state = torch.cat((g_qpos, g_qvel), dim=1).reshape(width, n, -1).transpose(0, 1)
        return next_engine, jac_state.contiguous(), g_control.reshape(width, n, -1).transpose(0, 1).contiguous()

    def ambient_to_tangent_grad(self, engine: torch.Tensor, grad_qpos: torch.Tensor) -> torch.Tensor:
        """Gradient w.r.t. the tangent position coordinates (N, nv) from the one w.r.t. ``qpos`` (N, nq):
        the root rotation's ``d/d delta_k = dL/dq . (q * (0, e_k)) / 2`` (``q' = q * exp(delta / 2)``)."""
        if not self.layout.floating_base:
            return grad_qpos
        quat = engine[:, 3:7].to(grad_qpos.dtype)
        w, v = quat[:, :1], quat[:, 1:]
        g_w, g_v = grad_qpos[:, 3:4], grad_qpos[:, 4:7]
        # q * (0, e) = (-v . e, w e + v x e); its dot with (g_w, g_v) is e . (-g_w v + w g_v + g_v x v)
        g_rot = 0.5 * (-g_w * v + w * g_v + torch.linalg.cross(g_v, v, dim=1))
        return torch.cat((grad_qpos[:, :3], g_rot, grad_qpos[:, _ROOT_Q:]), dim=1)

    def fd_jacobians(
        self, engine: torch.Tensor, control: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Next engine state and its finite-difference Jacobians (``fd_scheme``), for every env.

        Returns ``next_engine`` (N, D) float32, ``jac_state`` (N, D, 2 nv) and ``jac_control``
        (N, D, J), both float64: derivatives of the ambient next state w.r.t. the tangent state
        (see the module docstring for the rotation's convention) and the torques.
        """
        engine = engine.detach().to(self.device, torch.float64)
        control = control.detach().to(self.device, torch.float64)
        if self.soft:
            return self._soft_fd_jacobians(engine, control)
        deltas = self._fd_deltas()
        outputs, jac = [], []
        for start in range(0, engine.shape[0], self.fd_chunk_envs):
            e = engine[start : start + self.fd_chunk_envs]
            u = control[start : start + self.fd_chunk_envs]
            if self.fd_scheme == "adaptive":
                y0, quotients = self._adaptive_jacobians(e, u)
                outputs.append(y0.float())
                jac.append(quotients.permute(1, 2, 0))
                continue
            qpos, qvel, torque = self._retract(e, u, deltas)  # (K * n, .) worlds, perturbation-major
            y = self._run_worlds(qpos.float(), qvel.float(), torque.float(), blocks=deltas.shape[0]).double()
            y = y.reshape(deltas.shape[0], e.shape[0], -1)
            outputs.append(y[0].float())
            jac.append(self._fd_quotients(y).permute(1, 2, 0))  # (n, D, P)
        jac = torch.cat(jac)
        nt = 2 * self.layout.nv
        return torch.cat(outputs), jac[:, :, :nt].contiguous(), jac[:, :, nt:].contiguous()

    def _adaptive_jacobians(self, engine: torch.Tensor, control: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``adaptive``: the nominal and +eps worlds of every coordinate in one batch, recording each
        substep's constraint set; forward quotients wherever a +eps world kept the nominal's set at every
        substep. Where it did not (a switch inside the forward stencil), the -eps world of that env and
        coordinate runs in a second batch: its backward quotient where it kept the nominal's set, else
        the smaller of the two quotients (``one_sided``'s choice). Returns the nominal next state (n, D)
        and the quotients (P, n, D), float64."""
        deltas = self._fd_deltas()  # nominal, then +eps e_i
        blocks, n, steps = deltas.shape[0], engine.shape[0], self._fd_steps
        qpos, qvel, torque = self._retract(engine, control, deltas)
        marks: list[torch.Tensor] = []
        y = self._run_worlds(qpos.float(), qvel.float(), torque.float(), blocks=blocks, signatures=marks).double()
        y = y.reshape(blocks, n, -1)
        marks_nominal = torch.stack(marks).reshape(len(marks), blocks, n, 2)  # (substeps, K, n, 2)
        switched = (marks_nominal[:, 1:] != marks_nominal[:, :1]).any(dim=-1).any(dim=0)  # (P, n)
        ahead = (y[1:] - y[:1]) / steps[:, None, None]
        coord, env = switched.nonzero(as_tuple=True)
        self.second_side_share = float(coord.numel()) / float(switched.numel())
        if not coord.numel():
            return y[0], ahead
        minus, kept = self._second_side(engine, control, coord, env, marks_nominal[:, 0])
        behind = (y[0, env] - minus) / steps[coord, None]
        forward = ahead[coord, env]
        smaller = torch.where(
            (forward.norm(dim=-1) <= behind.norm(dim=-1))[:, None], forward, behind
        )  # both sides switched: the smaller quotient, the side that crossed less
        ahead[coord, env] = torch.where(kept[:, None], behind, smaller)
        return y[0], ahead

    def _second_side(self, engine, control, coord, env, nominal_marks):
        """The -eps worlds of the (coordinate, env) pairs ``coord``, ``env`` in one batch, padded to a
        bucket size so that few batch sizes (and captured graphs) exist: their next states (M, D) and
        whether each kept the nominal world's constraint set at every substep (M,)."""
        steps, count = self._fd_steps, coord.numel()
        size = _bucket(count)
        self._hold_second_size(size, keep=engine.shape[0] * (1 + steps.numel()))
        pick = torch.cat((env, env.new_zeros(size - count)))  # padding: copies of env 0, ignored
        deltas = torch.zeros(size, steps.numel(), dtype=steps.dtype, device=steps.device)
        deltas[torch.arange(count), coord] = -steps[coord]
        qpos, qvel, torque = self._retract(engine[pick], control[pick], deltas[None])
        marks: list[torch.Tensor] = []
        y = self._run_worlds(qpos.float(), qvel.float(), torque.float(), signatures=marks).double()[:count]
        own = torch.stack(marks)[:, :count]  # (substeps, M, 2)
        kept = (own == nominal_marks[:, env]).all(dim=-1).all(dim=0)
        return y, kept

    def _hold_second_size(self, size: int, keep: int, most: int = 4) -> None:
        """Keep the ``Data`` of the ``most`` second-batch sizes used last; free the others (each size a
        training run meets would otherwise stay allocated), never the first batch's (``keep`` worlds)
        or a forward step's."""
        if size in self._second_sizes:
            self._second_sizes.remove(size)
        self._second_sizes.append(size)
        while len(self._second_sizes) > most:
            old = self._second_sizes.pop(0)
            if old in (keep, self.num_envs) or old not in self._data:
                continue
            self.stepper.forget(self._data.pop(old)[0])
            self._signatures.pop(old, None)

    def _retract(self, engine: torch.Tensor, control: torch.Tensor, deltas: torch.Tensor):
        """Inputs of ``K x n`` worlds: every env's state and torque moved by each tangent vector in ``deltas``:
        (K, P), the same K vectors for every env, or (K, n, P), one set per env.

        Positions, hinges, velocities and torques move additively; the root quaternion by a
        body-frame rotation, ``q * exp(delta_rot / 2)``.
        """
        layout = self.layout
        qpos, qvel = self._split(engine)
        d = deltas if deltas.dim() == 3 else deltas[:, None, :]  # (K, 1 or n, P) against (1, n, .) nominal
        nv = layout.nv
        vel = qvel[None] + d[..., nv : 2 * nv]
        torque = control[None] + d[..., 2 * nv :]
        worlds = (deltas.shape[0], engine.shape[0])

        def flat(*parts: torch.Tensor) -> torch.Tensor:  # (K, n, .) pieces -> (K * n, widths), perturbation-major
            return torch.cat([p.expand(*worlds, p.shape[-1]) for p in parts], dim=-1).flatten(0, 1)

        if not layout.floating_base:  # hinges only: every coordinate moves additively
            return flat(qpos[None] + d[..., :nv]), flat(vel), flat(torque)
        pos = qpos[None, :, 0:3] + d[..., 0:3]
        turn = quat_from_rotation_vector(d[..., 3:6])  # body-frame rotation: q' = q * exp(delta / 2)
        quat = xyzw_to_wxyz(quat_mul(wxyz_to_xyzw(qpos[None, :, 3:7]), turn))
        hinges = qpos[None, :, _ROOT_Q:] + d[..., _ROOT_V:nv]
        return flat(pos, quat, hinges), flat(vel), flat(torque)

    def tangent_to_ambient_grad(self, engine: torch.Tensor, grad_tangent: torch.Tensor) -> torch.Tensor:
        """Gradient w.r.t. the engine state (N, D) from the gradient w.r.t. its tangent coordinates (N, 2 nv).

        Identity except for the root rotation: ``dL/dq = (2 / |q|) E(conj(q^))^T dL/d delta``
        (module docstring); orthogonal to ``q`` because the step ignores ``|q|``.
        """
        if not self.layout.floating_base:
            return grad_tangent
        quat = engine[:, 3:7].to(grad_tangent.dtype)
        norm = quat.norm(dim=1, keepdim=True)
        w, v = quat[:, :1] / norm, quat[:, 1:] / norm
        g_rot = grad_tangent[:, 3:6]
        g_w = -(v * g_rot).sum(dim=1, keepdim=True)
        g_v = w * g_rot + torch.linalg.cross(v, g_rot, dim=1)
        g_quat = 2.0 / norm * torch.cat((g_w, g_v), dim=1)
        return torch.cat((grad_tangent[:, 0:3], g_quat, grad_tangent[:, _ROOT_V:]), dim=1)

    # -- engine <-> backend-neutral coordinates ---------------------------------------------
    def _state_from_engine(self, engine: torch.Tensor) -> SimState:
        if self.soft:  # qpos: displacements from each env's rest shape; particle views in torch
            n, half = engine.shape[0], engine.shape[1] // 2
            empty = engine.new_zeros(n, 0)
            particle_q = self.soft_models.rest + engine[:, :half].reshape(n, -1, 3)
            return SimState(empty, empty.clone(), engine, particle_q, engine[:, half:].reshape(n, -1, 3))
        if not self.layout.floating_base:
            return SimState(joint_q=engine[:, : self.layout.nq], joint_qd=engine[:, self.layout.nq :], engine=engine)
        joint_q, joint_qd = engine_to_generalized(engine, self._com_offset)
        return SimState(joint_q=joint_q, joint_qd=joint_qd, engine=engine)

    def state_from_generalized(self, joint_q, joint_qd, particle_q=None, particle_qd=None) -> SimState:
        """The engine state of generalized coordinates (root quaternion normalised); differentiable."""
        if self.soft:
            n = self.num_envs
            displacement = particle_q.to(self.device, torch.float32) - self.soft_models.rest
            velocity = particle_qd.to(self.device, torch.float32)
            return self._state_from_engine(torch.cat((displacement.reshape(n, -1), velocity.reshape(n, -1)), dim=1))
        if particle_q is not None or particle_qd is not None:
            raise BackendError("particles are not supported by the mujoco_warp adapter")
        joint_q = joint_q.to(self.device, torch.float32)
        joint_qd = joint_qd.to(self.device, torch.float32)
        if not self.layout.floating_base:
            return self._state_from_engine(torch.cat((joint_q, joint_qd), dim=1))
        return self._state_from_engine(generalized_to_engine(joint_q, joint_qd, self._com_offset))


def engine_to_generalized(engine: torch.Tensor, com_offset: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Neutral ``joint_q``, ``joint_qd`` from MuJoCo's (qpos, qvel) rows of a free-root model, in torch.

    ``com_offset`` (3,) is the root body's centre of mass in its own frame (``body_ipos``).
    """
    nv = (engine.shape[1] - 1) // 2  # D = nq + nv, and nq = nv + 1 with a free root
    qpos, qvel = engine[:, :-nv], engine[:, -nv:]
    quat = wxyz_to_xyzw(qpos[:, 3:7])
    ang_world = quat_rotate(quat, qvel[:, 3:6])
    com_arm = quat_rotate(quat, com_offset.to(engine).expand(engine.shape[0], 3))
    lin_com = qvel[:, 0:3] + torch.linalg.cross(ang_world, com_arm, dim=1)
    joint_q = torch.cat((qpos[:, 0:3], quat, qpos[:, _ROOT_Q:]), dim=1)
    joint_qd = torch.cat((lin_com, ang_world, qvel[:, _ROOT_V:]), dim=1)
    return joint_q, joint_qd


def generalized_to_engine(joint_q: torch.Tensor, joint_qd: torch.Tensor, com_offset: torch.Tensor) -> torch.Tensor:
    """The inverse of :func:`engine_to_generalized`; the root quaternion is normalised on the way."""
    quat = torch.nn.functional.normalize(joint_q[:, 3:7], dim=1)  # x, y, z, w
    ang_world = joint_qd[:, 3:6]
    ang_body = quat_rotate(quat_conjugate(quat), ang_world)
    com_arm = quat_rotate(quat, com_offset.to(joint_q).expand(joint_q.shape[0], 3))
    lin_origin = joint_qd[:, 0:3] - torch.linalg.cross(ang_world, com_arm, dim=1)
    qpos = torch.cat((joint_q[:, 0:3], xyzw_to_wxyz(quat), joint_q[:, _ROOT_Q:]), dim=1)
    qvel = torch.cat((lin_origin, ang_body, joint_qd[:, _ROOT_V:]), dim=1)
    return torch.cat((qpos, qvel), dim=1)


def _bucket(count: int) -> int:
    """The batch size that holds ``count`` worlds: the next of 8, 12, 16, 24, 32, 48, ... (2^k and
    1.5 x 2^k), so the padding is under a third and a training run meets a few dozen sizes at most."""
    size = 8
    while size < count:
        size = size * 3 // 2 if size & (size - 1) == 0 else size * 4 // 3
    return size


class _MujocoWarpStep(torch.autograd.Function):
    """(engine state, torques) -> next engine state; backward is the finite-difference Jacobians' VJP."""

    @staticmethod
    def forward(ctx, sim: MujocoWarpSim, engine: torch.Tensor, control: torch.Tensor):
        next_engine, jac_state, jac_control = sim.fd_jacobians(engine, control)
        ctx.sim = sim
        ctx.save_for_backward(engine.detach(), jac_state, jac_control)
        return next_engine

    @staticmethod
    def backward(ctx, grad_next):
        engine, jac_state, jac_control = ctx.saved_tensors
        g = grad_next.to(torch.float64).unsqueeze(1)  # (N, 1, D)
        grad_tangent = (g @ jac_state).squeeze(1)
        grad_control = (g @ jac_control).squeeze(1)
        grad_engine = ctx.sim.tangent_to_ambient_grad(engine, grad_tangent)
        return None, grad_engine.to(grad_next.dtype), grad_control.to(grad_next.dtype)


class _AdjointStep(torch.autograd.Function):
    """(engine state, control) -> next engine state; backward replays the substeps' adjoint (:mod:`.adjoint.step`)."""

    @staticmethod
    def forward(ctx, sim: MujocoWarpSim, engine: torch.Tensor, control: torch.Tensor):
        next_engine, records = sim.adjoint_step(engine, control)
        ctx.sim, ctx.records = sim, records
        ctx.save_for_backward(control.detach())
        return next_engine

    @staticmethod
    def backward(ctx, grad_next):
        (control,) = ctx.saved_tensors
        sim, nq = ctx.sim, ctx.sim.layout.nq
        g = grad_next.to(torch.float64)
        g_qpos, g_qvel, g_control = control_step_vjp(
            sim.tree, ctx.records, control, sim.applied_force, g[:, :nq].contiguous(), g[:, nq:].contiguous()
        )
        grad_engine = torch.cat((g_qpos, g_qvel), dim=1)
        return None, grad_engine.to(grad_next.dtype), g_control.to(grad_next.dtype)


__all__ = ["MujocoWarpSim", "build_spec", "engine_to_generalized", "generalized_to_engine"]
