"""The camera in the robot client's loop (``daddpg-robot-client --goals --objects --camera``):
what the options build around the arms' env, and the camera's calibration for
``daddpg-calibrate --camera``. NumPy at import; the camera package (OpenCV; MuJoCo for the
simulated camera) is imported when a camera is asked for.

- ``--goals sampler`` (default): the goal sampler's goals, as without a camera. ``--goals
  tags``: each episode's goals are read from the Reach tags at reset, before the arms move
  (`TagGoals`; the median over a few frames); in simulation the tags are first put where the
  sampler's goals are (`SimCamera.place_targets`), and success is still judged against those
  true goals. A tag not seen holds the arms for the whole episode.
- ``--objects sim`` (default): the simulated cell's own object (ground truth). ``--objects
  camera-tag`` / ``camera-color``: the object from the camera every control period (its tag,
  or colour and depth), tracked (`daddpg_jax.deploy.camera.objects.CameraObjectSource`;
  ``--track hold``, the default, keeps the last pose while the object is hidden, as the
  paper's robot did; ``--track predict`` carries it forward at its estimated velocity, also
  over a late frame's age) and watched (`WatchedObjects`): a frame older than the limits'
  ``max_frame_age`` or an object not seen for longer than ``max_object_lost`` holds the arms
  (the observation's ``perception_fault``), as a stale arm reading does; such episodes count
  as failures.
- ``--camera sim`` (default with ``--arms sim`` / ``ur-sim``): the simulated cell rendered
  from the limits' camera pose every control period (`SimCamera`, no shadows, the sensor's
  noise from its own random stream); ``opencv`` / ``realsense``: a real camera (``--arms
  ur``). Ages are measured on the camera's clock: simulated seconds for the simulated camera
  (paced or ``--fast``), the monotonic clock for a real one.

The camera's pose comes from the limits file's ``[camera]`` table (the calibrated one); the
simulated camera can be mounted elsewhere (`SimOptions.pose_error`: moved after the
calibration), drop frames (`SimOptions.drop`) and lag (`SimOptions.sensor`'s latency), for
measuring what each does to a closed loop.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field

import numpy as np

from daddpg_jax.deploy.camera.frames import TRACKING

GOALS = ("sampler", "tags")
OBJECTS = ("sim", "camera-tag", "camera-color")
CAMERAS = ("sim", "opencv", "realsense")
CAMERA_STREAM = 0x43414D
"""second seed word of the simulated camera's own random stream ([seed, CAMERA_STREAM])"""
TAG_FRAMES = 3
"""frames whose median gives the episode's Reach targets"""


class PerceptionError(ValueError):
    """Perception options that do not fit together, or a camera that cannot be built (one
    line)."""


def add_arguments(p) -> None:
    """The robot client's perception flags (and ``--rerun``) on the argparse parser ``p``."""
    add = p.add_argument
    add("--goals", choices=GOALS, default="sampler",
        help="sampler: the goal sampler's goals (default); tags: read each episode's goals "
             "from the Reach tags at reset (a tag not seen holds the arms; docs/PERCEPTION.md)")
    add("--objects", choices=OBJECTS, default="sim",
        help="sim: the simulated cell's own object (default); camera-tag / camera-color: the "
             "object from the camera every control period, by its tag or by colour and depth "
             "(a frame older than the limits' max_frame_age or the object lost for longer "
             "than max_object_lost holds the arms)")
    add("--track", choices=TRACKING, default="hold",
        help="the object tracker (--objects camera-*): hold keeps the last pose while the "
             "object is hidden (default); predict carries it forward at its estimated "
             "velocity, also over a late frame's age")
    add("--camera", choices=CAMERAS, default=None,
        help="the camera (default: the limits file's [camera] kind, else sim): sim renders the "
             "simulated cell (--arms sim, ur-sim); opencv, realsense: a real camera (--arms ur)")
    add("--rerun", default=None, metavar="FILE.rrd",
        help="record the run for the Rerun viewer (pip install 'daddpg-jax[rerun]'): camera "
             "images with detections, targets and object poses (and the truth in "
             "simulation), commanded targets, limits boxes, safety holds, step times")


