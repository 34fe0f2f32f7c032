"""The camera's settings (NumPy only): `CameraConfig`, read from the ``[camera]`` table of a
robot limits file by `camera_from_limits`, with a nominal simulated mount when there is none.

    [camera]
    kind = "sim"                      # sim | opencv | realsense
    position = [0.95, 0.0, 1.20]      # the camera's optical centre, world frame, m
    look_at = [0.32, 0.0, 0.42]       # what it looks at (or rotvec = [rx, ry, rz]: the
                                      # rotation world <- camera, OpenCV's camera frame)
    width = 640
    height = 480
    fovy_deg = 45.0                   # sim; a real camera reports its own intrinsics
    device = "0"                      # opencv: a device index or a video file; realsense:
                                      # a serial number ("" = the first one)
    layout = "paper"                  # Reach targets: "paper" (tag 0) or "per-arm" (tags 1, 2)
    # optional, a real camera's intrinsics when the device's are not to be used:
    # fx = 600.0, fy = 600.0, cx = 319.5, cy = 239.5, dist = [k1, k2, p1, p2, k3]

A pose in the file is a mount (where the simulated camera renders from, or a real camera's
pose from `daddpg_jax.deploy.camera.calibration.calibrate_camera_pose`); without one the
nominal mount `NOMINAL_POSITION` / `NOMINAL_LOOK_AT` is used. Without a ``layout`` the Reach
targets are the paper's: 10 cm above one tag, one to each side (`tags.PAPER_LAYOUT`); a
simulated run whose targets must be the goal sampler's uses ``layout = "per-arm"``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from daddpg_jax.deploy.camera.frames import Intrinsics, look_at, rotvec_to_matrix, transform
from daddpg_jax.deploy.camera.tags import PAPER_LAYOUT, PER_ARM_LAYOUT, TargetLayout

KINDS = ("sim", "opencv", "realsense")
NOMINAL_POSITION = (0.95, 0.0, 1.20)
"""the nominal mount: in front of the table (x), centred, 0.8 m above the table top"""
NOMINAL_LOOK_AT = (0.32, 0.0, 0.42)
NOMINAL_FOVY_DEG = 45.0
LAYOUTS = {"per-arm": PER_ARM_LAYOUT, "paper": PAPER_LAYOUT}
MAX_COORD = 3.0
MAX_SIZE = 4096
_KEYS = {"kind", "position", "look_at", "rotvec", "width", "height", "fovy_deg", "device",
         "layout", "fx", "fy", "cx", "cy", "dist"}


class CameraConfigError(ValueError):
    """A ``[camera]`` value that is missing, malformed or out of range (one line)."""


def nominal_pose() -> np.ndarray:
    """``T_world_cam`` of the nominal mount."""
    return look_at(NOMINAL_POSITION, NOMINAL_LOOK_AT)


@dataclass(frozen=True)
class CameraConfig:
    """Which camera, where it is (``T_world_cam``; ``mounted``: given in the file, else the
    nominal mount), its image size, the simulated camera's field of view, a real camera's
    intrinsics when given (else the device's), the device, and the Reach target layout."""

    kind: str = "sim"
    T_world_cam: np.ndarray = field(default_factory=nominal_pose)
    width: int = 640
    height: int = 480
    fovy_deg: float = NOMINAL_FOVY_DEG
    intrinsics: Intrinsics | None = None
    device: str = "0"
    layout: str = "paper"
    mounted: bool = False

    @property
    def target_layout(self) -> TargetLayout:
        return LAYOUTS[self.layout]

    def sim_intrinsics(self) -> Intrinsics:
        return Intrinsics.from_fovy(self.width, self.height, self.fovy_deg)


def _vec(table, key, n=3) -> np.ndarray:
    v = table[key]
    try:
        out = np.asarray(v, float).reshape(-1)
    except (TypeError, ValueError):
        raise CameraConfigError(f"camera.{key} must be {n} numbers, got {v!r}") from None
    if out.shape != (n,) or not np.all(np.isfinite(out)):
        raise CameraConfigError(f"camera.{key} must be {n} finite numbers, got {v!r}")
    return out


def _number(table, key, lo, hi) -> float:
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
            or not lo <= v <= hi:
        raise CameraConfigError(f"camera.{key} must be a number in [{lo}, {hi}], got {v!r}")
    return float(v)


def _pose(table) -> tuple[np.ndarray, bool]:
    if "position" not in table:
        if "look_at" in table or "rotvec" in table:
            raise CameraConfigError("camera: look_at/rotvec given without position")
        return nominal_pose(), False
    p = _vec(table, "position")
    if np.any(np.abs(p) > MAX_COORD):
        raise CameraConfigError(f"camera.position must be within {MAX_COORD} m of the origin")
    if ("look_at" in table) == ("rotvec" in table):
        raise CameraConfigError("camera: give exactly one of look_at and rotvec with position")
    if "look_at" in table:
        c = _vec(table, "look_at")
        if np.linalg.norm(c - p) < 0.05:
            raise CameraConfigError("camera.look_at must be at least 5 cm from position")
        try:
            return look_at(p, c), True
        except ValueError as e:
            raise CameraConfigError(f"camera: {e}") from None
    return transform(rotvec_to_matrix(_vec(table, "rotvec")), p), True


def _intrinsics(table, width, height) -> Intrinsics | None:
    given = [k for k in ("fx", "fy", "cx", "cy") if k in table]
    if not given:
        if "dist" in table:
            raise CameraConfigError("camera.dist given without fx, fy, cx, cy")
        return None
    if len(given) != 4:
        raise CameraConfigError("camera: give all of fx, fy, cx, cy (or none)")
    fx, fy = (_number(table, k, 1.0, 1e5) for k in ("fx", "fy"))
    cx, cy = _number(table, "cx", 0.0, width), _number(table, "cy", 0.0, height)
    dist = np.zeros(5)
    if "dist" in table:
        d = np.asarray(table["dist"], float).reshape(-1)
        if d.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(d)):
            raise CameraConfigError("camera.dist must be 4, 5, 8, 12 or 14 finite numbers")
        dist = d
    return Intrinsics(width, height, fx, fy, cx, cy, tuple(float(x) for x in dist))


