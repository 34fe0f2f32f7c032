"""The simulated camera (``kind = "sim"``): renders the simulated cell (a
`mjx_envs.numpy_env.NumpyDualArmEnv`, e.g. `daddpg_jax.deploy.ursim.SimCell`'s ``env``) from a
camera pose, RGB and depth, with sensor noise, blur, exposure and lighting changes and a
capture latency, all drawn from a random stream of its own (``seed``): the episodes' goals and
placements, drawn from the run's stream, stay paired with a run without a camera.

It renders a copy of the simulator's model with visual-only additions, built with
``mujoco.MjSpec`` from the same scene in the same physics version (`build_render_model`):

- AprilTags (tag36h11) as a white plate and black cell boxes, exact to the cell: the Reach
  tags (ids 0, 1, 2; each a mocap body with a stand down to the table, parked out of sight
  until placed), the calibration board (`calibration.NOMINAL_BOARD`), and a tag on the object
  (`objects.BAR` / `objects.POT`: on the bar's middle, on the pot's lid);
- object colours for the colour segmentation (`objects.ObjectGeometry.colours`);
- the camera and nothing else: every added geom has no mass and no contacts, every added body
  is a mocap body after the scene's own. Stepping the copy and the simulator from one state
  gives identical positions and velocities (tests/test_camera.py); the shipped scenes, the
  physics versions and the recorded results are untouched.

Each capture copies the simulator's state (qpos, qvel, act, the arms' mocap targets, the base
poses of a miscalibrated cell) into the copy, and renders the state of ``latency`` s ago (the
states of earlier captures are kept): the frame's ``stamp`` is that state's time on the
camera's clock, simulated seconds that keep counting over resets (`SimClock`).
"""

from __future__ import annotations

import os

# headless rendering; it takes effect only when MuJoCo is not imported yet (set MUJOCO_GL=egl
# in the environment of a process that imports the simulator first)
os.environ.setdefault("MUJOCO_GL", "egl")

import collections  # noqa: E402
import math  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import cv2  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from daddpg_jax.deploy.camera import objects as objects_lib  # noqa: E402
from daddpg_jax.deploy.camera.calibration import (  # noqa: E402
    NOMINAL_BOARD,
    TABLE_Z,
    BoardLayout,
)
from daddpg_jax.deploy.camera.config import CameraConfig  # noqa: E402
from daddpg_jax.deploy.camera.frames import (  # noqa: E402
    Frame,
    Intrinsics,
    matrix_to_quat,
    quat_to_matrix,
    transform,
    yaw_matrix,
)
from daddpg_jax.deploy.camera.tags import SHIPPED_TAGS, TargetLayout, tag_cells  # noqa: E402
from mjx_envs import model as model_lib  # noqa: E402
from mjx_envs import settings as settings_lib  # noqa: E402

CAMERA_NAME = "perception_cam"
TAG_HALF_THICKNESS = 0.0005
"""half the thickness of a simulated tag's plate and cells, m"""
PARK = (0.0, 0.0, -5.0)
"""where unused Reach tags wait (under the floor)"""
REACH_TAGS = (0, 1, 2)
STAND_RGBA = (0.55, 0.56, 0.60, 1.0)
SHADOW_SIZE = 2048
"""the shadow map's side in the copy (the scene's 4096 costs twice the render time)"""


@dataclass(frozen=True)
class SensorModel:
    """What the simulated sensor does to a perfect render. Drawn per frame: pixel noise
    (Gaussian, ``noise_std`` 8-bit levels), a Gaussian blur of sigma ~ U(``blur``) px, an
    exposure gain ~ U(``exposure``), the capture latency ~ U(``latency``) s, depth noise of
    ``depth_std`` m at 1 m (growing with the square of the distance) and a fraction
    ``depth_dropout`` of pixels without a depth reading. Drawn per `SimCamera.reset` (an
    episode): the light's intensity scale ~ U(``lighting``) and its direction tilted by up to
    ``light_tilt_deg``."""

    noise_std: float = 2.0
    blur: tuple = (0.0, 0.8)
    exposure: tuple = (0.8, 1.2)
    lighting: tuple = (0.6, 1.2)
    light_tilt_deg: float = 25.0
    latency: tuple = (0.0, 0.0)
    depth_std: float = 0.001
    depth_dropout: float = 0.01