def check_options(goals: str, objects: str, camera: str | None, arms: str,
                  track: str = "hold") -> str | None:
    """One-line error text when the perception flags do not fit together or with ``--arms``,
    else None."""
    uses = goals == "tags" or objects != "sim"
    if track != "hold" and objects == "sim":
        return "--track predicts an object seen by the camera: use --objects camera-tag/color"
    if camera is not None and not uses:
        return "--camera needs --goals tags or --objects camera-tag/camera-color"
    if arms == "ur" and camera == "sim":
        return "--camera sim renders the simulator: use --arms sim or ur-sim (or a real camera)"
    if arms != "ur" and camera in ("opencv", "realsense"):
        return f"--camera {camera} sees a real cell: use --arms ur (or --camera sim)"
    if objects == "camera-color" and camera == "opencv":
        return "--objects camera-color needs a depth camera (--camera sim or realsense)"
    return None


@dataclass
class SimOptions:
    """The simulated camera's settings for a run: ``sensor`` (a `SensorModel`; None: its
    defaults), ``pose_error`` (dx, dy, dz m, rx, ry, rz deg: the true mount moved from the
    calibrated pose of the limits file, about the camera's optical centre), ``drop`` (the
    fraction of captures that deliver the previous frame again), ``shadows`` (off: the quick
    render, without shadows and without the floor's reflection; depth is rendered only for
    ``--objects camera-color``)."""

    sensor: object = None
    pose_error: tuple | None = None
    drop: float = 0.0
    shadows: bool = False


def moved_pose(T_world_cam, error) -> np.ndarray:
    """``T_world_cam`` moved by ``error`` (dx, dy, dz m in the world frame; rx, ry, rz deg, a
    rotation vector in the world frame about the optical centre)."""
    from daddpg_jax.deploy.camera.frames import rotvec_to_matrix  # lazy: the camera package

    e = np.asarray(error, float).reshape(6)
    T = np.asarray(T_world_cam, float).copy()
    T[:3, :3] = rotvec_to_matrix(np.radians(e[3:])) @ T[:3, :3]
    T[:3, 3] = T[:3, 3] + e[:3]
    return T


class DroppingCamera:
    """A camera that delivers its previous frame again for a fraction ``drop`` of captures
    (its own random stream ``seed``); the rest passes through."""

    def __init__(self, camera, drop: float, seed=0):
        self.camera, self.drop = camera, float(drop)
        self.rng = np.random.default_rng(seed)
        self.last = None
        self.dropped = 0

    def capture(self):
        if self.last is not None and self.rng.uniform() < self.drop:
            self.dropped += 1
            return self.last
        self.last = self.camera.capture()
        return self.last

    def reset(self):
        self.last = None
        if hasattr(self.camera, "reset"):
            self.camera.reset()

    def __getattr__(self, name):
        return getattr(self.camera, name)


class WatchedObjects:
    """An object source on a camera (`CameraObjectSource`) whose readings carry ``fault``:
    why the loop must hold (a frame older than ``max_frame_age`` s, the object not seen for
    longer than ``max_object_lost`` s, the camera failing), else None; and ``frame_age``."""

    def __init__(self, source, max_frame_age: float, max_object_lost: float, close=None):
        self.source = source
        self.max_frame_age, self.max_object_lost = float(max_frame_age), float(max_object_lost)
        self._close = close
        self.last: dict | None = None

    def reset(self, qpos) -> None:
        self.last = None
        self.source.reset(qpos)

    def observe_arms(self, grip) -> None:
        """The grippers' positions now, for a source that carries a held object with them."""
        self.source.observe_arms(grip)

    def read(self) -> dict:
        from daddpg_jax.deploy.camera.frames import CameraError  # lazy: the camera package

        try:
            r = dict(self.source.read())
        except CameraError as e:
            r = dict(self.source.tracker.update(None, self.source.now()))
            r.update(fault=f"camera: {' '.join(str(e).split())[:120]}", frame_age=math.inf)
            self.last = r
            return r
        frame = self.source.last_frame
        age = float(self.source.now() - frame.stamp)
        r["frame_age"] = age
        if age > self.max_frame_age:
            r["fault"] = (f"camera frame too old ({age * 1e3:.0f} ms > "
                          f"{self.max_frame_age * 1e3:.0f} ms)")
        elif not math.isfinite(r["age"]):
            r["fault"] = "object not seen by the camera"
        elif r["age"] > self.max_object_lost:
            r["fault"] = (f"object lost for {r['age']:.2f} s (> {self.max_object_lost:g} s)")
        else:
            r["fault"] = None
        self.last = r
        return r

    def close(self) -> None:
        if self._close is not None:
            self._close()


