"""Headless rendering of env states with MuJoCo's renderer (``MUJOCO_GL=egl``)."""

from __future__ import annotations

import os

import mujoco
import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

DEFAULT_CAMERA = dict(lookat=(0.22, 0.0, 0.50), distance=1.15, azimuth=195.0, elevation=-30.0)


def make_camera(lookat=None, distance=None, azimuth=None, elevation=None) -> mujoco.MjvCamera:
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cfg = dict(DEFAULT_CAMERA)
    given = dict(lookat=lookat, distance=distance, azimuth=azimuth, elevation=elevation)
    for k, v in given.items():
        if v is not None:
            cfg[k] = v
    cam.lookat[:] = cfg["lookat"]
    cam.distance, cam.azimuth, cam.elevation = cfg["distance"], cfg["azimuth"], cfg["elevation"]
    return cam


class Renderer:
    """Renders unbatched env states (qpos + goals) of one env to RGB arrays."""

    def __init__(self, env, width: int = 640, height: int = 480):
        self.env = env
        self.model = env.mj_model
        self.data = mujoco.MjData(self.model)
        self.renderer = mujoco.Renderer(self.model, height=height, width=width)
        self.camera = make_camera()
        self._goal_sites = [self.model.site(n).id for n in ("goal_l", "goal_r")
                            if _has_site(self.model, n)]

    def frame(self, qpos, desired_goal=None, mocap_pos=None) -> np.ndarray:
        d = self.data
        d.qpos[:] = np.asarray(qpos, np.float64)
        if mocap_pos is not None:
            d.mocap_pos[: len(mocap_pos)] = np.asarray(mocap_pos)
        if desired_goal is not None:
            for sid, g in zip(self._goal_sites, np.asarray(desired_goal), strict=False):
                self.model.site_pos[sid] = g
        mujoco.mj_forward(self.model, d)
        self.renderer.update_scene(d, camera=self.camera)
        return self.renderer.render().copy()

    def close(self):
        self.renderer.close()


def _has_site(model, name):
    try:
        model.site(name)
        return True
    except KeyError:
        return False


def render_state(env, state, width=640, height=480, camera=None) -> np.ndarray:
    r = Renderer(env, width, height)
    if camera:
        r.camera = make_camera(**camera)
    try:
        return r.frame(np.asarray(env.backend.qpos(state.data)), state.obs["desired_goal"],
                       np.asarray(env.backend.mocap_pos(state.data)))
    finally:
        r.close()
