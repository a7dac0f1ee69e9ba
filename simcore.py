"""The backend-neutral vocabulary that tasks and adapters share, and nothing else.

``tasks/`` (what the learning problem is) and ``backends/`` (how an engine simulates it) both
import this module and never each other: the state layout (:class:`SimState`,
:class:`StateLayout`), how controls drive an engine (:class:`ControlKind`), the physical
constants every adapter must honour (:class:`PhysicsSpec`, including the PD law of
``JOINT_POSITION_TARGET``), what an adapter may read of a task (:class:`TaskSpec`), quaternion
helpers, and the entry-point registry both packages use to find plug-ins by name.

State layout (z up, quaternions ``(x, y, z, w)``, everything in the world frame):

* ``joint_q``  (N, nq): ``[root_pos(3), root_quat(4), dof_q(J)]`` for a floating base, else ``dof_q``.
* ``joint_qd`` (N, nv): ``[root_lin_vel(3), root_ang_vel(3), dof_qd(J)]``; the linear velocity is
  that of the root body's centre of mass, the angular velocity is in the world frame.
* ``particle_q``, ``particle_qd`` (N, P, 3): particles of soft bodies (``None`` without any).
* ``engine`` (N, D): the adapter's own full state (maximal coordinates, solver extras), the only
  thing an adapter's ``simulate`` reads. The other fields are views of it, kept consistent by the adapter.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path
from typing import Protocol

import torch


class ControlKind(enum.Enum):
    """How a task's control tensor drives the engine."""

    JOINT_TORQUE = "joint_torque"  # (N, J) generalized forces on the actuated dofs
    JOINT_POSITION_TARGET = "joint_position_target"  # (N, J) PD targets, gains in the task's physics spec
    TET_ACTIVATION = "tet_activation"  # (N, T) per-tetrahedron muscle activation of a soft body


@dataclass(frozen=True)
class StateLayout:
    """Static sizes of the backend-neutral state for one env."""

    num_dofs: int  # actuated/articulated degrees of freedom after the root (J)
    floating_base: bool = True
    num_particles: int = 0
    num_tets: int = 0

    @property
    def nq(self) -> int:
        return (7 if self.floating_base else 0) + self.num_dofs

    @property
    def nv(self) -> int:
        return (6 if self.floating_base else 0) + self.num_dofs


def nonfinite_rows(tensor: torch.Tensor) -> list[int]:
    """Rows (first index) of ``tensor`` that hold a NaN or inf, ascending; [] when all are finite.

    A finite sum proves every entry finite (a NaN makes the sum NaN, an inf makes it inf or NaN), so
    the common case costs one reduction: the row-by-row ``isfinite`` check costs about five times as
    many torch calls, and the contract checks three tensors every step. Only a non-finite sum (a bad
    entry, or finite entries large enough to overflow it) runs the exact row-by-row check."""
    values = tensor.detach()
    if math.isfinite(float(values.sum())):
        return []
    return (~torch.isfinite(values).reshape(values.shape[0], -1).all(dim=1)).nonzero().flatten().tolist()


@dataclass
class SimState:
    """Batched backend-neutral state; see the module docstring for the layout."""

    joint_q: torch.Tensor
    joint_qd: torch.Tensor
    engine: torch.Tensor
    particle_q: torch.Tensor | None = None
    particle_qd: torch.Tensor | None = None

    # -- views of a floating base ---------------------------------------------------------
    @property
    def root_pos(self) -> torch.Tensor:
        return self.joint_q[:, 0:3]

    @property
    def root_quat(self) -> torch.Tensor:
        return self.joint_q[:, 3:7]

    @property
    def root_lin_vel(self) -> torch.Tensor:
        return self.joint_qd[:, 0:3]

    @property
    def root_ang_vel(self) -> torch.Tensor:
        return self.joint_qd[:, 3:6]

    def dof_q(self, layout: StateLayout) -> torch.Tensor:
        return self.joint_q[:, layout.nq - layout.num_dofs :]

    def dof_qd(self, layout: StateLayout) -> torch.Tensor:
        return self.joint_qd[:, layout.nv - layout.num_dofs :]

    # -- whole-state helpers --------------------------------------------------------------
    def tensors(self) -> dict[str, torch.Tensor]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if getattr(self, f.name) is not None}

    def map(self, fn) -> SimState:
        """Apply ``fn`` to every tensor field."""
        return SimState(**{k: fn(v) for k, v in self.tensors().items()})

    def detach(self) -> SimState:
        return self.map(torch.Tensor.detach)

    def select(self, env_mask: torch.Tensor, other: SimState) -> SimState:
        """Rows of ``other`` where ``env_mask`` is true, rows of ``self`` elsewhere."""
        mine = self.tensors()
        theirs = other.tensors()
        out = {}
        for name, value in mine.items():
            mask = env_mask.reshape((-1,) + (1,) * (value.dim() - 1))
            out[name] = torch.where(mask, theirs[name], value)
        return SimState(**out)

    def nonfinite_envs(self) -> list[int]:
        """The envs whose state holds a NaN or inf in any tensor, ascending ([] for a finite state):
        the per-step check of :meth:`BatchedSim.advance` (one sum per tensor in the common case,
        :func:`nonfinite_rows`)."""
        return sorted(set().union(*(nonfinite_rows(value) for value in self.tensors().values())))