class TagGoals:
    """The episode's goals from the Reach tags (`targets_from_camera`, median over
    ``frames``) at the calibrated pose ``T_world_cam``; ``place``: put the tags where the
    sampler's goals are first (simulation); ``reset_camera``: this source starts the camera's
    episode (no camera object source does); ``park``: where the arms wait while the tags are
    read (world [2, 3]; `park_targets`), None: where they are."""

    def __init__(self, camera, T_world_cam, layout, frames: int = TAG_FRAMES,
                 place: bool = False, reset_camera: bool = True, close=None, park=None):
        self.camera, self.T_world_cam, self.layout = camera, np.asarray(T_world_cam), layout
        self.frames, self.place, self.reset_camera = int(frames), bool(place), reset_camera
        self.park = None if park is None else np.asarray(park, np.float32).reshape(2, 3)
        self._close = close
        self.last = None

    def read(self, goal, keepalive=None):
        """(the goals the policy sees [2, 3], NaN where a tag was not seen; the fault or
        None); ``keepalive()`` is called before each frame (the arms hold: their controllers'
        watchdog is kicked while the camera reads)."""
        from daddpg_jax.deploy.camera.frames import CameraError  # lazy: the camera package
        from daddpg_jax.deploy.camera.tags import targets_from_camera  # lazy: OpenCV

        if self.place:
            self.camera.place_targets(goal, self.layout)
        if self.reset_camera and hasattr(self.camera, "reset"):
            self.camera.reset()
        camera = self.camera if keepalive is None else _Keepalive(self.camera, keepalive)
        try:
            got = targets_from_camera(camera, self.T_world_cam, self.layout, frames=self.frames)
        except CameraError as e:
            return np.full((2, 3), np.nan), f"camera: {' '.join(str(e).split())[:120]}"
        self.last = got
        if got.complete:
            return got.targets, None
        missing = [int(self.layout.tags[i]) for i in range(2) if not got.found[i]]
        return got.targets, f"Reach tag(s) {sorted(set(missing))} not seen"

    def close(self) -> None:
        if self._close is not None:
            self._close()


class _Keepalive:
    """``camera`` whose every capture first calls ``keepalive()``."""

    def __init__(self, camera, keepalive):
        self.camera, self.keepalive = camera, keepalive

    def capture(self):
        self.keepalive()
        return self.camera.capture()


