"""Frame calibration (NumPy + standard library): each arm's base pose in the policy's world
frame from points on the table whose world positions are known (a printed board), touched with
the gripper's tool centre and read in the arm's base frame (``getActualTCPPose``).

    fits = fit_arms(points, measured)                     # {"left": (T, residuals), ...}
    print("\n".join(report_lines(points, fits)))         # each point's residual, each base
    check_fits(points, measured, fits, limits=limits)     # CalibrationError: refused
    write_calibration("cell.toml", {a: entry(*fits[a]) for a in fits})

Two models: ``yaw`` (default; the base stands level: a turn about the vertical and a 3-D
offset, 4 parameters, as `mjx_envs.randomize` models a calibration error of ``base_offset`` and
``base_yaw``; solved in closed form) and ``full`` (any rotation, 6 parameters: Kabsch's SVD
solution with the reflection fixed; resolves the tilt only as well as the points' spread
allows). The residual of each point is the distance between its known world position and the
transformed measurement.

What is refused (`CalibrationError`, one line): fewer than `MIN_POINTS` points per arm, points
on one line or spanning less than `MIN_SPAN` in two directions (`fit_base`); then
(`check_fits`) a single point that the others contradict (leave-one-out: named, never dropped),
left and right readings that fit each other's points (swapped), readings that fit only with a
reflection or a scale off 1 by more than `MAX_SCALE_ERROR`, an RMS or largest residual over
the limits' ``calibration_max_rms_mm`` / ``calibration_max_residual_mm``, a base that lands on
the other arm's nominal base, and (unless ``allow_far_base``) a base farther than
``calibration_max_base_offset_m`` or turned more than ``calibration_max_base_angle_deg`` from
its nominal pose (`daddpg_jax.deploy.ur3.BASE_POS` / ``BASE_YAW``).
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from daddpg_jax.deploy import robot, ur3
from daddpg_jax.deploy.arms import base_transform, invert, receive_only
from daddpg_jax.deploy.limits import (
    ARM_KEYS,
    MIN_CALIBRATION_POINTS,
    LimitsError,
    RobotLimits,
)
from daddpg_jax.deploy.ur3 import BASE_POS, BASE_YAW

MIN_POINTS = MIN_CALIBRATION_POINTS
"""Fewest points per arm (6)."""
MIN_SPAN = 0.10
"""Smallest extent of each arm's known points along each of their two main directions, m."""
MAX_SCALE_ERROR = 0.01
"""Largest |scale - 1| of the similarity fit (Umeyama) between readings and points; widened to
5 standard errors of the scale when the points' noise makes it less certain than that."""
OUTLIER_FACTOR = 3.0
"""A point is an outlier when leaving it out divides the RMS residual by more than this, the
others then fit within the limits and its own residual (to their fit) exceeds the largest
allowed."""
MODELS = ("yaw", "full")
MARKER = "# -- calibration (written by daddpg-calibrate; rerun it to replace this block) --"
CAMERA_MARKER = ("# -- camera (written by daddpg-calibrate --camera; rerun it to replace this "
                 "block) --")


class CalibrationError(ValueError):
    """Points that cannot give a calibration (too few, degenerate, non-finite) or a fit that is
    refused (outlier, swapped, mirrored, scaled, residuals too large, base too far); one line."""


def _points(name, p) -> np.ndarray:
    a = np.asarray(p, float)
    if a.ndim != 2 or a.shape[1] not in (3, 6):
        raise CalibrationError(f"{name} must be N rows of [x, y, z] (or UR poses [x, y, z, rx, "
                               f"ry, rz]), got shape {list(a.shape)}")
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{name} holds NaN or infinite values")
    return a[:, :3]


def _xyz(v) -> str:
    return "[" + ", ".join(f"{x:.4f}" for x in v) + "]"


def _rms(r) -> float:
    return float(np.sqrt(np.mean(np.square(r))))


def _solve(w, b, model) -> tuple[np.ndarray, np.ndarray]:
    """The least-squares fit of [N, 3] points and readings, N >= 3 (no acceptance checks)."""
    wc, bc = w.mean(0), b.mean(0)
    W, B = w - wc, b - bc
    spread = np.linalg.svd(B[:, :2] if model == "yaw" else B, compute_uv=False)
    if spread[1] < 1e-3 * math.sqrt(len(b)):  # all within ~1 mm of one line
        raise CalibrationError("the readings lie on one line"
                               + (" seen from above" if model == "yaw" else "")
                               + ": spread the points over the board")
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