@dataclass(frozen=True)
class PhysicsSpec:
    """Engine-neutral physical constants of a task; every adapter applies each of them or refuses the
    spec (``BatchedSim.physics_mapping`` says how; ``tests/test_physics_mapping.py`` checks it).

    ``JOINT_POSITION_TARGET`` control follows one PD law, evaluated by every adapter at every
    substep (:meth:`pd_torque` is its reference): tau = clip(kp (q* - q) - kd qd, -limit, limit).
    """

    frame_dt: float = 1.0 / 60.0  # one control step
    substeps: int = 16  # integrator steps per control step
    gravity: float = -9.81  # along z
    ground_plane: bool = True  # a z-up plane through the origin
    contact_ke: float = 4.0e4  # penalty contact: normal stiffness
    contact_kd: float = 1.0e3  # normal damping (1e4 makes the adjoint blow up: docs/newton.md)
    contact_kf: float = 3.0e2  # tangential (friction) slope; 3e3 makes policy-driven adjoints explode (docs/newton.md)
    contact_mu: float = 0.75  # Coulomb friction coefficient
    joint_limit_ke: float = 1.0e3
    joint_limit_kd: float = 1.0e1
    joint_damping: float = 1.0  # passive viscous damping on articulated dofs
    armature: float | None = None  # rotor inertia reflected onto each articulated dof (kg m^2); None: the asset's
    pd_kp: float = 0.0  # JOINT_POSITION_TARGET: stiffness (N m / rad)
    pd_kd: float = 0.0  # JOINT_POSITION_TARGET: damping (N m s / rad)
    torque_limits: tuple[float, ...] = ()  # JOINT_POSITION_TARGET: |tau_j| <= limit_j (N m); () = none

    def __post_init__(self) -> None:
        if isinstance(self.substeps, bool) or not isinstance(self.substeps, int) or self.substeps < 1:
            raise ValueError(f"PhysicsSpec.substeps must be an integer >= 1, got {self.substeps!r}")

        def number(value) -> bool:  # a bool is an int to Python, never a physical constant here
            return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)

        if not number(self.frame_dt) or self.frame_dt <= 0:
            raise ValueError(f"PhysicsSpec.frame_dt must be a finite number > 0, got {self.frame_dt!r}")
        if not isinstance(self.ground_plane, bool):
            raise ValueError(f"PhysicsSpec.ground_plane must be True or False, got {self.ground_plane!r}")
        for name in ("contact_ke", "contact_kd", "contact_kf", "contact_mu", "joint_limit_ke", "joint_limit_kd"):
            value = getattr(self, name)
            if not (number(value) and value >= 0):
                raise ValueError(f"PhysicsSpec.{name} must be a finite number >= 0, got {value!r}")
        for name in ("joint_damping", "pd_kp", "pd_kd", "gravity"):
            value = getattr(self, name)
            if not number(value):
                raise ValueError(f"PhysicsSpec.{name} must be a finite number, got {value!r}")
        if self.armature is not None and not (number(self.armature) and self.armature >= 0):
            raise ValueError(f"PhysicsSpec.armature must be None or a finite number >= 0, got {self.armature!r}")
        if not isinstance(self.torque_limits, tuple | list) or any(
            not (number(limit) and limit > 0) for limit in self.torque_limits
        ):
            raise ValueError(f"PhysicsSpec.torque_limits must be positive and finite, got {self.torque_limits}")

    @property
    def sim_dt(self) -> float:
        return self.frame_dt / self.substeps

    def pd_torque(self, target: torch.Tensor, dof_q: torch.Tensor, dof_qd: torch.Tensor) -> torch.Tensor:
        """The PD law of ``JOINT_POSITION_TARGET``: clip(kp (q* - q) - kd qd) per joint, (N, J)."""
        tau = self.pd_kp * (target - dof_q) - self.pd_kd * dof_qd
        if not self.torque_limits:
            return tau
        if len(self.torque_limits) != tau.shape[-1]:
            raise ValueError(f"{len(self.torque_limits)} torque limits for {tau.shape[-1]} joints")
        limit = torch.tensor(self.torque_limits, dtype=tau.dtype, device=tau.device)
        return torch.maximum(torch.minimum(tau, limit), -limit)


