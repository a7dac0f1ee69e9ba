"""Write go2.urdf, the Unitree Go2 quadruped used by diffsim-bench, next to this script.

The facts below (masses, centres of mass, inertia tensors, joint origins, axes and
limits, collision primitive sizes) are carried over by hand from Unitree's
go2_description URDF (unitree_ros, BSD-3-Clause licence). Nothing is read from that
file at run time; this script needs only the standard library and numpy.

What differs from the official file:
  * 13 links and 12 revolute joints, no fixed joints. Every fixed child link that
    carries mass (head, motor rotors, feet) is folded into the link it hangs from as
    one rigid body: masses add, the COM is the mass-weighted mean, and each part's
    inertia is moved to the composite COM with the parallel-axis theorem (full 3x3
    tensor, products of inertia included, in the parent link frame). All of these
    fixed joints have rpy 0, so no rotation of the tensors is needed. The massless
    links (calflower, imu, radar, front_camera) are dropped.
  * Collision geometry is primitives only (box, cylinders, spheres); no visuals,
    materials or meshes. The thigh box is replaced by a cylinder along the thigh and
    the foot sphere sits on the calf link.

Regenerate with:  python tasks/assets/go2/make_go2_urdf.py
"""

from pathlib import Path

import numpy as np

LEGS = ("FL", "FR", "RL", "RR")
FORE = {"FL": 1, "FR": 1, "RL": -1, "RR": -1}  # +1 front leg, -1 rear leg
SIDE = {"FL": 1, "FR": -1, "RL": 1, "RR": -1}  # +1 left leg, -1 right leg
HALF_PI = np.pi / 2

# Inertial facts: link -> (mass kg, COM xyz in link frame, (ixx, ixy, ixz, iyy, iyz, izz) about the COM).
LINK_INERTIA = {
    "base": (6.921, (0.021112, 0, -0.005366), (0.02448, 0.00012166, 0.0014849, 0.098077, -3.12e-05, 0.107)),
    "FL_hip": (0.678, (-0.0054, 0.00194, -0.000105), (0.00048, -3.01e-06, 1.11e-06, 0.000884, -1.42e-06, 0.000596)),
    "FL_thigh": (1.152, (-0.00374, -0.0223, -0.0327), (0.00584, 8.72e-05, -0.000289, 0.0058, 0.000808, 0.00103)),
    "FL_calf": (0.154, (0.00548, -0.000975, -0.115), (0.00108, 3.4e-07, 1.72e-05, 0.0011, 8.28e-06, 3.29e-05)),
    "FR_hip": (0.678, (-0.0054, -0.00194, -0.000105), (0.00048, 3.01e-06, 1.11e-06, 0.000884, 1.42e-06, 0.000596)),
    "FR_thigh": (1.152, (-0.00374, 0.0223, -0.0327), (0.00584, -8.72e-05, -0.000289, 0.0058, -0.000808, 0.00103)),
    "FR_calf": (0.154, (0.00548, 0.000975, -0.115), (0.00108, -3.4e-07, 1.72e-05, 0.0011, -8.28e-06, 3.29e-05)),
    "RL_hip": (0.678, (0.0054, 0.00194, -0.000105), (0.00048, 3.01e-06, -1.11e-06, 0.000884, -1.42e-06, 0.000596)),
    "RL_thigh": (1.152, (-0.00374, -0.0223, -0.0327), (0.00584, 8.72e-05, -0.000289, 0.0058, 0.000808, 0.00103)),
    "RL_calf": (0.154, (0.00548, -0.000975, -0.115), (0.00108, 3.4e-07, 1.72e-05, 0.0011, 8.28e-06, 3.29e-05)),
    "RR_hip": (0.678, (0.0054, -0.00194, -0.000105), (0.00048, -3.01e-06, -1.11e-06, 0.000884, 1.42e-06, 0.000596)),
    "RR_thigh": (1.152, (-0.00374, 0.0223, -0.0327), (0.00584, -8.72e-05, -0.000289, 0.0058, -0.000808, 0.00103)),
    "RR_calf": (0.154, (0.00548, 0.000975, -0.115), (0.00108, -3.4e-07, 1.72e-05, 0.0011, -8.28e-06, 3.29e-05)),
}

