"""Pictures of task states, for the ``render`` verb: the same neutral state drawn the same way whichever
engine produced it (``simcore``'s layout: z up, root quaternion x, y, z, w).

Rigid tasks (a floating or fixed base of hinges) are drawn by MuJoCo's offscreen renderer from the
model MuJoCo-Warp simulates (:func:`backends.mujoco_warp.adapter.build_spec`: the task's own asset,
collision geometry, the ground plane) with a checkered ground so motion shows, and a camera that keeps
the root in view. Headless: MuJoCo's EGL context (Mesa's software rasteriser where there is no GPU); set
``MUJOCO_GL`` before anything imports MuJoCo to choose another. Soft bodies (particles of a tet mesh)
are drawn as the mesh's boundary surface with matplotlib, no GL at all.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # read when MuJoCo is first imported in the process

import numpy as np  # noqa: E402
import torch  # noqa: E402

from simcore import ControlKind  # noqa: E402

WIDTH, HEIGHT = 480, 360


class RigidScene:
    """Frames of a rigid task's states: :meth:`frame` takes one env's ``joint_q`` (nq,)."""

    def __init__(self, task, width: int = WIDTH, height: int = HEIGHT):
        import mujoco

        from backends.mujoco_warp.adapter import build_spec

        spec = build_spec(task)
        spec.compiler.discardvisual = False  # MuJoCo's URDF reader sets it, which would drop the ground's material
        grid = spec.add_texture(name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D, width=256, height=256)
        grid.builtin = mujoco.mjtBuiltin.mjBUILTIN_CHECKER
        grid.rgb1, grid.rgb2 = [0.32, 0.36, 0.42], [0.22, 0.25, 0.3]
        material = spec.add_material(name="grid", texrepeat=[1.0, 1.0], texuniform=True)
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
        for geom in spec.geoms:
            if geom.type == mujoco.mjtGeom.mjGEOM_PLANE:
                geom.material = "grid"
                geom.size = [20.0, 20.0, 1.0]  # drawn to 20 m each way (it collides as an infinite plane)
            else:
                geom.rgba = [0.85, 0.55, 0.25, 1.0]
        spec.worldbody.add_light(
            pos=[0.0, 0.0, 6.0], dir=[0.0, 0.0, -1.0], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
        )
        self._mujoco = mujoco
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.floating = task.layout.floating_base
        self.renderer = mujoco.Renderer(self.model, height, width)
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        mujoco.mj_forward(self.model, self.data)  # the default pose: how big the robot is
        robot = [g for g in range(self.model.ngeom) if self.model.geom_type[g] != mujoco.mjtGeom.mjGEOM_PLANE]
        root = self.data.xpos[1]
        reach = max(float(np.linalg.norm(self.data.geom_xpos[g] - root) + self.model.geom_rbound[g]) for g in robot)
        self.camera.distance = 4.0 * reach
        self.camera.elevation, self.camera.azimuth = -20.0, 135.0

    def frame(self, joint_q: np.ndarray, lookat: np.ndarray | None = None) -> np.ndarray:
        """(height, width, 3) uint8 of the state; the camera follows the root (or looks at ``lookat``)."""
        q = np.asarray(joint_q, dtype=np.float64)
        if self.floating:  # neutral x, y, z, w -> MuJoCo's w, x, y, z
            q = np.concatenate((q[:3], q[6:7], q[3:6], q[7:]))
        self.data.qpos[:] = q
        self._mujoco.mj_forward(self.model, self.data)
        self.camera.lookat[:] = q[:3] if self.floating else self.model.stat.center
        if self.floating:
            self.camera.lookat[2] = max(self.camera.lookat[2], 0.2)
        if lookat is not None:
            self.camera.lookat[:] = lookat
        self.renderer.update_scene(self.data, self.camera)
        return self.renderer.render().copy()

    def close(self) -> None:
        self.renderer.close()


class SoftScene:
    """Frames of a soft body's states: :meth:`frame` takes one env's ``particle_q`` (P, 3)."""

    def __init__(self, task, width: int = WIDTH, height: int = HEIGHT):
        tets = task.soft_body.tets.numpy()
        faces = np.sort(
            np.concatenate([tets[:, [0, 1, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 3]], tets[:, [1, 2, 3]]]), axis=1
        )
        unique, counts = np.unique(faces, axis=0, return_counts=True)
        self.surface = unique[counts == 1]  # a face of one tet only lies on the boundary
        self.size = (width, height)

    def frame(self, particle_q: np.ndarray) -> np.ndarray:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        x = np.asarray(particle_q, dtype=float)
        dpi = 100
        fig = plt.figure(figsize=(self.size[0] / dpi, self.size[1] / dpi), dpi=dpi)
        ax = fig.add_subplot(projection="3d")
        ax.add_collection3d(
            Poly3DCollection(x[self.surface], facecolor=(0.85, 0.55, 0.25), edgecolor=(0.3, 0.2, 0.1), linewidth=0.2)
        )
        centre = x.mean(axis=0)
        half = max(float(np.ptp(x, axis=0).max()), 0.2)
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(0.0, 2 * half)
        ax.view_init(elev=20, azim=-60)
        ax.set_box_aspect((1, 1, 1))
        fig.canvas.draw()
        image = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
        plt.close(fig)
        return image

    def close(self) -> None:
        pass


def scene_for(task, width: int = WIDTH, height: int = HEIGHT):
    """The scene that draws ``task``'s states."""
    if task.control_kind == ControlKind.TET_ACTIVATION:
        return SoftScene(task, width, height)
    return RigidScene(task, width, height)


def state_picture_input(task, state) -> np.ndarray:
    """What :meth:`frame` takes of env 0 of a :class:`simcore.SimState`."""
    if task.control_kind == ControlKind.TET_ACTIVATION:
        return state.particle_q[0].detach().to("cpu", torch.float64).numpy()
    return state.joint_q[0].detach().to("cpu", torch.float64).numpy()
