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
from daddpg_jax.deploy.arms import base_transform, invert, receive_only
from daddpg_jax.deploy.limits import ARM_KEYS, LimitsError, RobotLimits
from daddpg_jax.deploy.ur3 import BASE_POS, BASE_YAW

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


# ---------------------------------------------------------------- the readings ---------------

def read_points(path: str, what: str) -> dict:
    """{"left": [n, 3+], "right": [n, 3+]} of a JSON points file (`what`: the flag that named
    it); CalibrationError (one line) if unreadable or malformed."""
    try:
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
    except (OSError, ValueError) as e:
        raise CalibrationError(f"cannot read {what} {path!r}: "
                               f"{getattr(e, 'strerror', None) or e}") from None
    if not isinstance(d, dict) or set(d) != set(ARM_KEYS):
        raise CalibrationError(f"{what} {path!r} must hold a 'left' and a 'right' "
                               f"list of points")
    try:
        return {a: np.asarray(d[a], float) for a in ARM_KEYS}
    except (TypeError, ValueError):
        raise CalibrationError(f"{what} {path!r}: every point must be a list of "
                               f"numbers") from None


def parse_base_error(text: str):
    """(offset [2, 3] m, yaw [2] rad) of --sim-base-error; CalibrationError if malformed."""
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 8 or not np.all(np.isfinite(v)) or max(abs(x) for x in v) > 30:
        raise CalibrationError("--sim-base-error must be 8 finite numbers: dx,dy,dz "
                               "(m),yaw (deg) of the left then the right base")
    a = np.asarray(v).reshape(2, 4)
    return a[:, :3], np.radians(a[:, 3])


def measure_sim(points: dict, base_error: str, noise_mm: float, seed: int) -> dict:
    """Readings of the simulated controllers (true bases with the --sim-base-error text
    `base_error`) with the tool centre placed exactly on each point, plus Gaussian noise of
    `noise_mm` RMS."""
    offset, yaw = parse_base_error(base_error)
    if not (np.isfinite(noise_mm) and 0 <= noise_mm <= 10):
        raise CalibrationError("--noise-mm must be in [0, 10]")
    rng = np.random.default_rng(seed)
    sigma = noise_mm * 1e-3 / np.sqrt(3.0)
    out = {}
    for i, (arm, a) in enumerate(zip(ARM_KEYS, robot.ARMS)):
        inv = invert(base_transform(BASE_POS[a] + offset[i], BASE_YAW[a] + yaw[i]))
        w = _points("--points", points[arm])
        out[arm] = w @ inv[:3, :3].T + inv[:3, 3] + rng.normal(0.0, sigma, w.shape)
    return out


def measure_ur(points: dict, hosts: list[str], prompt=input) -> dict:
    """Readings of two UR arms (read-only RTDE): for each point, `prompt` asks the operator to
    put the tool centre on it, then the arm's getActualTCPPose is read."""
    receives = receive_only(hosts)
    out = {}
    try:
        for i, arm in enumerate(ARM_KEYS):
            rows = []
            for k, w in enumerate(points[arm]):
                prompt(f"{arm} arm: put the tool centre on point {k + 1} "
                       f"({', '.join(f'{x:.4f}' for x in w)} m) and press Enter ")
                rows.append(receives[i].getActualTCPPose())
            out[arm] = np.asarray(rows, float)
    finally:
        for r in receives:
            r.disconnect()
    return out