# Fixed parts folded into a moving link: (name, receiving link, position of the part's
# frame in that link's frame, mass, inertia about the part's own origin, which is its COM).
#
# Why fold them: light bodies on fixed joints make penalty/soft-constraint solvers stiff
# (a tiny mass held by a stiff weld), and the engines handle fixed joints differently
# (merged by one, simulated as constraints by another), which would make their results
# differ for reasons unrelated to the benchmark. The rotors' spin inertia through the
# gearbox is modelled by joint armature in the task's physics spec, not by these links.
HEAD_INERTIA = (9.6e-06, 0, 0, 9.6e-06, 0, 9.6e-06)
FOOT_INERTIA = (9.6e-06, 0, 0, 9.6e-06, 0, 9.6e-06)
ROTOR_INERTIA_X = (0.000111842, 0, 0, 0.000059647, 0, 0.000059647)  # spins about x (hip)
ROTOR_INERTIA_Y = (0.000059647, 0, 0, 0.000111842, 0, 0.000059647)  # spins about y (thigh, calf)
ROTOR_MASS = 0.089

FIXED_PARTS = [
    ("Head_upper", "base", (0.285, 0, 0.01), 0.001, HEAD_INERTIA),
    ("Head_lower", "base", (0.285 + 0.008, 0, 0.01 - 0.07), 0.001, HEAD_INERTIA),  # hangs from Head_upper
]
for leg in LEGS:
    fore, side = FORE[leg], SIDE[leg]
    FIXED_PARTS += [
        (f"{leg}_hip_rotor", "base", (0.11215 * fore, 0.04675 * side, 0), ROTOR_MASS, ROTOR_INERTIA_X),
        (f"{leg}_thigh_rotor", f"{leg}_hip", (0, -0.00015 * side, 0), ROTOR_MASS, ROTOR_INERTIA_Y),
        (f"{leg}_calf_rotor", f"{leg}_thigh", (0, -0.03235 * side, 0), ROTOR_MASS, ROTOR_INERTIA_Y),
        (f"{leg}_foot", f"{leg}_calf", (0, 0, -0.213), 0.04, FOOT_INERTIA),
    ]

# Joint limits: (lower rad, upper rad, effort N m, velocity rad/s).
HIP_LIMIT = (-1.0472, 1.0472, 23.7, 30.1)
THIGH_LIMIT = {1: (-1.5708, 3.4907, 23.7, 30.1), -1: (-0.5236, 4.5379, 23.7, 30.1)}  # by FORE: front, rear
CALF_LIMIT = (-2.7227, -0.83776, 45.43, 15.70)
# Joints, in file order: (name, parent, child, origin xyz in the parent frame, axis, limit).
JOINTS = []
for leg in LEGS:
    fore, side = FORE[leg], SIDE[leg]
    JOINTS += [
        (f"{leg}_hip_joint", "base", f"{leg}_hip", (0.1934 * fore, 0.0465 * side, 0), (1, 0, 0), HIP_LIMIT),
        (f"{leg}_thigh_joint", f"{leg}_hip", f"{leg}_thigh", (0, 0.0955 * side, 0), (0, 1, 0), THIGH_LIMIT[fore]),
        (f"{leg}_calf_joint", f"{leg}_thigh", f"{leg}_calf", (0, 0, -0.213), (0, 1, 0), CALF_LIMIT),
    ]

# Collision primitives: link -> [(name, origin xyz, rpy, geometry tag, geometry attributes)].
# The official calf cylinder of FL differs slightly from the other three legs; kept as is.
CALF_CYLINDER = {  # origin xyz, pitch, radius
    "FL": ((0.008, 0, -0.06), -0.21, 0.012),
    "FR": ((0.01, 0, -0.06), -0.2, 0.013),
    "RL": ((0.01, 0, -0.06), -0.2, 0.013),
    "RR": ((0.01, 0, -0.06), -0.2, 0.013),
}
FOOT_CENTRE = (-0.002, 0, -0.213)  # foot joint origin (0, 0, -0.213) plus the sphere's offset (-0.002, 0, 0)
COLLISIONS = {"base": [("base", (0, 0, 0), (0, 0, 0), "box", {"size": (0.3762, 0.0935, 0.114)})]}
for leg in LEGS:
    side = SIDE[leg]
    calf_xyz, calf_pitch, calf_radius = CALF_CYLINDER[leg]
    COLLISIONS[f"{leg}_hip"] = [
        (f"{leg}_hip", (0, 0.08 * side, 0), (HALF_PI, 0, 0), "cylinder", {"length": 0.04, "radius": 0.046})
    ]
    COLLISIONS[f"{leg}_thigh"] = [
        (f"{leg}_thigh", (0, 0, -0.1065), (0, 0, 0), "cylinder", {"length": 0.17, "radius": 0.015})
    ]
    COLLISIONS[f"{leg}_calf"] = [
        (f"{leg}_calf", calf_xyz, (0, calf_pitch, 0), "cylinder", {"length": 0.12, "radius": calf_radius}),
        (f"{leg}_foot", FOOT_CENTRE, (0, 0, 0), "sphere", {"radius": 0.022}),
    ]