def camera_from_limits(mapping: Mapping | None) -> CameraConfig:
    """The `CameraConfig` of a limits mapping's ``[camera]`` table (the whole parsed limits
    file, or None): the nominal simulated mount for what it does not
    set, the paper's target layout. `CameraConfigError` (one line) for an unknown key or a bad
    value."""
    table = {} if mapping is None else mapping.get("camera", {})
    if not isinstance(table, Mapping):
        raise CameraConfigError(f"camera must be a table, got {type(table).__name__}")
    unknown = sorted(set(table) - _KEYS)
    if unknown:
        raise CameraConfigError(f"camera: unknown keys {unknown} (known: {sorted(_KEYS)})")
    kind = table.get("kind", "sim")
    if kind not in KINDS:
        raise CameraConfigError(f"camera.kind must be one of {list(KINDS)}, got {kind!r}")
    width = int(_number(table, "width", 16, MAX_SIZE)) if "width" in table else 640
    height = int(_number(table, "height", 16, MAX_SIZE)) if "height" in table else 480
    fovy = _number(table, "fovy_deg", 5.0, 150.0) if "fovy_deg" in table else NOMINAL_FOVY_DEG
    layout = table.get("layout", "paper")
    if layout not in LAYOUTS:
        raise CameraConfigError(f"camera.layout must be one of {sorted(LAYOUTS)}, got "
                                f"{layout!r}")
    device = table.get("device", "0")
    if not isinstance(device, (str, int)) or isinstance(device, bool):
        raise CameraConfigError(f"camera.device must be a string or an index, got {device!r}")
    T, mounted = _pose(table)
    return CameraConfig(kind=kind, T_world_cam=T, width=width, height=height, fovy_deg=fovy,
                        intrinsics=_intrinsics(table, width, height), device=str(device),
                        layout=layout, mounted=mounted)