@dataclass(frozen=True, eq=False)
class SoftBodySpec:
    """A tetrahedral Neo-Hookean body driven by per-tetrahedron activations (``TET_ACTIVATION``).

    ``vertices`` (P, 3) and ``tets`` (T, 4) are the rest mesh at scale 1 (positive tet volumes);
    env ``e`` simulates that mesh scaled by ``rest_scales(N)[e]`` (rest shape, masses and all), a
    fixed spread of body sizes over the envs that every adapter and the task agree on. Material in
    SI units: Lame parameters ``k_mu``, ``k_lambda`` (Pa), viscous ``k_damp`` (Pa s), ``density``
    (kg/m^3); every tet gives a quarter of its mass to each of its vertices. Ground contact uses the
    task's :class:`PhysicsSpec` contact constants with particles of radius ``particle_radius``.

    Activation ``a`` of a tet enters the volumetric term of the energy as Newton's FEM does: the
    volume force is ``k_lambda * V * (J - alpha + a) * dJ/dx`` (J = det F), so ``a > 0`` pulls the
    tet's vertices inwards as if it were larger than it is (:func:`activation_nodal_forces`).
    """

    vertices: torch.Tensor  # (P, 3) float64, rest positions at scale 1
    tets: torch.Tensor  # (T, 4) int64
    k_mu: float
    k_lambda: float
    k_damp: float
    density: float
    particle_radius: float = 0.0
    scale_spread: float = 0.0  # env scales are 1 + scale_spread * U(-1, 1)
    scale_seed: int = 0  # the fixed draw of env scales

    def __post_init__(self) -> None:
        check_tet_mesh(self.vertices, self.tets)
        for name in ("k_mu", "k_lambda", "density"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"SoftBodySpec.{name} must be a finite number > 0, got {value!r}")
        for name in ("k_damp", "particle_radius", "scale_spread"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"SoftBodySpec.{name} must be a finite number >= 0, got {value!r}")
        if self.scale_spread >= 1:
            raise ValueError(f"SoftBodySpec.scale_spread must be < 1 (scales stay positive), got {self.scale_spread}")

    @property
    def num_particles(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_tets(self) -> int:
        return int(self.tets.shape[0])

    def rest_scales(self, num_envs: int) -> torch.Tensor:
        """(N,) float64 scale of each env's body: the same for a given ``num_envs`` everywhere."""
        gen = torch.Generator().manual_seed(self.scale_seed)
        u = 2.0 * torch.rand(num_envs, generator=gen, dtype=torch.float64) - 1.0
        return 1.0 + self.scale_spread * u

    def tet_volumes(self) -> torch.Tensor:
        """(T,) rest volumes at scale 1."""
        return signed_tet_volumes(self.vertices, self.tets)

    def particle_masses(self) -> torch.Tensor:
        """(P,) float64 masses at scale 1 (a quarter of every incident tet's mass)."""
        share = (self.density * self.tet_volumes() / 4.0).unsqueeze(1).expand(-1, 4)
        masses = torch.zeros(self.num_particles, dtype=torch.float64)
        return masses.index_add_(0, self.tets.reshape(-1), share.reshape(-1))


class TetMeshError(ValueError):
    """A tetrahedral mesh an FEM engine would misread (no tets, degenerate or inverted ones, bad indices)."""


def signed_tet_volumes(vertices: torch.Tensor, tets: torch.Tensor) -> torch.Tensor:
    """Signed volume (T,) of every tetrahedron: det([x1 - x0, x2 - x0, x3 - x0]) / 6."""
    x = vertices.double()[tets]
    return torch.linalg.det(x[:, 1:] - x[:, :1]) / 6.0


def check_tet_mesh(vertices: torch.Tensor, tets: torch.Tensor, min_volume: float = 1e-12) -> None:
    """Refuse a mesh an FEM engine would misread, with one line saying what is wrong."""
    vertices, tets = torch.as_tensor(vertices), torch.as_tensor(tets)
    if vertices.dim() != 2 or vertices.shape[1] != 3 or vertices.shape[0] == 0:
        raise TetMeshError(f"vertices must have shape (P, 3) with P >= 1, got {tuple(vertices.shape)}")
    if not vertices.is_floating_point() or not bool(torch.isfinite(vertices).all()):
        raise TetMeshError("vertices must be finite floating-point numbers")
    if tets.dim() != 2 or tets.shape[1] != 4:
        raise TetMeshError(f"tetrahedra must have shape (T, 4), got {tuple(tets.shape)}")
    if tets.shape[0] == 0:
        raise TetMeshError("the mesh has no tetrahedra")
    if tets.is_floating_point() or tets.is_complex() or tets.dtype == torch.bool:
        raise TetMeshError(f"tetrahedron indices must be integers, got {tets.dtype}")
    low, high = int(tets.min()), int(tets.max())
    if low < 0 or high >= vertices.shape[0]:
        raise TetMeshError(f"tetrahedron indices must lie in [0, {vertices.shape[0]}), got {low}..{high}")
    volumes = signed_tet_volumes(vertices, tets.long())
    bad = (volumes <= min_volume).nonzero().flatten()
    if bad.numel():
        first = int(bad[0])
        kind = "inverted" if float(volumes[first]) < -min_volume else "zero-volume"
        raise TetMeshError(
            f"{bad.numel()} tetrahedra are inverted or zero-volume (first: tet {first}, {kind}, "
            f"volume {float(volumes[first]):.3g}); every tet needs positive volume"
        )


def activation_nodal_forces(
    particle_q: torch.Tensor, tets: torch.Tensor, activation: torch.Tensor, k_lambda: float
) -> torch.Tensor:
    """Forces (N, P, 3) on the particles from the activation term of :class:`SoftBodySpec`.

    The activation part of the volume force of tet ``t`` is ``-a_t * k_lambda * V_t * dJ/dx_i`` on
    vertex ``i``; with ``J = det(D_s) / det(D_m)`` and ``V_t det(D_m)^-1 = 1/6`` it needs no rest
    data: vertex 1 gets ``-a k_lambda (x2 - x0) x (x3 - x0) / 6`` (2 and 3 likewise by cyclic
    order), vertex 0 minus their sum. ``particle_q`` (N, P, 3), ``tets`` (T, 4), ``activation`` (N, T).
    """
    x = particle_q[:, tets]  # (N, T, 4, 3)
    e1, e2, e3 = (x[:, :, i] - x[:, :, 0] for i in (1, 2, 3))
    scale = (-activation * k_lambda / 6.0).unsqueeze(-1)
    f1 = scale * torch.linalg.cross(e2, e3, dim=-1)
    f2 = scale * torch.linalg.cross(e3, e1, dim=-1)
    f3 = scale * torch.linalg.cross(e1, e2, dim=-1)
    per_vertex = torch.stack((-(f1 + f2 + f3), f1, f2, f3), dim=2)  # (N, T, 4, 3)
    forces = torch.zeros_like(particle_q)
    index = tets.reshape(-1).to(particle_q.device)
    return forces.index_add(1, index, per_vertex.reshape(particle_q.shape[0], -1, 3))


class TaskSpec(Protocol):
    """What an adapter may read of a task (``tasks.base.Task`` provides it): data, no observations."""

    name: str
    asset_path: Path
    asset_format: str  # "mjcf" | "urdf" | "tetmesh" | anything an adapter of its own understands
    layout: StateLayout
    control_kind: ControlKind
    action_dim: int
    physics: PhysicsSpec
    #: per-adapter settings the task was validated with, e.g. ``{"newton": {"solver": "featherstone"}}``;
    #: an adapter reads its own entry, and options passed to it explicitly override them
    backend_options: Mapping[str, Mapping[str, object]]
    #: ``TET_ACTIVATION`` tasks: the soft body (mesh, material, env scales); ``None`` otherwise
    soft_body: SoftBodySpec | None

    def sample_initial_state(self, num_envs: int, generator: torch.Generator) -> tuple[torch.Tensor, ...]:
        """Randomised initial coordinates: ``joint_q`` (N, nq), ``joint_qd`` (N, nv), and for tasks with
        particles also ``particle_q``, ``particle_qd`` (N, P, 3): the arguments of
        ``state_from_generalized``."""
        ...

    def actions_to_control(self, actions: torch.Tensor) -> torch.Tensor:
        """Map policy actions (N, action_dim) to the control tensor of ``control_kind``."""
        ...


class PluginRegistry:
    """Classes found by name through an entry-point group, loaded lazily, checked against a base class.

    Built-in and third-party plug-ins are found the same way: a package declares
    ``[project.entry-points."GROUP"] name = "module:Class"``. Classes registered in-process with
    :meth:`register` (tests, notebooks) shadow entry points of the same name.
    """

    def __init__(self, group: str, base: type, kind: str):
        self.group, self.base, self.kind = group, base, kind
        self._runtime: dict[str, type] = {}
        self._installed: dict | None = None

    def _entry_points(self) -> dict:
        # read once per process: scanning every installed distribution's metadata costs ~20 ms, and a
        # suite plan looks names up thousands of times (a package installed later needs a new process)
        if self._installed is None:
            self._installed = {ep.name: ep for ep in entry_points(group=self.group)}
        return self._installed

    def available(self) -> list[str]:
        """Every registered name, sorted (nothing is imported)."""
        return sorted(set(self._entry_points()) | set(self._runtime))

    def register(self, name: str, cls: type) -> None:
        self._check(name, cls)
        self._runtime[name] = cls

    def get(self, name: str) -> type:
        if name in self._runtime:
            return self._runtime[name]
        eps = self._entry_points()
        if name not in eps:
            raise UnknownNameError(self.kind, name, self.available())
        cls = eps[name].load()
        self._check(name, cls)
        return cls

    def _check(self, name: str, cls) -> None:
        if not (isinstance(cls, type) and issubclass(cls, self.base)):
            raise TypeError(f"{self.kind} {name!r} -> {cls!r} is not a {self.base.__name__} subclass")


class UnknownNameError(KeyError):
    """A backend or task name nobody registered; the message lists the valid ones."""

    def __init__(self, kind: str, name: str, choices: list[str]):
        self.kind, self.name, self.choices = kind, name, choices
        super().__init__(name)

    def __str__(self) -> str:
        return f"unknown {self.kind} {self.name!r}; choose from: {', '.join(self.choices) or '(none registered)'}"


# -- quaternions, stored as (x, y, z, w) -------------------------------------------------------


def quat_rotate(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4)."""
    xyz, w = q[..., :3], q[..., 3:4]
    t = 2.0 * torch.linalg.cross(xyz, v, dim=-1)
    return v + w * t + torch.linalg.cross(xyz, t, dim=-1)


def up_z(q: torch.Tensor) -> torch.Tensor:
    """z component (...,) of the body z axis of orientations ``q`` (..., 4): 1 upright, 0 on its side."""
    z = torch.zeros(q.shape[:-1] + (3,), dtype=q.dtype, device=q.device)
    z[..., 2] = 1.0
    return quat_rotate(q, z)[..., 2]


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``)."""
    ax, ay, az, aw = a.unbind(-1)
    bx, by, bz, bw = b.unbind(-1)
    return torch.stack(
        (
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ),
        dim=-1,
    )


def quat_from_angle_axis(angle: torch.Tensor, axis: torch.Tensor) -> torch.Tensor:
    """Quaternions for rotations by ``angle`` (...,) about unit ``axis`` (..., 3)."""
    half = 0.5 * angle.unsqueeze(-1)
    return torch.cat((axis * torch.sin(half), torch.cos(half)), dim=-1)


def quat_conjugate(q: torch.Tensor) -> torch.Tensor:
    """Inverse of unit quaternions ``q`` (..., 4)."""
    return torch.cat((-q[..., :3], q[..., 3:]), dim=-1)


def quat_from_rotation_vector(rotvec: torch.Tensor) -> torch.Tensor:
    """Unit quaternions for rotation vectors (..., 3) (axis * angle); zero maps to the identity."""
    angle = rotvec.norm(dim=-1)
    axis = rotvec / angle.clamp_min(1e-30).unsqueeze(-1)
    return quat_from_angle_axis(angle, axis)


def xyzw_to_wxyz(q: torch.Tensor) -> torch.Tensor:
    return torch.cat((q[..., 3:], q[..., :3]), dim=-1)


def wxyz_to_xyzw(q: torch.Tensor) -> torch.Tensor:
    return torch.cat((q[..., 1:], q[..., :1]), dim=-1)
