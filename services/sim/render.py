"""Rendering the robot's cameras: colour and depth from one render pass, and segmentation.

Depth is metres along the optical axis (reversed-Z depth buffer, undone in float64 as MuJoCo's
own Renderer does). A ``CameraRenderer`` owns an OpenGL context, which is bound to the thread
that created it: make and use it in one thread. ``snapshot`` copies the state to render (cheap:
do it with the physics paused); ``render`` is the slow part and releases the GIL.
"""

from __future__ import annotations

import mujoco
import numpy as np

from schemas import CameraIntrinsics


def intrinsics(model: mujoco.MjModel, camera: int, width: int, height: int) -> CameraIntrinsics:
    """Pinhole intrinsics of ``camera`` rendered at width × height pixels."""
    sensor = model.cam_sensorsize[camera]
    if sensor[0] > 0 and sensor[1] > 0:  # focal lengths given (our robots); principal point at 0
        fx_len, fy_len = model.cam_intrinsic[camera][:2]
        fx, fy = fx_len / sensor[0] * width, fy_len / sensor[1] * height
        cx, cy = (width - 1) / 2, (height - 1) / 2
        return CameraIntrinsics(width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy)
    return CameraIntrinsics.from_fov(width, height, float(model.cam_fovy[camera]))


#: what a sensor sees: bodies and world geometry, never decorations (labels, frames, lights,
#: cameras, contact points, ...)
SENSOR_CATEGORIES = mujoco.mjtCatBit.mjCAT_STATIC | mujoco.mjtCatBit.mjCAT_DYNAMIC


def sensor_option() -> mujoco.MjvOption:
    """Visualisation options of a physical sensor: geoms of the default visible groups only.
    Sites are markers (roi, robot_start, poi_*), tendons and joints are abstractions: none of
    them is drawn, whatever a scene's styling."""
    option = mujoco.MjvOption()
    option.sitegroup[:] = 0
    option.tendongroup[:] = 0
    option.flexgroup[:] = 0
    option.skingroup[:] = 1
    for flag in (
        mujoco.mjtVisFlag.mjVIS_TENDON,
        mujoco.mjtVisFlag.mjVIS_JOINT,
        mujoco.mjtVisFlag.mjVIS_CAMERA,
        mujoco.mjtVisFlag.mjVIS_LIGHT,
        mujoco.mjtVisFlag.mjVIS_CONTACTPOINT,
        mujoco.mjtVisFlag.mjVIS_CONTACTFORCE,
        mujoco.mjtVisFlag.mjVIS_COM,
        mujoco.mjtVisFlag.mjVIS_INERTIA,
        mujoco.mjtVisFlag.mjVIS_ACTUATOR,
        mujoco.mjtVisFlag.mjVIS_CONSTRAINT,
        mujoco.mjtVisFlag.mjVIS_RANGEFINDER,
        mujoco.mjtVisFlag.mjVIS_PERTFORCE,
        mujoco.mjtVisFlag.mjVIS_PERTOBJ,
        mujoco.mjtVisFlag.mjVIS_TRANSPARENT,
    ):
        option.flags[flag] = 0
    option.frame = mujoco.mjtFrame.mjFRAME_NONE
    option.label = mujoco.mjtLabel.mjLABEL_NONE
    return option


class CameraRenderer:
    """Offscreen renderer of one image size; shadows off by default (4× faster on Mesa)."""

    def __init__(self, model: mujoco.MjModel, width: int, height: int, shadows: bool = False):
        self.model = model
        self.width, self.height = width, height
        self.shadows = shadows
        self._gl = mujoco.GLContext(width, height)
        self._gl.make_current()
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        self._context.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=10_000)
        self._option = sensor_option()
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._perturb = mujoco.MjvPerturb()
        self._rect = mujoco.MjrRect(0, 0, width, height)
        extent = model.stat.extent
        near = np.float32(model.vis.map.znear * extent)
        far = np.float32(model.vis.map.zfar * extent)
        c = -(far + near) / (far - near)
        d = -(np.float32(2) * far * near) / (far - near)
        self._c, self._d = np.float32(-0.5) * c - np.float32(0.5), np.float32(-0.5) * d

    def snapshot(self, data: mujoco.MjData, camera: int) -> None:
        """Copy the state into the scene to render (call with the physics paused)."""
        self._camera.fixedcamid = camera
        mujoco.mjv_updateScene(
            self.model,
            data,
            self._option,
            self._perturb,
            self._camera,
            SENSOR_CATEGORIES,
            self._scene,
        )
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = self.shadows

    def render(self, depth: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """RGB uint8 (h, w, 3) and depth float32 (h, w) metres of the last snapshot, from one
        render pass."""
        self._gl.make_current()
        mujoco.mjr_render(self._rect, self._scene, self._context)
        rgb = np.empty((self.height, self.width, 3), np.uint8)
        z = np.empty((self.height, self.width), np.float32) if depth else None
        mujoco.mjr_readPixels(rgb, z, self._rect, self._context)
        rgb = np.ascontiguousarray(rgb[::-1])
        if z is not None:  # undo the reversed-Z projection, in float64 for precision
            z = (self._d / (z[::-1].astype(np.float64) + self._c)).astype(np.float32)
        return rgb, z

    def segmentation(self, data: mujoco.MjData, camera: int) -> np.ndarray:
        """Geom id per pixel (-1 where no geom), int32 (h, w)."""
        self.snapshot(data, camera)
        flags = self._scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        try:
            rgb, _ = self.render(depth=False)
        finally:
            flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = False
            flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = False
        segid = rgb[..., 0].astype(np.int64) | rgb[..., 1].astype(np.int64) << 8
        segid |= rgb[..., 2].astype(np.int64) << 16  # segid + 1, 0 = background
        lookup = np.full(self._scene.ngeom + 1, -1, np.int32)
        for g in self._scene.geoms[: self._scene.ngeom]:
            if g.segid != -1 and g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lookup[g.segid + 1] = g.objid
        return lookup[np.minimum(segid, self._scene.ngeom)]

    def close(self) -> None:
        if self._context is not None:
            self._gl.make_current()
            self._context.free()
            self._context = None
            self._gl.free()