@dataclass
class Perception:
    """What ``--goals``, ``--objects`` and ``--camera`` build: called with the simulated
    cell (a `daddpg_jax.deploy.ursim.SimCell`; None on real arms) it returns (object source
    or None, goal source or None) for `daddpg_jax.deploy.arms.ArmsEnv`. ``limits``: the
    `RobotLimits` (the ``[camera]`` table, the ages); ``task``; ``seed``: the run's (the
    simulated camera's stream is [seed, CAMERA_STREAM]); ``sim``: `SimOptions`; ``track``:
    the object tracker's mode (`TRACKING`)."""

    goals: str
    objects: str
    camera_kind: str
    limits: object
    task: str
    seed: int = 0
    sim: SimOptions = field(default_factory=SimOptions)
    track: str = "hold"
    camera: object = None
    goal_source: object = None
    object_source: object = None

    def __post_init__(self):
        if self.goals not in GOALS or self.objects not in OBJECTS:
            raise PerceptionError(f"--goals must be one of {GOALS}, --objects one of {OBJECTS}")
        if self.track not in TRACKING:
            raise PerceptionError(f"--track must be one of {TRACKING}, got {self.track!r}")
        if self.objects != "sim":
            from daddpg_jax.deploy.camera.objects import geometry_for_task  # lazy: OpenCV

            if geometry_for_task(self.task) is None:
                raise PerceptionError(f"--objects {self.objects}: the {self.task!r} task has "
                                      f"no object for the camera")
        self.config = camera_config(self.limits, self.camera_kind)

    def __call__(self, cell=None):
        if cell is None and self.config.kind == "sim":
            raise PerceptionError("--camera sim renders the simulator: not with --arms ur")
        if cell is not None and self.config.kind != "sim":
            raise PerceptionError(f"--camera {self.config.kind} sees a real cell: not with "
                                  f"simulated arms")
        self.camera = self._camera(cell)
        T = self.config.T_world_cam
        objects = None
        if self.objects != "sim":
            from daddpg_jax.deploy.camera.objects import make_object_source  # lazy: OpenCV

            method = "tag" if self.objects == "camera-tag" else "colour"
            src = make_object_source(self.camera, self.task, T, method, self.track,
                                     place=None if cell is None else cell.reset)
            objects = WatchedObjects(src, self.limits.max_frame_age,
                                     self.limits.max_object_lost, close=self.close)
        goals = None
        if self.goals == "tags":
            goals = TagGoals(self.camera, T, self.config.target_layout, place=cell is not None,
                             reset_camera=objects is None, close=self.close,
                             park=park_targets(self.limits))
        self.object_source, self.goal_source = objects, goals
        return objects, goals

    def _camera(self, cell):
        from daddpg_jax.deploy.camera.factory import make_camera  # lazy: OpenCV, MuJoCo

        cfg = self.config
        if cfg.kind != "sim":
            from daddpg_jax.deploy.camera.frames import CameraError  # lazy: as above

            try:
                return make_camera(cfg)
            except (CameraError, OSError) as e:
                raise PerceptionError(f"camera: {' '.join(str(e).split())[:200]}") from None
        # lazy: MuJoCo's renderer loads only for the simulated camera
        from daddpg_jax.deploy.camera.sim_camera import SensorModel, SimCamera

        s = self.sim
        mount = cfg.T_world_cam if s.pose_error is None else moved_pose(cfg.T_world_cam,
                                                                        s.pose_error)
        true_cfg = _replace_pose(cfg, mount)
        stream = [int(self.seed), CAMERA_STREAM]
        cam = SimCamera(cell.env, true_cfg, SensorModel() if s.sensor is None else s.sensor,
                        seed=stream, shadows=s.shadows, depth=self.objects == "camera-color")
        if not s.shadows:  # the quick render: no shadows, no floor reflection (a second pass)
            import mujoco  # lazy: loaded already by the simulated camera

            cam.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        if s.drop > 0:
            cam = DroppingCamera(cam, s.drop, seed=[int(self.seed), CAMERA_STREAM, 1])
        return cam

    def close(self) -> None:
        cam, self.camera = self.camera, None
        if cam is not None:
            cam.close()


PARK_FRACTION = (0.05, 0.5, 0.9)
"""where in each arm's workspace box the arms wait while the Reach tags are read: near the
bases (x), the box's middle (y), high (z): behind the goal region as the camera sees it"""


def park_targets(limits) -> np.ndarray:
    """Each arm's wait while the tags are read (world [2, 3]): `PARK_FRACTION` of its box."""
    lo, hi = np.asarray(limits.workspace_low), np.asarray(limits.workspace_high)
    return (lo + np.asarray(PARK_FRACTION) * (hi - lo)).astype(np.float32)


def _replace_pose(cfg, T):
    return dataclasses.replace(cfg, T_world_cam=np.asarray(T, float))


def camera_config(limits, kind: str | None = None):
    """The `CameraConfig` of the limits' ``[camera]`` table (the nominal simulated mount
    without one), its kind replaced by ``kind`` when given; in simulation a table without a
    ``layout`` gets the per-arm layout (the sampler's two independent goals)."""
    try:  # lazy: the camera package needs OpenCV (the optional extra [camera])
        from daddpg_jax.deploy.camera.config import CameraConfigError, camera_from_limits
    except ImportError as e:
        raise PerceptionError(f"the camera needs OpenCV (pip install 'daddpg-jax[camera]'): "
                              f"{e}") from None
    table = dict(limits.camera or {})
    if kind is not None:
        table["kind"] = kind
    if table.get("kind", "sim") == "sim" and "layout" not in table:
        table["layout"] = "per-arm"
    try:
        return camera_from_limits({"camera": table})
    except CameraConfigError as e:
        raise PerceptionError(str(e)) from None


def from_options(opt, limits, task: str, sim: SimOptions | None = None):
    """The `Perception` of daddpg-robot-client's options ``opt`` (``goals``, ``objects``,
    ``camera``, ``track``, ``seed``) for ``task``, or None when no camera is used.
    PerceptionError."""
    goals, objects = getattr(opt, "goals", "sampler"), getattr(opt, "objects", "sim")
    if goals == "sampler" and objects == "sim":
        return None
    # headless rendering for the simulated camera; it takes effect only when MuJoCo is not
    # imported yet (the simulator is built after this)
    os.environ.setdefault("MUJOCO_GL", "egl")
    return Perception(goals, objects, getattr(opt, "camera", None), limits, task,
                      seed=getattr(opt, "seed", 0), sim=sim or SimOptions(),
                      track=getattr(opt, "track", "hold"))