def tensor(ixx, ixy, ixz, iyy, iyz, izz):
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], dtype=float)


def composite(parts):
    """Combine rigid parts given as (mass, com, 3x3 inertia about that com), all in one frame."""
    total_mass = sum(m for m, _, _ in parts)
    com = sum(m * np.asarray(c, dtype=float) for m, c, _ in parts) / total_mass
    inertia = np.zeros((3, 3))
    for m, c, i_own in parts:
        d = np.asarray(c, dtype=float) - com
        inertia += i_own + m * (d @ d * np.eye(3) - np.outer(d, d))
    return total_mass, com, inertia


def folded_inertials():
    """Per moving link: (mass, com, inertia) with its fixed parts folded in."""
    result = {}
    for link, (mass, com, i6) in LINK_INERTIA.items():
        parts = [(mass, com, tensor(*i6))]
        parts += [(m, pos, tensor(*i6p)) for _, owner, pos, m, i6p in FIXED_PARTS if owner == link]
        result[link] = composite(parts)
    return result


def num(x):
    x = float(x)
    if abs(x) < 1e-12:
        return "0"
    return f"{x:.7g}"


def vec(values):
    return " ".join(num(v) for v in values)


def urdf_text():
    lines = [
        '<?xml version="1.0"?>',
        "<!-- Generated by make_go2_urdf.py; edit that script, not this file. -->",
        '<robot name="go2">',
    ]
    for link, (mass, com, inertia) in folded_inertials().items():
        lines += [
            f'  <link name="{link}">',
            "    <inertial>",
            f'      <origin xyz="{vec(com)}" rpy="0 0 0"/>',
            f'      <mass value="{num(mass)}"/>',
            f'      <inertia ixx="{num(inertia[0, 0])}" ixy="{num(inertia[0, 1])}" ixz="{num(inertia[0, 2])}"'
            f' iyy="{num(inertia[1, 1])}" iyz="{num(inertia[1, 2])}" izz="{num(inertia[2, 2])}"/>',
            "    </inertial>",
        ]
        for name, xyz, rpy, shape, attrs in COLLISIONS[link]:
            shape_attrs = " ".join(f'{k}="{vec(v) if isinstance(v, tuple) else num(v)}"' for k, v in attrs.items())
            lines += [
                f'    <collision name="{name}">',
                f'      <origin xyz="{vec(xyz)}" rpy="{vec(rpy)}"/>',
                f"      <geometry><{shape} {shape_attrs}/></geometry>",
                "    </collision>",
            ]
        lines.append("  </link>")
    for name, parent, child, xyz, axis, (lower, upper, effort, velocity) in JOINTS:
        lines += [
            f'  <joint name="{name}" type="revolute">',
            f'    <parent link="{parent}"/>',
            f'    <child link="{child}"/>',
            f'    <origin xyz="{vec(xyz)}" rpy="0 0 0"/>',
            f'    <axis xyz="{vec(axis)}"/>',
            f'    <limit lower="{num(lower)}" upper="{num(upper)}" effort="{num(effort)}" velocity="{num(velocity)}"/>',
            "  </joint>",
        ]
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    out_path = Path(__file__).with_name("go2.urdf")
    out_path.write_text(urdf_text())
    total_mass = sum(mass for mass, _, _ in folded_inertials().values())
    print(f"wrote {out_path} ({len(LINK_INERTIA)} links, {len(JOINTS)} joints), total mass {total_mass:.6f} kg")
