"""The task's object from the camera (NumPy + OpenCV): the bar (push, pick up) and the pot,
estimated from a frame in two ways, tracked over time, and served as an object source.

- `TagObjectEstimator`: a tag on the object (tag 20 centred on the bar's middle, tag 21 on the
  pot's lid in front of the knob): the object's pose is the tag's pose times the tag's known
  place on the object (`ObjectGeometry.tag_pos`), its two object points (the bar's necks, the
  pot's handles) follow from the object's geometry.
- `ColourObjectEstimator`: no tag; the object's top face (the bar, or the pot's lid) segmented
  by colour (HSV), its pixels back-projected with the depth image into the world, a plane
  fitted to them (the top face's normal), the centre below the face's centroid by the known
  height; the principal axis of the bar's face gives the yaw and the two ends. The pot's yaw
  comes from its two handles' colour (their pixels' principal axis, the handles told apart
  as seen from the lid's centre); while the grippers hide them (fewer than
  ``min_axis_pixels``, or one side less than half the other: one handle's own axis runs
  across the pot's), the lid gives the position alone and the tracker holds the yaw. A
  face seen shorter than ``min_extent`` of its known size counts as hidden.
- `ObjectTracker`: an alpha-beta filter of position and orientation (velocities from the
  sightings' capture times), which holds the last pose (``mode="hold"``, as the paper's robot
  did while the grippers hid its rod) or predicts it at constant velocity for up to
  ``predict_s`` (``mode="predict"``) when a frame has no sighting; "predict" also carries
  each sighting forward from its capture time to the present (a late frame). A frame
  delivered again (the same capture time) or out of order changes nothing. Every reading
  carries the age of the last real sighting (``age``, s) and whether this frame had one
  (``seen``).
- `CameraObjectSource`: the object source of `daddpg_jax.deploy.arms.ArmsEnv`: ``reset(qpos)``
  and ``read()`` returning the world-frame dict of
  `mjx_envs.observation.read_object_sensors` (plus ``age``, ``seen`` and ``source``).
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field

import cv2
import numpy as np

from daddpg_jax.deploy.camera.frames import (
    TRACKING,
    Frame,
    apply,
    invert,
    matrix_to_quat,
    matrix_to_rotvec,
    rotvec_to_matrix,
    transform,
    yaw_of,
)
from daddpg_jax.deploy.camera.tags import TagDetector, tag_poses
from mjx_envs import registry

GREEN = (0.15, 0.62, 0.22, 1.0)
MAGENTA = (0.80, 0.12, 0.70, 1.0)
HSV_GREEN = ((45, 90, 40), (85, 255, 255))
HSV_MAGENTA = ((140, 110, 40), (165, 255, 255))


@dataclass(frozen=True)
class ObjectGeometry:
    """What the camera path knows of an object (its frame: the body's, z up when it rests).

    ``points``: each arm's object point [2, 3] in the object frame; ``tag_id``, ``tag_size``,
    ``tag_pos``: the tag on it (face centre in the object frame, its axes the object's);
    ``top_z``: the height of its top face (bar) or lid (pot) above its centre; ``top_size``:
    that face's length along the object's y and x; ``colours``: geom name -> RGBA of the
    simulated copy; ``top_hsv`` / ``axis_hsv``: the HSV ranges (OpenCV's 0-180 hue) of the
    top face and of the parts whose principal axis gives the yaw (None: the top face's)."""

    name: str
    body: str
    scenes: tuple
    points: tuple
    tag_id: int
    tag_size: float
    tag_pos: tuple
    top_z: float
    top_size: tuple
    colours: dict = field(default_factory=dict)
    top_hsv: tuple = ()
    axis_hsv: tuple | None = None

    def colour_of(self, geom: str):
        return self.colours.get(geom, self.colours.get("*", (0.5, 0.5, 0.5, 1.0)))

    @property
    def T_obj_tag(self) -> np.ndarray:
        return transform(np.eye(3), self.tag_pos)

    def object_points(self, pos, R) -> np.ndarray:
        return apply(transform(R, pos), np.asarray(self.points, float))


BAR = ObjectGeometry(
    name="bar", body="bar", scenes=("scene_push.xml", "scene_pickup.xml"),
    points=((0.0, 0.135, 0.0), (0.0, -0.135, 0.0)), tag_id=20, tag_size=0.064,
    tag_pos=(0.0, 0.0, 0.021), top_z=0.02, top_size=(0.40, 0.10), colours={"*": GREEN},
    top_hsv=(HSV_GREEN,))
POT = ObjectGeometry(
    name="pot", body="pot", scenes=("scene_pot.xml",),
    points=((0.0, 0.095, 0.02), (0.0, -0.095, 0.02)), tag_id=21, tag_size=0.04,
    tag_pos=(0.045, 0.0, 0.054), top_z=0.053, top_size=(0.144, 0.144),
    colours={"pot_lid": GREEN, "pot_handle_l": MAGENTA, "pot_handle_r": MAGENTA,
             "*": (0.55, 0.58, 0.62, 1.0), "pot_knob": (0.15, 0.15, 0.15, 1.0)},
    top_hsv=(HSV_GREEN,), axis_hsv=(HSV_MAGENTA,))
GEOMETRIES = (BAR, POT)


def geometry_for_scene(scene: str) -> ObjectGeometry | None:
    """The object of a scene file (None: no object, e.g. reach)."""
    return next((g for g in GEOMETRIES if scene in g.scenes), None)


def geometry_for_task(task: str) -> ObjectGeometry | None:
    """The object of a registered task, by its body (`mjx_envs.registry.OBJECTS`; None: no
    object, or one the camera does not know)."""
    obj = registry.OBJECTS.get(task)
    return None if obj is None else next((g for g in GEOMETRIES if g.body == obj[1]), None)


@dataclass
class ObjectEstimate:
    """One sighting: the object's centre ``pos`` [3] and orientation ``R`` [3, 3] (world),
    its object points [2, 3], the capture time, and how it was found. ``has_yaw`` False: only
    the position was seen (the pot's lid with both handles in the grippers); ``R`` is then
    level with an arbitrary yaw and the tracker keeps its own."""

    pos: np.ndarray
    R: np.ndarray
    points: np.ndarray
    stamp: float
    source: str
    quality: float = 0.0
    has_yaw: bool = True

    @property
    def quat(self) -> np.ndarray:
        return matrix_to_quat(self.R)

    @property
    def yaw(self) -> float:
        return yaw_of(self.R)


class TagObjectEstimator:
    """The object from its tag (see the module doc); ``T_world_cam``: the camera's
    calibrated pose."""

    source = "tag"

    def __init__(self, geometry: ObjectGeometry, T_world_cam, detector: TagDetector | None = None):
        self.geometry = geometry
        self.T_world_cam = np.asarray(T_world_cam, float)
        self.detector = TagDetector() if detector is None else detector
        self._T_tag_obj = invert(geometry.T_obj_tag)

    def estimate(self, frame: Frame, poses: dict | None = None) -> ObjectEstimate | None:
        g = self.geometry
        if poses is None:
            poses = tag_poses(frame, self.detector, self.T_world_cam, {g.tag_id: g.tag_size})
        pose = poses.get(g.tag_id)
        if pose is None:
            return None
        T = pose.T_world_tag @ self._T_tag_obj
        R, p = T[:3, :3], T[:3, 3]
        return ObjectEstimate(p.copy(), R.copy(), g.object_points(p, R), frame.stamp, "tag",
                              pose.error_px)


# -- colour -------------------------------------------------------------------------------------

def hsv_mask(rgb: np.ndarray, ranges) -> np.ndarray:
    """uint8 mask of the pixels inside any of the HSV ``ranges`` ((lo, hi), ...)."""
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    if len(ranges) == 2 and np.ndim(ranges[0]) == 1:
        ranges = (ranges,)
    mask = np.zeros(rgb.shape[:2], np.uint8)
    for lo, hi in ranges:
        mask |= cv2.inRange(hsv, np.array(lo, np.uint8), np.array(hi, np.uint8))
    return mask


def back_project(frame: Frame, mask: np.ndarray, T_world_cam) -> np.ndarray:
    """World points [N, 3] of the masked pixels that have a depth reading."""
    if frame.depth is None:
        raise ValueError("colour estimation needs a depth image (a camera with depth)")
    v, u = np.nonzero(mask)
    z = frame.depth[v, u].astype(float)
    ok = z > 0
    u, v, z = u[ok], v[ok], z[ok]
    it = frame.intrinsics
    px = np.stack([u, v], axis=1).astype(float)
    if np.any(it.distortion):
        px = cv2.undistortPoints(px.reshape(-1, 1, 2), it.matrix, it.distortion,
                                 P=it.matrix).reshape(-1, 2)
    x = (px[:, 0] - it.cx) / it.fx * z
    y = (px[:, 1] - it.cy) / it.fy * z
    return apply(T_world_cam, np.stack([x, y, z], axis=1))


def _plane(points, up=(0.0, 0.0, 1.0)):
    """(centroid, unit normal towards ``up``) of the least-squares plane through points."""
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    n = vt[2]
    return c, (n if n @ np.asarray(up) >= 0 else -n)


def top_face(points, band: float = 0.008, final_band: float = 0.004):
    """(points of the top face, centroid, normal): those within ``band`` m of the highest
    part, a plane fitted to them, then those within ``final_band`` of that plane."""
    h = points[:, 2]
    keep = points[np.abs(h - np.percentile(h, 98.0)) <= band]
    if len(keep) < 8:
        return keep, points.mean(axis=0), np.array([0.0, 0.0, 1.0])
    c, n = _plane(keep)
    near = points[np.abs((points - c) @ n) <= final_band]
    if len(near) >= 8:
        keep = near
        c, n = _plane(keep)
    return keep, c, n


def _axis(points, normal, toward=(0.0, 1.0, 0.0)):
    """(the principal direction of ``points`` within the plane of ``normal``, turned towards
    ``toward``; the points' extent along it (1st to 99th percentile); the offset of that
    extent's middle from the points' mean along it)."""
    q = points - points.mean(axis=0)
    q = q - np.outer(q @ normal, normal)
    _, _, vt = np.linalg.svd(q, full_matrices=False)
    a = vt[0] - (vt[0] @ normal) * normal
    a /= np.linalg.norm(a)
    if a @ np.asarray(toward) < 0:
        a = -a
    s = q @ a
    lo, hi = np.percentile(s, 1.0), np.percentile(s, 99.0)
    return a, float(hi - lo), float(0.5 * (lo + hi))


def _radial_axis(points, centre, normal, toward=(0.0, 1.0, 0.0)):
    """The direction from ``centre`` to ``points`` within the plane of ``normal``, as an axis
    (the principal direction of their unit radial vectors: parts on opposite sides agree, and
    one part alone still gives it, where a part's own principal direction would be its
    length), turned towards ``toward``."""
    q = points - centre
    q = q - np.outer(q @ normal, normal)
    r = np.linalg.norm(q, axis=1)
    u = q[r > 1e-6] / r[r > 1e-6, None]
    _, vecs = np.linalg.eigh(u.T @ u)
    a = vecs[:, -1] - (vecs[:, -1] @ normal) * normal
    a /= np.linalg.norm(a)
    return -a if a @ np.asarray(toward) < 0 else a


def _middle(s) -> float:
    return float(0.5 * (np.percentile(s, 1.0) + np.percentile(s, 99.0)))


class ColourObjectEstimator:
    """The object from a colour segmentation and depth (see the module doc)."""

    source = "colour"

    def __init__(self, geometry: ObjectGeometry, T_world_cam, min_pixels: int = 40,
                 min_extent: float = 0.8, erode: int = 1, min_axis_pixels: int = 100):
        self.geometry = geometry
        self.T_world_cam = np.asarray(T_world_cam, float)
        self.min_pixels, self.min_extent, self.erode = int(min_pixels), float(min_extent), erode
        self.min_axis_pixels = int(min_axis_pixels)

    def _points(self, frame: Frame, ranges) -> np.ndarray:
        mask = hsv_mask(frame.rgb, ranges)
        if self.erode:
            mask = cv2.erode(mask, np.ones((2 * self.erode + 1,) * 2, np.uint8))
        return back_project(frame, mask, self.T_world_cam)

    def estimate(self, frame: Frame) -> ObjectEstimate | None:
        g = self.geometry
        pts = self._points(frame, g.top_hsv)
        if len(pts) < self.min_pixels:
            return None
        face, c, n = top_face(pts)
        if len(face) < self.min_pixels:
            return None
        if g.axis_hsv is None:
            a, extent, _ = _axis(face, n)  # the face's length
            if extent < self.min_extent * g.top_size[0]:
                return None
        else:
            parts = self._points(frame, g.axis_hsv)
            if len(parts) < self.min_axis_pixels:  # the handles in the grippers: the lid alone
                return self._lid_only(face, c, n, frame)
            # the handles told apart as seen from the lid's centre; with both in view, their
            # pixels' principal axis (one handle's alone runs across the pot's axis)
            side = (parts - c) @ _radial_axis(parts, c, n) > 0
            if min(side.sum(), (~side).sum()) < 0.5 * max(side.sum(), (~side).sum()):
                return self._lid_only(face, c, n, frame)  # a handle half hidden: no yaw
            a, _, _ = _axis(parts, n)
            # the grippers at the handles hide the face along the axis, not across it
            if np.ptp((face - c) @ np.cross(n, a)) < self.min_extent * g.top_size[1]:
                return None
        # the middle of the face's extent along and across the axis, not its centroid: the
        # ends stay in view when a gripper hides a neck, and the strip of a side face that
        # the band lets in lies within the face's outline
        b = np.cross(n, a)
        q = face - c
        centre_face = c + _middle(q @ a) * a + _middle(q @ b) * b
        pos = centre_face - g.top_z * n
        x = np.cross(a, n)
        R = np.stack([x / np.linalg.norm(x), a, n], axis=1)
        return ObjectEstimate(pos, R, g.object_points(pos, R), frame.stamp, "colour",
                              float(len(face)))

    def _lid_only(self, face, c, n, frame) -> ObjectEstimate | None:
        """The position from a round face seen whole (its extent in two directions), no
        yaw."""
        g = self.geometry
        a, extent, _ = _axis(face, n)
        b = np.cross(n, a)
        q = face - c
        if min(extent, float(np.ptp(q @ b))) < self.min_extent * min(g.top_size):
            return None
        pos = c + _middle(q @ a) * a + _middle(q @ b) * b - g.top_z * n
        R = np.stack([np.cross(a, n) / np.linalg.norm(np.cross(a, n)), a, n], axis=1)
        return ObjectEstimate(pos, R, g.object_points(pos, R), frame.stamp, "colour",
                              float(len(face)), has_yaw=False)


# -- tracking -----------------------------------------------------------------------------------

def _zeros_reading() -> dict:
    z3 = np.zeros(3, np.float32)
    return {"pos": z3, "quat": np.array([1, 0, 0, 0], np.float32), "linvel": z3,
            "angvel": z3, "object_point": np.zeros((2, 3), np.float32), "present": True,
            "age": math.inf, "seen": False, "source": "none"}


class ObjectTracker:
    """An alpha-beta filter of an object's position and orientation, with velocities; holds or
    predicts while the object is hidden (see the module doc). ``alpha``/``beta``: the filter's
    gains (1, 0: each sighting taken as is, no velocity); ``max_speed``/``max_turn``: larger
    velocity estimates are clipped (m/s, rad/s); a sighting more than ``max_gap`` s after the
    last one starts the filter again."""

    MODES = TRACKING

    def __init__(self, geometry: ObjectGeometry, mode: str = "hold", alpha: float = 0.7,
                 beta: float = 0.3, predict_s: float = 0.5, max_speed: float = 2.0,
                 max_turn: float = 6.0, max_gap: float = 0.5):
        if mode not in self.MODES:
            raise ValueError(f"mode must be one of {self.MODES}, got {mode!r}")
        self.geometry, self.mode = geometry, mode
        self.alpha, self.beta, self.predict_s = float(alpha), float(beta), float(predict_s)
        self.max_speed, self.max_turn = float(max_speed), float(max_turn)
        self.max_gap = float(max_gap)
        self.reset()

    def reset(self) -> None:
        self.pos = self.R = None
        self.vel, self.omega = np.zeros(3), np.zeros(3)
        self.t = self.seen_at = -math.inf
        self.source = "none"

    def _clip(self, v, top):
        n = float(np.linalg.norm(v))
        return v * (top / n) if n > top else v

    def _predict(self, dt: float):
        return self.pos + self.vel * dt, rotvec_to_matrix(self.omega * dt) @ self.R

    def update(self, est: ObjectEstimate | None, now: float | None = None) -> dict:
        """Feeds one frame's sighting (None: not seen) and returns the reading at ``now``
        (default: the sighting's time, or the last state's)."""
        if est is not None:
            self._correct(est)
        if self.pos is None:
            return _zeros_reading()
        now = self.t if now is None else max(float(now), self.t)
        age = now - self.seen_at
        if est is None and self.mode == "hold":
            pos, R = self._predict(0.0)  # hidden: the last pose, standing still
            vel, omega = np.zeros(3), np.zeros(3)
        elif est is None and age > self.predict_s:
            pos, R = self._predict(self.predict_s)  # predicted as far as allowed, then held
            vel, omega = np.zeros(3), np.zeros(3)
        elif self.mode == "predict":
            pos, R = self._predict(now - self.t)  # to the present from the capture time
            vel, omega = self.vel, self.omega
        else:
            pos, R = self._predict(0.0)
            vel, omega = self.vel, self.omega
        return {"pos": pos.astype(np.float32), "quat": matrix_to_quat(R).astype(np.float32),
                "linvel": vel.astype(np.float32), "angvel": omega.astype(np.float32),
                "object_point": self.geometry.object_points(pos, R).astype(np.float32),
                "present": True, "age": float(age), "seen": est is not None,
                "source": self.source}

    def _correct(self, est: ObjectEstimate) -> None:
        t = float(est.stamp)
        if self.pos is not None and t <= self.t:
            return  # a frame delivered again (a dropped capture) or one out of order: no news
        if self.pos is None and not est.has_yaw:
            return  # a position without a yaw cannot start the track
        pos, R = np.asarray(est.pos, float).copy(), np.asarray(est.R, float).copy()
        if not est.has_yaw:  # the face's normal seen, the yaw held from the track
            n = R[:, 2]
            self.omega = np.zeros(3)
            a = self.R[:, 1]
            a = a - (a @ n) * n
            a /= max(float(np.linalg.norm(a)), 1e-9)
            R = np.stack([np.cross(a, n), a, n], axis=1)
        if self.pos is None or t - self.seen_at > self.max_gap:
            # the first sighting, or one after a long gap: taken as is, without a velocity
            self.pos, self.R = pos, R
            self.vel, self.omega = np.zeros(3), np.zeros(3)
        else:
            dt = t - self.t
            pos_p, R_p = self._predict(dt)
            r = pos - pos_p
            e = matrix_to_rotvec(R @ R_p.T)
            self.pos = pos_p + self.alpha * r
            self.R = rotvec_to_matrix(self.alpha * e) @ R_p
            self.vel = self._clip(self.vel + self.beta / dt * r, self.max_speed)
            self.omega = self._clip(self.omega + self.beta / dt * e, self.max_turn)
        self.t = self.seen_at = max(t, self.t)
        self.source = est.source


HOLD_RADIUS = 0.03
"""an object point this close to a gripper (m) at a sighting's capture time is held by it"""
GRIP_HISTORY = 64
"""grippers' positions kept (control periods: 2.5 s at 25 Hz, more than any frame's age)"""


class CameraObjectSource:
    """An object source (``reset(qpos)``, ``read()``) on a camera, an estimator and a
    tracker. ``place``: called with the episode's drawn start ``qpos`` at reset (a simulated
    cell's ``reset``; on a robot None: a person places the object); ``now``: the clock of
    the camera's stamps (default the camera's ``now`` when it has one, else
    ``time.monotonic``); ``warmup``: frames read at reset until a first sighting."""

    def __init__(self, camera, estimator, tracker: ObjectTracker | None = None, place=None,
                 now=None, warmup: int = 3):
        self.camera, self.estimator = camera, estimator
        self.tracker = ObjectTracker(estimator.geometry) if tracker is None else tracker
        self.place = place
        self.now = now if now is not None else getattr(camera, "now", time.monotonic)
        self.warmup = int(warmup)
        self.last_frame: Frame | None = None
        self.last_estimate: ObjectEstimate | None = None
        self._grips: deque = deque(maxlen=GRIP_HISTORY)

    def reset(self, qpos) -> None:
        if self.place is not None:
            self.place(qpos)
        if hasattr(self.camera, "reset"):
            self.camera.reset()
        self.tracker.reset()
        self._grips.clear()
        for _ in range(self.warmup):
            if self.read()["seen"]:
                break

    def observe_arms(self, grip) -> None:
        """The grippers' positions [2, 3] (world) at this moment of the camera's clock: in
        predict mode an object held by both grippers moves with them from its last sighting's
        capture time to the present (`carried`)."""
        self._grips.append((float(self.now()), np.asarray(grip, float).reshape(2, 3).copy()))

    def read(self) -> dict:
        frame = self.camera.capture()
        est = self.estimator.estimate(frame)
        self.last_frame, self.last_estimate = frame, est
        r = self.tracker.update(est, self.now())
        if self.tracker.mode == "predict" and self.tracker.pos is not None:
            r = self.carried(r)
        return r

    def _grips_at(self, t: float):
        """The grippers' positions at ``t``, interpolated between the observations around it
        (the last one after them; None: none at or before ``t``)."""
        before = None
        for when, grip in self._grips:
            if when >= t - 1e-9:
                if before is None or when - before[0] < 1e-9:
                    return grip if abs(when - t) < 1e-9 else None
                w = (t - before[0]) / (when - before[0])
                return (1.0 - w) * before[1] + w * grip
            before = (when, grip)
        return None if before is None else before[1]

    def carried(self, reading: dict) -> dict:
        """``reading`` with the object moved as the grippers moved since the last sighting's
        capture time, when each of its two points was within `HOLD_RADIUS` of a different
        gripper then (the arms' readings have no camera latency); else unchanged."""
        tr, now = self.tracker, float(self.now())
        then, grips = self._grips_at(tr.t), self._grips_at(now)
        if then is None or grips is None or now <= tr.t:
            return reading
        points = tr.geometry.object_points(tr.pos, tr.R)
        d = np.linalg.norm(points[:, None, :] - then[None, :, :], axis=-1)  # [point, arm]
        near = d.argmin(axis=1)
        if near[0] == near[1] or not np.all(d.min(axis=1) < HOLD_RADIUS):
            return reading
        shift = (grips - then)[near].mean(axis=0)
        pos = tr.pos + shift
        out = dict(reading)
        out.update(pos=pos.astype(np.float32),
                   quat=matrix_to_quat(tr.R).astype(np.float32),
                   linvel=(shift / (now - tr.t)).astype(np.float32),
                   object_point=tr.geometry.object_points(pos, tr.R).astype(np.float32))
        return out


def make_object_source(camera, task: str, T_world_cam, method: str = "tag",
                       mode: str = "hold", place=None, detector: TagDetector | None = None
                       ) -> CameraObjectSource:
    """A `CameraObjectSource` for ``task`` (push, pickup, pot) on ``camera`` at the
    calibrated pose ``T_world_cam``: ``method`` "tag" (the object's tag) or "colour" (colour
    and depth); ``mode``: the tracker's "hold" or "predict"; ``place``: see
    `CameraObjectSource`."""
    geometry = geometry_for_task(task)
    if geometry is None:
        raise ValueError(f"task {task!r} has no object for the camera (push, pickup, pot)")
    if method == "tag":
        est = TagObjectEstimator(geometry, T_world_cam, detector)
    elif method == "colour":
        est = ColourObjectEstimator(geometry, T_world_cam)
    else:
        raise ValueError(f"method must be 'tag' or 'colour', got {method!r}")
    return CameraObjectSource(camera, est, ObjectTracker(geometry, mode), place=place)