def _geometry(w) -> None:
    """Refuses known points on one line or spanning less than MIN_SPAN in two directions."""
    W = w - w.mean(0)
    _, s, Vt = np.linalg.svd(W, full_matrices=False)
    if s[1] < 1e-3 * math.sqrt(len(w)):
        raise CalibrationError("the points lie on one line: spread them over the board")
    extent = np.ptp(W @ Vt[:2].T, axis=0)
    if extent.min() < MIN_SPAN - 1e-6:
        raise CalibrationError(f"the points span {extent[0] * 100:.1f} x {extent[1] * 100:.1f} "
                               f"cm: at least {MIN_SPAN * 100:g} cm in two directions is needed "
                               f"(spread them over the board)")


def fit_base(points_world, tcp_base, model: str = "yaw") -> tuple[np.ndarray, np.ndarray]:
    """(world <- base 4x4, residual per point [N] m) by least squares from N >= 6 points:
    ``points_world`` [N, 3] known positions (not on one line, spanning at least `MIN_SPAN` in
    two directions), ``tcp_base`` [N, 3] (or [N, 6] poses) the tool centre measured on each in
    the base frame."""
    w, b = _points("points_world", points_world), _points("tcp_base", tcp_base)
    if model not in MODELS:
        raise CalibrationError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    if len(w) != len(b):
        raise CalibrationError(f"{len(w)} known points but {len(b)} measurements")
    if len(w) < MIN_POINTS:
        raise CalibrationError(f"at least {MIN_POINTS} points are needed, got {len(w)}")
    _geometry(w)
    return _solve(w, b, model)


def fit_arms(points: dict, measured: dict, model: str = "yaw") -> dict:
    """{"left": (T, residuals), "right": ...} of `fit_base`; its errors name the arm."""
    out = {}
    for arm in ARM_KEYS:
        try:
            out[arm] = fit_base(points[arm], measured[arm], model)
        except CalibrationError as e:
            raise CalibrationError(f"{arm} arm: {e}") from None
    return out


def leave_one_out(points_world, tcp_base, model: str = "yaw") -> tuple[np.ndarray, np.ndarray]:
    """(RMS residual of the others when point i is left out [N] m, point i's residual to that
    fit [N] m); inf where the others cannot be fitted."""
    w, b = _points("points_world", points_world), _points("tcp_base", tcp_base)
    rest, alone = np.full(len(w), np.inf), np.full(len(w), np.inf)
    for i in range(len(w)):
        keep = np.arange(len(w)) != i
        try:
            T, r = _solve(w[keep], b[keep], model)
        except CalibrationError:
            continue
        rest[i] = _rms(r)
        alone[i] = np.linalg.norm(T[:3, :3] @ b[i] + T[:3, 3] - w[i])
    return rest, alone


def similarity(points_world, tcp_base) -> tuple[float, float, bool]:
    """(scale, its tolerance, reflected) of the readings against the points: the scale of the
    similarity fit w ~ s R b + t with R any orthogonal matrix (Umeyama); reflected when that R
    has det < 0, judged in 3-D where the points span 3-D (1 cm RMS off their plane), else in the
    horizontal plane (both frames z up), else not judged (False)."""
    w, b = _points("points_world", points_world), _points("tcp_base", tcp_base)
    W, B = w - w.mean(0), b - b.mean(0)
    U, S, Vt = np.linalg.svd(B.T @ W)
    b2 = float(np.sum(B ** 2))
    scale = float(S.sum() / b2) if b2 > 0 else 0.0
    fit = W - scale * B @ (Vt.T @ U.T).T
    sigma = math.sqrt(float(np.sum(fit ** 2)) / max(3 * len(w) - 7, 1))  # per axis
    tol = max(MAX_SCALE_ERROR, 5 * sigma / math.sqrt(b2)) if b2 > 0 else MAX_SCALE_ERROR
    n = math.sqrt(len(w))
    if np.linalg.svd(W, compute_uv=False)[2] >= 0.01 * n:
        reflected = np.linalg.det(B.T @ W) < 0
    elif np.linalg.svd(W[:, :2], compute_uv=False)[1] >= 0.01 * n:
        reflected = np.linalg.det(B[:, :2].T @ W[:, :2]) < 0
    else:
        reflected = False
    return scale, tol, bool(reflected)


def nominal_base(arm: str) -> np.ndarray:
    """World <- base 4x4 of the nominal cell for "left" or "right"."""
    return ur3.base_transform(robot.ARMS[ARM_KEYS.index(arm)])


