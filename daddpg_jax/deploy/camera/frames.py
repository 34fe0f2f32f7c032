"""What a camera delivers (NumPy only): `Frame`, `Intrinsics`, the `Camera` protocol, and the
rigid-transform helpers of the camera path.

Conventions: images are RGB ``uint8`` [H, W, 3]; depth is ``float32`` [H, W] in metres along
the optical axis (0 where the sensor has no reading); pixel coordinates are OpenCV's (the
centre of the top-left pixel is (0, 0)); the camera frame is OpenCV's (x right, y down, z
along the optical axis); poses are 4x4 transforms ``T_a_b`` that map points of frame b into
frame a (``T_world_cam``: the camera's pose in the world frame of the policy, metres).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

TRACKING = ("hold", "predict")
"""the object tracker's modes (`daddpg_jax.deploy.camera.objects.ObjectTracker`; here, with
NumPy only, so that the robot client's ``--track`` names them without OpenCV)"""


class CameraError(RuntimeError):
    """A camera that cannot deliver a frame (no device, end of a file, timeout); one line."""


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera with OpenCV's distortion coefficients (k1, k2, p1, p2[, k3, ...])."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple = (0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def distortion(self) -> np.ndarray:
        return np.asarray(self.dist, float).reshape(-1)

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy_deg: float) -> Intrinsics:
        """A distortion-free camera with square pixels, the principal point at the image's
        centre and vertical field of view ``fovy_deg`` (what MuJoCo's renderer draws:
        fy = (H / 2) / tan(fovy / 2))."""
        f = 0.5 * height / math.tan(math.radians(fovy_deg) / 2.0)
        return cls(int(width), int(height), f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @classmethod
    def from_matrix(cls, width: int, height: int, K, dist=None) -> Intrinsics:
        K = np.asarray(K, float)
        d = tuple(float(x) for x in np.asarray(dist if dist is not None else np.zeros(5),
                                               float).reshape(-1))
        return cls(int(width), int(height), float(K[0, 0]), float(K[1, 1]), float(K[0, 2]),
                   float(K[1, 2]), d)

    def fovy_deg(self) -> float:
        return math.degrees(2.0 * math.atan(0.5 * self.height / self.fy))


@dataclass
class Frame:
    """One capture: ``rgb`` [H, W, 3] uint8, ``depth`` [H, W] float32 metres or None (0: no
    reading), ``stamp`` the capture time on the camera's monotonic clock (s), and the
    camera's ``intrinsics``. ``index`` counts the camera's frames from 0."""

    rgb: np.ndarray
    stamp: float
    intrinsics: Intrinsics
    depth: np.ndarray | None = None
    index: int = 0
    info: dict = field(default_factory=dict)

    @property
    def gray(self) -> np.ndarray:
        """The image as 8-bit luminance (ITU-R BT.601 weights)."""
        rgb = self.rgb.astype(np.float32)
        y = 0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]
        return np.clip(y + 0.5, 0, 255).astype(np.uint8)


@runtime_checkable
class Camera(Protocol):
    """What the robot side needs of a camera: ``capture()`` the next `Frame` (blocking;
    `CameraError` when none comes), its ``intrinsics``, and ``close()``."""

    intrinsics: Intrinsics

    def capture(self) -> Frame: ...

    def close(self) -> None: ...


# -- rigid transforms ---------------------------------------------------------------------------

def transform(R, t) -> np.ndarray:
    """The 4x4 transform of rotation ``R`` [3, 3] and translation ``t`` [3]."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, float)
    T[:3, 3] = np.asarray(t, float).reshape(3)
    return T


def invert(T) -> np.ndarray:
    T = np.asarray(T, float)
    R, t = T[:3, :3], T[:3, 3]
    return transform(R.T, -R.T @ t)


def apply(T, points) -> np.ndarray:
    """``T`` applied to points [..., 3]."""
    T = np.asarray(T, float)
    return np.asarray(points, float) @ T[:3, :3].T + T[:3, 3]


def rotvec_to_matrix(rv) -> np.ndarray:
    """Rodrigues: a rotation vector (rad) -> 3x3 rotation."""
    rv = np.asarray(rv, float).reshape(3)
    th = float(np.linalg.norm(rv))
    if th < 1e-12:
        return np.eye(3)
    k = rv / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def matrix_to_rotvec(R) -> np.ndarray:
    """A 3x3 rotation -> its rotation vector (rad), also near pi."""
    R = np.asarray(R, float)
    q = matrix_to_quat(R)
    w, v = q[0], q[1:]
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        return np.zeros(3)
    return v / s * 2.0 * math.atan2(s, w)


def matrix_to_quat(R) -> np.ndarray:
    """A 3x3 rotation -> unit quaternion (w, x, y, z) with w >= 0."""
    R = np.asarray(R, float)
    tr = np.trace(R)
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = math.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k]) * 2
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q = np.asarray(q, float)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def quat_to_matrix(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, float).reshape(4) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def yaw_matrix(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yaw_of(R) -> float:
    """The heading of a rotation's x axis about world z, rad."""
    R = np.asarray(R, float)
    return math.atan2(R[1, 0], R[0, 0])


def look_at(position, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_cam`` of a camera at ``position`` looking at ``target`` (OpenCV frame: z
    towards the target, x to the image's right, y down, the image's up towards ``up``)."""
    p, c = np.asarray(position, float), np.asarray(target, float)
    z = c - p
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: the viewing direction is parallel to 'up'")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return transform(np.stack([x, y, z], axis=1), p)