# -- daddpg-calibrate --camera ------------------------------------------------------------------

def parse_numbers(text: str | None, n: int, flag: str):
    """The ``n`` comma-separated finite numbers of ``text`` (None: None); PerceptionError."""
    if text is None:
        return None
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != n or not all(math.isfinite(x) for x in v):
        raise PerceptionError(f"{flag} must be {n} comma-separated finite numbers, got "
                              f"{text!r}")
    return tuple(v)


def calibrate_camera(limits, kind: str | None = None, frames: int = 5, sim_error=None,
                     chessboard=(), pattern=(9, 6), square: float = 0.025):
    """(the ``[camera]`` table to write, the `CameraCalibration`, the report's lines): the
    camera's pose from ``frames`` frames of the tag board lying on the table
    (`calibrate_camera_pose`; refused with its `CalibrationError`), the intrinsics from a
    chessboard's images (``chessboard``: paths; `intrinsics_from_chessboard`) when given,
    else the device's (the simulated camera: its field of view). ``kind``: the camera
    (default the limits' ``[camera]`` kind, else sim); ``sim_error``: the simulated camera's
    true mount moved from the limits' pose (`moved_pose`), for a rehearsal."""
    from daddpg_jax.deploy.camera.calibration import (  # lazy: OpenCV
        calibrate_camera_pose,
        intrinsics_from_chessboard,
    )
    from daddpg_jax.deploy.camera.frames import matrix_to_rotvec  # lazy: the camera package

    cfg = camera_config(limits, kind)
    lines, intr = [], None
    if chessboard:
        import cv2  # lazy: OpenCV, as above

        images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in chessboard]
        if any(im is None for im in images):
            raise PerceptionError("--chessboard: an image cannot be read")
        intr, rms = intrinsics_from_chessboard(images, pattern, square)
        lines.append(f"intrinsics from {len(images)} chessboard images: fx {intr.fx:.1f} fy "
                     f"{intr.fy:.1f} cx {intr.cx:.1f} cy {intr.cy:.1f} px, RMS {rms:.2f} px")
    if intr is not None:
        cfg = dataclasses.replace(cfg, intrinsics=intr)
    captured = _board_frames(cfg, frames, sim_error)
    if intr is not None:
        captured = [dataclasses.replace(f, intrinsics=intr) for f in captured]
    cal = calibrate_camera_pose(captured)
    lines += cal.report_lines()
    table = dict(limits.camera or {})
    table.pop("look_at", None)
    table.update(kind=cfg.kind, position=[round(float(x), 6) for x in cal.T_world_cam[:3, 3]],
                 rotvec=[round(float(x), 8) for x in matrix_to_rotvec(cal.T_world_cam[:3, :3])],
                 width=int(captured[0].intrinsics.width),
                 height=int(captured[0].intrinsics.height))
    if intr is not None:
        table.update(fx=intr.fx, fy=intr.fy, cx=intr.cx, cy=intr.cy,
                     dist=[float(x) for x in intr.distortion])
    return table, cal, lines


def _board_frames(cfg, n: int, sim_error=None) -> list:
    """``n`` frames of the board from the camera of ``cfg`` (the simulated one: the default
    task's cell at home, the camera at the limits' mount moved by ``sim_error``, no noise)."""
    from daddpg_jax.deploy.camera.factory import make_camera  # lazy: OpenCV, MuJoCo

    if cfg.kind == "sim":
        # lazy: MuJoCo's renderer and the simulator load only for the simulated camera
        from daddpg_jax.deploy.camera.sim_camera import SensorModel, SimCamera
        from mjx_envs.numpy_env import NumpyDualArmEnv

        env = NumpyDualArmEnv()  # the default task's cell: no object in front of the board
        env.reset(np.random.default_rng(0))
        mount = cfg.T_world_cam if sim_error is None else moved_pose(cfg.T_world_cam, sim_error)
        cam = SimCamera(env, _replace_pose(cfg, mount), SensorModel(lighting=(1.0, 1.0),
                                                                     light_tilt_deg=0.0),
                        shadows=False)
    else:
        cam = make_camera(cfg)
    try:
        return [cam.capture() for _ in range(max(1, int(n)))]
    finally:
        cam.close()