def _within(residuals, limits: RobotLimits) -> bool:
    r = np.asarray(residuals) * 1e3
    return (_rms(r) <= limits.calibration_max_rms_mm
            and float(r.max()) <= limits.calibration_max_residual_mm)


def check_fits(points: dict, measured: dict, fits: dict, model: str = "yaw",
               limits: RobotLimits | None = None, allow_far_base: bool = False) -> None:
    """Refuses (CalibrationError, one line) the fits of `fit_arms` as listed in the module's
    docstring, in that order; the thresholds are the limits' (default `RobotLimits()`)."""
    lim = limits if limits is not None else RobotLimits()
    w = {a: _points(f"{a} points", points[a]) for a in ARM_KEYS}
    b = {a: _points(f"{a} readings", measured[a]) for a in ARM_KEYS}
    thresholds = (f"calibration_max_rms_mm {lim.calibration_max_rms_mm:g}, "
                  f"calibration_max_residual_mm {lim.calibration_max_residual_mm:g}")
    for arm in ARM_KEYS:
        rest, alone = leave_one_out(w[arm], b[arm], model)
        k = int(np.argmin(rest))
        full = _rms(fits[arm][1])
        if (alone[k] * 1e3 > lim.calibration_max_residual_mm
                and rest[k] * 1e3 <= lim.calibration_max_rms_mm
                and full > OUTLIER_FACTOR * rest[k]):
            raise CalibrationError(
                f"{arm} point {k + 1} {_xyz(w[arm][k])} m is an outlier: {alone[k] * 1e3:.1f} mm "
                f"off the fit of the other {len(w[arm]) - 1} (rms {rest[k] * 1e3:.2f} mm without "
                f"it, {full * 1e3:.2f} mm with it); touch it again or correct its coordinates "
                f"(no point is dropped)")

    def fits_well(wa, ba, residuals):  # within the limits and not mirrored
        return _within(residuals, lim) and not similarity(wa, ba)[2]

    pairs = list(zip(ARM_KEYS, ARM_KEYS[::-1]))
    if (len(w["left"]) == len(w["right"])
            and not all(fits_well(w[a], b[a], fits[a][1]) for a in ARM_KEYS)):
        try:
            crossed = [_solve(w[a], b[o], model)[1] for a, o in pairs]
        except CalibrationError:
            crossed = []
        if crossed and all(fits_well(w[a], b[o], r) for (a, o), r in zip(pairs, crossed)):
            raise CalibrationError(
                f"the left and right readings are swapped: each fits the other arm's points "
                f"(rms {_rms(crossed[0]) * 1e3:.2f} / {_rms(crossed[1]) * 1e3:.2f} mm, against "
                f"{_rms(fits['left'][1]) * 1e3:.1f} / {_rms(fits['right'][1]) * 1e3:.1f} mm as "
                f"given, or mirrored); exchange them")
    for arm in ARM_KEYS:
        scale, tol, reflected = similarity(w[arm], b[arm])
        if reflected:
            raise CalibrationError(
                f"the {arm} readings are a mirror image of its points (the fit needs a "
                f"reflection): check the sign of each axis and the order of the points")
        if abs(scale - 1.0) > tol:
            raise CalibrationError(
                f"the {arm} readings fit its points only with a scale of {scale:.4f} (the "
                f"readings are {1 / scale if scale else math.inf:.3f} x the board; tolerance "
                f"{tol:.1%}): check that points and readings are both in metres")
    for arm in ARM_KEYS:
        r = np.asarray(fits[arm][1]) * 1e3
        if not _within(fits[arm][1], lim):
            k = int(np.argmax(r))
            raise CalibrationError(
                f"the {arm} fit has rms {_rms(r):.2f} mm, largest {r[k]:.2f} mm at point "
                f"{k + 1}, over the limits ({thresholds}): touch the points again")
    for i, arm in enumerate(ARM_KEYS):
        other = ARM_KEYS[1 - i]
        T = fits[arm][0]
        own, angle = pose_error(T, nominal_base(arm))
        near = pose_error(T, nominal_base(other))[0]
        if near < own and near <= lim.calibration_max_base_offset_m:
            raise CalibrationError(
                f"the {arm} base fits {near:.3f} m from the {other} arm's nominal base and "
                f"{own:.3f} m from its own: left and right are swapped (points or readings)")
        if not allow_far_base and (own > lim.calibration_max_base_offset_m
                                   or angle > lim.calibration_max_base_angle_deg):
            raise CalibrationError(
                f"the {arm} base fits {own:.3f} m and {angle:.1f} deg from its nominal pose, "
                f"over the limits (calibration_max_base_offset_m "
                f"{lim.calibration_max_base_offset_m:g}, calibration_max_base_angle_deg "
                f"{lim.calibration_max_base_angle_deg:g}): check the points' world frame, or "
                f"pass --allow-far-base if the arm really stands there")


