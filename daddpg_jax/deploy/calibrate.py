"""Frame calibration (NumPy + standard library): each arm's base pose in the policy's world
frame from points on the table whose world positions are known (a printed board), touched with
the gripper's tool centre and read in the arm's base frame (``getActualTCPPose``).

    T, residuals = fit_base(points_world, tcp_base)         # least squares, >= 4 points
    write_calibration("cell.toml", {"left": entry(T_l, r_l), "right": entry(T_r, r_r)})

Two models: ``yaw`` (default; the base stands level: a turn about the vertical and a 3-D
offset, 4 parameters, as `mjx_envs.randomize` models a calibration error of ``base_offset`` and
``base_yaw``; solved in closed form) and ``full`` (any rotation, 6 parameters: Kabsch's SVD
solution with the reflection fixed; needs points that are not all on one line, and resolves the
tilt only as well as the points' spread allows). The residual of each point is the distance
between its known world position and the transformed measurement.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from daddpg_jax.deploy import robot
from daddpg_jax.deploy.limits import ARM_KEYS, LimitsError, RobotLimits

MIN_POINTS = 4
MODELS = ("yaw", "full")
MARKER = "# -- calibration (written by daddpg-calibrate; rerun it to replace this block) --"


class CalibrationError(ValueError):
    """Points that cannot give a calibration (too few, degenerate, non-finite); one line."""


def _points(name, p) -> np.ndarray:
    a = np.asarray(p, float)
    if a.ndim != 2 or a.shape[1] not in (3, 6):
        raise CalibrationError(f"{name} must be N rows of [x, y, z] (or UR poses [x, y, z, rx, "
                               f"ry, rz]), got shape {list(a.shape)}")
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{name} holds NaN or infinite values")
    return a[:, :3]


def fit_base(points_world, tcp_base, model: str = "yaw") -> tuple[np.ndarray, np.ndarray]:
    """(world <- base 4x4, residual per point [N] m) by least squares from N >= 4 points:
    ``points_world`` [N, 3] known positions, ``tcp_base`` [N, 3] (or [N, 6] poses) the tool
    centre measured on each in the base frame."""
    w, b = _points("points_world", points_world), _points("tcp_base", tcp_base)
    if model not in MODELS:
        raise CalibrationError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    if len(w) != len(b):
        raise CalibrationError(f"{len(w)} known points but {len(b)} measurements")
    if len(w) < MIN_POINTS:
        raise CalibrationError(f"at least {MIN_POINTS} points are needed, got {len(w)}")
    wc, bc = w.mean(0), b.mean(0)
    W, B = w - wc, b - bc
    spread = np.linalg.svd(B[:, :2] if model == "yaw" else B, compute_uv=False)
    if spread[1] < 1e-3 * math.sqrt(len(b)):  # all within ~1 mm of one line
        raise CalibrationError("the points lie on one line: spread them over the board")
    if model == "yaw":
        s = np.sum(B[:, 0] * W[:, 1] - B[:, 1] * W[:, 0])
        c = np.sum(B[:, 0] * W[:, 0] + B[:, 1] * W[:, 1])
        R = robot.rot_z(math.atan2(s, c))
    else:
        U, _, Vt = np.linalg.svd(B.T @ W)
        d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
        R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = wc - R @ bc
    residuals = np.linalg.norm(b @ R.T + T[:3, 3] - w, axis=-1)
    return T, residuals


def pose_error(T_est, T_true) -> tuple[float, float]:
    """(distance between the base origins, m; angle between the rotations, degrees)."""
    T_est, T_true = np.asarray(T_est, float), np.asarray(T_true, float)
    dR = T_est[:3, :3].T @ T_true[:3, :3]
    angle = math.degrees(math.acos(float(np.clip((np.trace(dR) - 1.0) / 2.0, -1.0, 1.0))))
    return float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])), angle


def entry(T, residuals) -> dict:
    """One arm's calibration table for the limits file (`RobotLimits.calibration`)."""
    T = np.asarray(T, float)
    res_mm = [round(float(r) * 1e3, 3) for r in residuals]
    return dict(base_pos=[round(float(x), 6) for x in T[:3, 3]],
                base_rotvec=[round(float(x), 8) for x in robot.matrix_to_rotvec(T[:3, :3])],
                residuals_mm=res_mm,
                rms_mm=round(float(np.sqrt(np.mean(np.square(res_mm)))), 3))


def _toml_block(calibration: dict) -> str:
    def arr(v):
        return "[" + ", ".join(repr(float(x)) for x in v) + "]"

    lines = [MARKER, "# Each arm's base pose in the world frame (world <- base: position, m, and "
             "rotation vector, rad),", "# with the residual of each calibration point, mm."]
    for arm in ARM_KEYS:
        c = calibration[arm]
        lines += ["", f"[calibration.{arm}]", f"base_pos = {arr(c['base_pos'])}",
                  f"base_rotvec = {arr(c['base_rotvec'])}",
                  f"residuals_mm = {arr(c['residuals_mm'])}", f"rms_mm = {float(c['rms_mm'])!r}"]
    return "\n".join(lines) + "\n"


def write_calibration(path, calibration: dict) -> RobotLimits:
    """Writes ``calibration`` ({"left": entry, "right": entry}) into the limits file ``path``
    (TOML: a block at the end, replacing an earlier one; JSON: the ``calibration`` field) and
    returns the limits read back. LimitsError (one line) if the result does not load; the file
    is then left as it was."""
    path = os.fspath(path)
    RobotLimits.load(path)  # a valid limits file to start from
    with open(path, encoding="utf-8") as f:
        old = f.read()
    if path.lower().endswith(".json"):
        d = json.loads(old)
        d["calibration"] = calibration
        new = json.dumps(d, indent=2) + "\n"
    else:
        head = old.split(MARKER, 1)[0].rstrip("\n")
        new = head + "\n\n" + _toml_block(calibration)
    root, ext = os.path.splitext(path)
    tmp = f"{root}.tmp{ext}"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(new)
    try:
        limits = RobotLimits.load(tmp)
    except LimitsError as e:
        os.remove(tmp)
        raise LimitsError(f"the calibration cannot be written into {path!r}: {e}") from None
    os.replace(tmp, path)
    return limits