PERFECT = SensorModel(noise_std=0.0, blur=(0.0, 0.0), exposure=(1.0, 1.0), lighting=(1.0, 1.0),
                      light_tilt_deg=0.0, latency=(0.0, 0.0), depth_std=0.0, depth_dropout=0.0)
"""a noiseless sensor with the scene's own lighting"""


class SimClock:
    """The camera's monotonic clock in simulated seconds: the simulator's time, plus the
    lengths of the episodes before (its time starts again at each reset)."""

    def __init__(self):
        self.base, self.last = 0.0, 0.0

    def __call__(self, sim_time: float) -> float:
        t = float(sim_time)
        if t + self.base < self.last - 1e-12:
            self.base = self.last - t
        self.last = t + self.base
        return self.last


# -- the render model ---------------------------------------------------------------------------

def _add_tag(body, tag_id: int, size: float, pos, quat=(1.0, 0.0, 0.0, 0.0), name=None):
    """Adds tag ``tag_id`` (black square ``size`` m, 1-cell white margin) to ``body``, its face
    at ``pos`` (the body's frame) facing the body's +z, turned by ``quat``; no mass, no
    contacts. Returns the added geoms' names."""
    cell = size / 8.0
    black = tag_cells(tag_id)
    R = quat_to_matrix(quat)
    pos = np.asarray(pos, float)
    name = name or f"tag{tag_id}"
    names = []

    def geom(nm, centre, half, rgba):
        body.add_geom(name=nm, type=mujoco.mjtGeom.mjGEOM_BOX, size=half,
                      pos=pos + R @ np.asarray(centre, float), quat=quat, rgba=rgba,
                      contype=0, conaffinity=0, mass=0.0, group=1)
        names.append(nm)

    t = TAG_HALF_THICKNESS
    geom(f"{name}_plate", (0.0, 0.0, -t - 0.0002), (5 * cell, 5 * cell, t), (1, 1, 1, 1))
    k = 0
    for row in range(8):
        col = 0
        while col < 8:
            if not black[row, col]:
                col += 1
                continue
            end = col
            while end + 1 < 8 and black[row, end + 1]:
                end += 1
            cx = ((col + end) / 2.0 - 3.5) * cell
            cy = (3.5 - row) * cell
            geom(f"{name}_c{k}", (cx, cy, -t), ((end - col + 1) * cell / 2.0, cell / 2.0, t),
                 (0.02, 0.02, 0.02, 1))
            k += 1
            col = end + 1
    return names


def _spec(cfg) -> mujoco.MjSpec:
    """The scene's spec in the task's physics version (as `mjx_envs.model.load_model`)."""
    version = model_lib.check_version(getattr(cfg, "physics_version", None))
    with model_lib.scene_path(cfg.scene) as path:
        spec = mujoco.MjSpec.from_file(str(path))
    if version != settings_lib.PHYSICS_VERSION:
        model_lib.edit_spec(spec, cfg.scene, version)
    return spec


@dataclass
class RenderModel:
    """The compiled copy (``model``, ``data``) and where its additions are: the number of
    the simulator's bodies and mocap bodies (first in the copy), each Reach tag's mocap index
    and stand geom, each tag's body id and pose in that body (``tags``: id -> (body id, 4x4,
    size)), the object's geometry and the camera's id."""

    model: mujoco.MjModel
    data: mujoco.MjData
    sim_nbody: int
    sim_nmocap: int
    reach: dict
    tags: dict
    geometry: objects_lib.ObjectGeometry | None
    camera_id: int