def report_lines(points: dict, fits: dict) -> list[str]:
    """One line per point (its residual) and one per arm (the base, its distance and angle to
    the nominal base, the RMS residual)."""
    lines = []
    for arm in ARM_KEYS:
        T, res = fits[arm]
        w = _points(f"{arm} points", points[arm])
        for k, (p, r) in enumerate(zip(w, res)):
            lines.append(f"{arm} point {k + 1} {_xyz(p)} m: residual {r * 1e3:.2f} mm")
        c = entry(T, res)
        off, angle = pose_error(T, nominal_base(arm))
        yaw = np.degrees(np.linalg.norm(c["base_rotvec"]))
        lines.append(f"{arm} base: position {c['base_pos']} m, rotation {yaw:.3f} deg (rotvec "
                     f"{c['base_rotvec']}), {off:.4f} m and {angle:.2f} deg from nominal; "
                     f"residuals mm {c['residuals_mm']} (rms {c['rms_mm']:.3f})")
    return lines


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
    return _write_block(path, "calibration", calibration, MARKER, _toml_block(calibration))


def _without_block(text: str, marker: str) -> str:
    """``text`` without the block that starts at ``marker`` (up to the next block written by
    daddpg-calibrate, or the end)."""
    if marker not in text:
        return text.rstrip("\n")
    head, rest = text.split(marker, 1)
    ends = [rest.find(m) for m in (MARKER, CAMERA_MARKER) if m != marker and m in rest]
    tail = rest[min(ends):] if ends else ""
    return (head.rstrip("\n") + ("\n\n" + tail if tail else "")).rstrip("\n")


def _write_block(path, key: str, value: dict, marker: str, block: str,
                 drop_table: str | None = None) -> RobotLimits:
    """Writes ``value`` as the field ``key`` of the limits file ``path`` (TOML: ``block`` at
    the end, replacing the earlier block of ``marker``; JSON: the field) and returns the
    limits read back; LimitsError (one line) if the result does not load (the file is then
    left as it was)."""
    path = os.fspath(path)
    RobotLimits.load(path)  # a valid limits file to start from
    with open(path, encoding="utf-8") as f:
        old = f.read()
    if path.lower().endswith(".json"):
        d = json.loads(old)
        d[key] = value
        new = json.dumps(d, indent=2) + "\n"
    else:
        text = _without_block(old, marker)
        new = (text if drop_table is None else _without_table(text, drop_table)).rstrip(
            "\n") + "\n\n" + block
    root, ext = os.path.splitext(path)
    tmp = f"{root}.tmp{ext}"
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(new)
    try:
        limits = RobotLimits.load(tmp)
    except LimitsError as e:
        os.remove(tmp)
        raise LimitsError(f"the {key} cannot be written into {path!r}: {e}") from None
    os.replace(tmp, path)
    return limits


def _toml_value(v) -> str:
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(repr(float(x)) for x in v) + "]"
    return repr(v)


def write_camera(path, camera: dict, report=()) -> RobotLimits:
    """Writes the ``[camera]`` table ``camera`` (its keys as `camera_from_limits` reads them)
    into the limits file ``path`` (TOML: a block at the end, replacing an earlier one or a
    hand-written ``[camera]`` table, with the lines of ``report`` as comments; JSON: the
    ``camera`` field) and returns the limits
    read back; LimitsError (one line) if the result does not load."""
    lines = [CAMERA_MARKER, "# The camera's pose in the world frame (position, m; rotvec: "
             "world <- camera, OpenCV's frame, rad),", "# from the tag board on the table:",
             *(f"#   {line.strip()}" for line in report), "", "[camera]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in camera.items()]
    return _write_block(path, "camera", dict(camera), CAMERA_MARKER, "\n".join(lines) + "\n",
                        drop_table="camera")


def _without_table(text: str, name: str) -> str:
    """``text`` without a hand-written TOML table ``[name]`` (its header up to the next
    table's; the block written in its place carries its keys)."""
    out, inside = [], False
    for line in text.splitlines(keepends=True):
        head = line.strip()
        if head.startswith("[") or head in (MARKER, CAMERA_MARKER):
            inside = head.split("#", 1)[0].strip() == f"[{name}]"
        if not inside:
            out.append(line)
    return "".join(out)


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
