"""The simulated robot (MuJoCo). Importing the package picks MuJoCo's headless OpenGL platform,
EGL, when none is set and there is no display, before any module imports mujoco."""

import os

if not os.environ.get("MUJOCO_GL") and not (
    os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
):
    os.environ["MUJOCO_GL"] = "egl"