def build_render_model(cfg, object_tags: bool = True, object_colours: bool = True,
                       board: BoardLayout | None = NOMINAL_BOARD) -> RenderModel:
    """The render copy of the scene of task config ``cfg`` (a `TaskConfig`: its scene,
    physics version, timestep and cone), with the visual additions of the module doc."""
    spec = _spec(cfg)
    geometry = objects_lib.geometry_for_scene(cfg.scene)
    n_bodies = len(spec.bodies)
    if geometry is not None:
        obj = spec.body(geometry.body)
        if object_colours:
            for g in spec.geoms:
                if g.parent.name == geometry.body:
                    g.rgba = geometry.colour_of(g.name)
        if object_tags:
            _add_tag(obj, geometry.tag_id, geometry.tag_size, geometry.tag_pos)
    world = spec.worldbody
    stands = {}
    for tid in REACH_TAGS:
        b = world.add_body(name=f"reach_tag{tid}", mocap=True, pos=PARK)
        _add_tag(b, tid, SHIPPED_TAGS[tid][0], (0.0, 0.0, 0.0))
        half = 5 * SHIPPED_TAGS[tid][0] / 8.0
        b.add_geom(name=f"reach_tag{tid}_stand", type=mujoco.mjtGeom.mjGEOM_BOX,
                   size=(half, half, 0.001), pos=(0.0, 0.0, -0.002), rgba=STAND_RGBA,
                   contype=0, conaffinity=0, mass=0.0, group=1)
        stands[tid] = f"reach_tag{tid}_stand"
    if board is not None:
        b = world.add_body(name="tag_board", mocap=True, pos=(0.0, 0.0, 0.0))
        for tid, (centre, yaw, size) in board.tags.items():
            _add_tag(b, tid, size, centre, matrix_to_quat(yaw_matrix(yaw)))
    world.add_camera(name=CAMERA_NAME, pos=(1.0, 0.0, 1.2), quat=(1.0, 0.0, 0.0, 0.0),
                     fovy=45.0)
    spec.visual.quality.shadowsize = SHADOW_SIZE
    model = spec.compile()
    model.opt.timestep = float(cfg.timestep)
    model.opt.cone = model_lib.CONES[cfg.cone]
    data = mujoco.MjData(model)
    n_sim_mocap = int(np.sum(model.body_mocapid[:n_bodies] >= 0))
    reach = {tid: (int(model.body_mocapid[model.body(f"reach_tag{tid}").id]),
                   model.geom(stands[tid]).id) for tid in REACH_TAGS}
    tags = {}
    if geometry is not None and object_tags:
        tags[geometry.tag_id] = (model.body(geometry.body).id,
                                 transform(np.eye(3), geometry.tag_pos), geometry.tag_size)
    for tid in REACH_TAGS:
        tags[tid] = (model.body(f"reach_tag{tid}").id, np.eye(4), SHIPPED_TAGS[tid][0])
    if board is not None:
        bid = model.body("tag_board").id
        for tid in board.tags:
            tags[tid] = (bid, board.pose(tid), board.tags[tid][2])
    return RenderModel(model, data, n_bodies, n_sim_mocap, reach, tags, geometry,
                       model.camera(CAMERA_NAME).id)


def cam_quat(T_world_cam) -> np.ndarray:
    """MuJoCo's camera orientation (looking along its -z, y up) of an OpenCV camera pose."""
    R = np.asarray(T_world_cam, float)[:3, :3] @ np.diag([1.0, -1.0, -1.0])
    return matrix_to_quat(R)


# -- the camera ---------------------------------------------------------------------------------

class SimCamera:
    """The simulated camera on ``env`` (a `NumpyDualArmEnv`, whose state it renders); see the
    module doc. ``config``: the mount, image size and field of view (default: the nominal
    mount, 640x480); ``sensor``: the `SensorModel`; ``seed``: its own random stream;
    ``object_tags``, ``object_colours``, ``board``: the copy's additions; ``depth``: render
    depth too; ``shadows``: cast shadows (most of the render time on a CPU renderer)."""

    def __init__(self, env, config: CameraConfig | None = None,
                 sensor: SensorModel = SensorModel(), seed: int = 0,
                 object_tags: bool = True, object_colours: bool = True,
                 board: BoardLayout | None = NOMINAL_BOARD, depth: bool = True,
                 shadows: bool = True):
        self.env = env
        self.config = CameraConfig() if config is None else config
        self.sensor, self.depth_on = sensor, bool(depth)
        self.rng = np.random.default_rng(seed)
        self.scene = build_render_model(env.config, object_tags, object_colours, board)
        m = self.scene.model
        self.intrinsics = Intrinsics.from_fovy(self.config.width, self.config.height,
                                               self.config.fovy_deg)
        m.cam_fovy[self.scene.camera_id] = self.config.fovy_deg
        self.set_pose(self.config.T_world_cam)
        self.renderer = mujoco.Renderer(m, height=self.config.height, width=self.config.width)
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = bool(shadows)
        self._light0 = (m.light_diffuse.copy(), m.light_dir.copy(),
                        np.array(m.vis.headlight.diffuse), np.array(m.vis.headlight.ambient))
        self.option = mujoco.MjvOption()
        self.option.sitegroup[:] = 0  # the scenes' goal markers and sites are not seen
        self.clock = SimClock()
        self.history: collections.deque = collections.deque(maxlen=64)
        self.index = 0

    # -- the scene ------------------------------------------------------------------------------

    def set_pose(self, T_world_cam) -> None:
        """Moves the camera (``T_world_cam``, OpenCV frame)."""
        m, cid = self.scene.model, self.scene.camera_id
        self.T_world_cam = np.asarray(T_world_cam, float).copy()
        m.cam_pos[cid] = self.T_world_cam[:3, 3]
        m.cam_quat[cid] = cam_quat(self.T_world_cam)

    def place_tag(self, tag_id: int, centre=None, yaw: float = 0.0) -> None:
        """Puts Reach tag ``tag_id`` (0, 1, 2) flat with its face's centre at ``centre``
        (world; no lower than the table), on a stand down to the table when higher; None
        parks it out of sight."""
        m, d = self.scene.model, self.scene.data
        mocap, stand = self.scene.reach[tag_id]
        if centre is None:
            d.mocap_pos[mocap] = PARK
            return
        c = np.asarray(centre, float).copy()
        c[2] = max(c[2], TABLE_Z + 2 * TAG_HALF_THICKNESS)  # on the table at the lowest
        d.mocap_pos[mocap] = c
        d.mocap_quat[mocap] = matrix_to_quat(yaw_matrix(yaw))
        height = max(float(c[2]) - TABLE_Z - 0.002, 0.0005)
        m.geom_size[stand, 2] = height / 2.0
        m.geom_pos[stand, 2] = -0.002 - height / 2.0

    def place_targets(self, targets, layout: TargetLayout) -> None:
        """Places the tags of ``layout`` so that its targets are ``targets`` [2, 3] (world)
        and parks the other Reach tags."""
        centres = layout.tag_centres(targets)
        for tid in REACH_TAGS:
            self.place_tag(tid, centres.get(tid))

    def tag_pose(self, tag_id: int) -> np.ndarray:
        """The true ``T_world_tag`` of a simulated tag in the copy's current state."""
        body, T_body_tag, _ = self.scene.tags[tag_id]
        d = self.scene.data
        T_world_body = transform(d.xmat[body].reshape(3, 3), d.xpos[body])
        return T_world_body @ T_body_tag

    def reset(self) -> None:
        """A new episode: the lighting drawn again (the sensor's own stream), the latency
        history cleared."""
        m, s, rng = self.scene.model, self.sensor, self.rng
        diffuse, direction, head_d, head_a = self._light0
        scale = rng.uniform(*s.lighting)
        m.light_diffuse[:] = np.clip(diffuse * scale, 0.0, 1.0)
        m.vis.headlight.diffuse[:] = np.clip(head_d * rng.uniform(*s.lighting), 0.0, 1.0)
        m.vis.headlight.ambient[:] = np.clip(head_a * rng.uniform(*s.lighting), 0.0, 1.0)
        tilt = math.radians(s.light_tilt_deg) * math.sqrt(rng.uniform())
        az = rng.uniform(0.0, 2.0 * math.pi)
        for i in range(m.nlight):
            base = direction[i] / max(np.linalg.norm(direction[i]), 1e-9)
            side = np.array([math.cos(az), math.sin(az), 0.0])
            m.light_dir[i] = math.cos(tilt) * base + math.sin(tilt) * side
        self.history.clear()

    # -- capture --------------------------------------------------------------------------------

    def now(self) -> float:
        """The simulator's present on the camera's clock."""
        return self.clock(self.env.data.time)

    def _snapshot(self) -> dict:
        d, sc = self.env.data, self.scene
        return dict(time=self.clock(d.time), qpos=d.qpos.copy(), qvel=d.qvel.copy(),
                    act=d.act.copy(), mocap_pos=d.mocap_pos[:sc.sim_nmocap].copy(),
                    mocap_quat=d.mocap_quat[:sc.sim_nmocap].copy())

    def sync(self, state: dict | None = None) -> float:
        """Copies a simulator state (default: now) and the simulator's body poses into the
        copy and runs its kinematics; returns the state's clock time."""
        state = self._snapshot() if state is None else state
        m, d, sc = self.scene.model, self.scene.data, self.scene
        sim_m = self.env.model
        m.body_pos[:sc.sim_nbody] = sim_m.body_pos
        m.body_quat[:sc.sim_nbody] = sim_m.body_quat
        d.qpos[:] = state["qpos"]
        d.qvel[:] = state["qvel"]
        if m.na:
            d.act[:] = state["act"]
        d.mocap_pos[:sc.sim_nmocap] = state["mocap_pos"]
        d.mocap_quat[:sc.sim_nmocap] = state["mocap_quat"]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_camlight(m, d)
        return float(state["time"])

    def render(self) -> tuple[np.ndarray, np.ndarray | None]:
        """(RGB, depth or None) of the copy's current state, without the sensor's effects."""
        r = self.renderer
        r.update_scene(self.scene.data, camera=self.scene.camera_id, scene_option=self.option)
        rgb = r.render().copy()
        depth = None
        if self.depth_on:
            r.enable_depth_rendering()
            depth = r.render().astype(np.float32)
            r.disable_depth_rendering()
        return rgb, depth

    def _delayed_state(self, latency: float) -> dict:
        now = self._snapshot()
        self.history.append(now)
        want = now["time"] - latency
        for state in reversed(self.history):
            if state["time"] <= want + 1e-6:  # float32 simulator times
                return state
        return self.history[0]

    def capture(self) -> Frame:
        """The next frame: the simulator's state of ``latency`` ago, rendered, with noise."""
        s = self.sensor
        latency = float(self.rng.uniform(*s.latency))
        stamp = self.sync(self._delayed_state(latency))
        rgb, depth = self.render()
        rgb, depth = self.degrade(rgb, depth)
        frame = Frame(rgb=rgb, stamp=stamp, intrinsics=self.intrinsics, depth=depth,
                      index=self.index, info={"latency": latency})
        self.index += 1
        return frame

    def degrade(self, rgb, depth):
        """The sensor's per-frame effects on a perfect render (`SensorModel`)."""
        s, rng = self.sensor, self.rng
        img = rgb.astype(np.float32) * rng.uniform(*s.exposure)
        sigma = rng.uniform(*s.blur)
        if sigma > 0.05:
            img = cv2.GaussianBlur(img, (0, 0), sigma)
        if s.noise_std > 0:
            img = img + rng.normal(0.0, s.noise_std, img.shape).astype(np.float32)
        rgb = np.clip(img + 0.5, 0, 255).astype(np.uint8)
        if depth is not None:
            depth = depth.copy()
            if s.depth_std > 0:
                depth += (s.depth_std * depth * depth
                          * rng.standard_normal(depth.shape)).astype(np.float32)
            if s.depth_dropout > 0:
                depth[rng.uniform(size=depth.shape) < s.depth_dropout] = 0.0
        return rgb, depth

    def close(self) -> None:
        self.renderer.close()
