"""The robot's own limits (NumPy + standard library): read from a robot-side file, never from the
policy service.

    limits = RobotLimits.load("ur3_cell.toml")          # or RobotLimits() for the defaults
    limits = limits.tightened(max_speed=0.1)             # overrides may only tighten
    safety = SafetyFilter(limits.safety_limits(speed_scale=0.5))
    limits.check_served(info)                            # GET /info against the robot's limits

A limits file is TOML or JSON (by its extension: ``.toml`` or ``.json``) with the fields of
`RobotLimits`; every value is checked when it is read (`LimitsError`, one line). The shipped
files are in ``daddpg_jax/deploy/limits/`` (``ur3_cell.toml``: the paper's cell, documented
field by field; ``sim.toml``: the simulator's own limits, for sim-to-sim evaluation) and in
docs/DEPLOYMENT.md. What the policy service reports (``GET /info``) never widens these limits:
`check_served` refuses a control period, task or action layout that differs from the robot's.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from daddpg_jax.deploy import robot, ur3
from daddpg_jax.deploy.safety import SafetyLimits
from mjx_envs.settings import TaskConfig

NUM_ARMS, ARM_ACTION = 2, 4
ARM_KEYS = ("left", "right")
MAX_SPEED_LIMIT = 3.0
"""Highest ``max_speed`` a limits file may set, m/s (the simulator's policies command up to
sqrt(3) * 0.05 m / 0.04 s = 2.17 m/s; a UR3's tool is limited to about 1 m/s)."""
MAX_COORD = 2.0
"""Largest absolute workspace coordinate, m (a UR3 reaches 0.5 m from its base)."""
MAX_CLEARANCE = 0.5
MAX_DEADLINE = 10.0
"""Largest deadline a limits file may set, s. A paced run (a robot) also needs deadline <=
control_period; only unpaced sim-to-sim runs (``--fast``) may wait longer."""
MAX_FINGER = 0.1
MAX_DRIVER_WAIT = 2.0
"""Largest ``connect_timeout``, ``call_timeout``, ``max_reading_gap`` and ``watchdog``, s: no
connection or driver call may keep the client waiting longer."""
SHIPPED = os.path.join(os.path.dirname(os.path.abspath(__file__)), "limits")
"""Folder of the shipped limits files."""


class LimitsError(ValueError):
    """A limits value (file or override) that is missing, malformed or out of range."""


# conservative built-in defaults: the simulator's workspace boxes (the paper's cell), a slow
# tool speed, a wide clearance, the simulator's control period, its full finger range
_TASK = TaskConfig()
DEFAULT_BOX_LOW = _TASK.workspace_low
DEFAULT_BOX_HIGH = _TASK.workspace_high


@dataclass(frozen=True)
class RobotLimits:
    """What the robot allows, whatever the policy or the service says. Units: m, s, m/s.

    workspace_low / workspace_high: per arm (left, right) box of the tool centre target in the
    world frame; max_speed: largest speed of each tool target (m/s; the step per period is
    ``max_speed * control_period``); min_clearance: smallest capsule gap between the arms;
    control_period: seconds between policy queries (must equal the served policy's ``dt``);
    deadline: latest usable answer of the service (<= control_period on a paced run; only an
    unpaced simulation may allow more, up to ``MAX_DEADLINE``); finger_min /
    finger_max: opening range of each finger; task: the task the robot runs ("" = any);
    max_observation_age: an observation older than this when its answer arrives is treated
    as a missed deadline (hold); calibration: each arm's base pose in the world frame
    (``{"left": {"base_pos": [x, y, z], "base_rotvec": [rx, ry, rz], "residuals_mm": [...]},
    "right": {...}}``, written by ``daddpg-calibrate``; None: the nominal
    `daddpg_jax.deploy.ur3.BASE_POS` / ``BASE_YAW``), used for every conversion between the
    world and the arms' base frames (`base_transforms`); calibration_max_rms_mm /
    calibration_max_residual_mm: largest RMS / single residual of a calibration's points, mm
    (``daddpg-calibrate`` refuses a fit over them, `check_calibration` a calibration over them
    or without residuals); calibration_max_base_offset_m / calibration_max_base_angle_deg:
    farthest a fitted base may lie from the nominal one (distance, m; rotation angle, degrees)
    before ``daddpg-calibrate`` asks for ``--allow-far-base``; connect_timeout: longest wait
    for a connection to an arm or a gripper; call_timeout: longest driver call (a call that
    raises, returns False or takes longer ends the run, exit 4); max_reading_gap: longest time
    the arms' readings may stay unusable (a frozen controller clock, a read slower than the
    deadline) before the run ends (exit 4; the arms hold meanwhile); watchdog: the controllers'
    own watchdog (an arm stops when the client has not kicked it for this long; at least
    ``deadline + control_period`` is used). Each of these four is in (0, 2] s.
    camera: the camera's table (``[camera]``: kind, mount or calibrated pose, image size,
    intrinsics, target layout; `daddpg_jax.deploy.camera.config.camera_from_limits`, written by
    ``daddpg-calibrate --camera``; None: the nominal simulated mount); max_frame_age: a camera
    frame older than this when it is read holds the arms (s); max_object_lost: the object
    not seen for longer than this holds the arms (s); both in (0, 10] s, measured on the
    camera's clock (simulated seconds for the simulated camera).
    """

    workspace_low: tuple = DEFAULT_BOX_LOW
    workspace_high: tuple = DEFAULT_BOX_HIGH
    max_speed: float = 0.25
    min_clearance: float = 0.05
    control_period: float = _TASK.timestep * _TASK.n_substeps
    deadline: float = 0.03  # of a 40 ms period: a hold goes out within the period
    finger_min: float = 0.0
    finger_max: float = _TASK.finger_stroke
    task: str = ""
    max_observation_age: float = 0.08
    calibration: Mapping | None = None
    calibration_max_rms_mm: float = 3.0
    calibration_max_residual_mm: float = 6.0
    calibration_max_base_offset_m: float = 0.05
    calibration_max_base_angle_deg: float = 10.0
    connect_timeout: float = 2.0
    call_timeout: float = 0.5
    max_reading_gap: float = 0.5
    watchdog: float = 0.2
    camera: Mapping | None = None
    max_frame_age: float = 0.15
    max_object_lost: float = 0.5
    source: str = "built-in defaults"

    def __post_init__(self):
        for name in ("workspace_low", "workspace_high"):
            v = getattr(self, name)
            arr = _box(name, v)
            object.__setattr__(self, name, tuple(tuple(float(x) for x in row) for row in arr))
        low, high = np.asarray(self.workspace_low), np.asarray(self.workspace_high)
        if np.any(low >= high):
            arm, axis = (int(i) for i in np.argwhere(low >= high)[0])
            raise LimitsError(f"workspace of the {ARM_KEYS[arm]} arm is empty along "
                              f"{'xyz'[axis]}: low {low[arm, axis]:g} >= high "
                              f"{high[arm, axis]:g}")
        _number("max_speed", self.max_speed, low=0.0, high=MAX_SPEED_LIMIT, low_open=True)
        _number("min_clearance", self.min_clearance, low=0.0, high=MAX_CLEARANCE)
        _number("control_period", self.control_period, low=0.0, high=1.0, low_open=True)
        _number("deadline", self.deadline, low=0.0, high=MAX_DEADLINE, low_open=True)
        _number("finger_min", self.finger_min, low=0.0, high=MAX_FINGER)
        _number("finger_max", self.finger_max, low=self.finger_min, high=MAX_FINGER)
        _number("max_observation_age", self.max_observation_age, low=0.0, high=10.0,
                low_open=True)
        for name in ("connect_timeout", "call_timeout", "max_reading_gap", "watchdog"):
            _number(name, getattr(self, name), low=0.0, high=MAX_DRIVER_WAIT, low_open=True)
        if not isinstance(self.task, str) or len(self.task) > 64:
            raise LimitsError(f"task must be a short string, got {self.task!r}")
        if self.calibration is not None:
            object.__setattr__(self, "calibration", _calibration(self.calibration))
        _number("calibration_max_rms_mm", self.calibration_max_rms_mm, low=0.0, high=100.0,
                low_open=True)
        _number("calibration_max_residual_mm", self.calibration_max_residual_mm, low=0.0,
                high=100.0, low_open=True)
        _number("calibration_max_base_offset_m", self.calibration_max_base_offset_m, low=0.0,
                high=MAX_COORD, low_open=True)
        _number("calibration_max_base_angle_deg", self.calibration_max_base_angle_deg, low=0.0,
                high=180.0, low_open=True)
        for name in ("max_frame_age", "max_object_lost"):
            _number(name, getattr(self, name), low=0.0, high=10.0, low_open=True)
        if self.camera is not None:
            object.__setattr__(self, "camera", _camera(self.camera))

    # -- reading ------------------------------------------------------------------------------

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "") -> RobotLimits:
        """Limits from the file layout: top-level fields and a ``[left]`` and ``[right]`` table
        each with ``workspace_low`` and ``workspace_high``. Unknown keys are refused."""
        if not isinstance(d, Mapping):
            raise LimitsError("a limits file must hold a table/object of fields")
        names = {f.name for f in dataclasses.fields(cls)} - {"workspace_low", "workspace_high",
                                                           "source"}
        unknown = sorted(set(d) - names - set(ARM_KEYS))
        if unknown:
            raise LimitsError(f"unknown field(s) {', '.join(unknown)}; a limits file has "
                              f"{', '.join(sorted(names | set(ARM_KEYS)))}")
        kw: dict[str, Any] = {k: d[k] for k in names if k in d}
        missing = [a for a in ARM_KEYS if a not in d]
        if missing:
            raise LimitsError(f"missing table(s) {', '.join(missing)} (each arm's workspace)")
        lows, highs = [], []
        for arm in ARM_KEYS:
            t = d[arm]
            if not isinstance(t, Mapping) or set(t) != {"workspace_low", "workspace_high"}:
                raise LimitsError(f"[{arm}] must hold exactly workspace_low and workspace_high")
            lows.append(t["workspace_low"])
            highs.append(t["workspace_high"])
        return cls(workspace_low=tuple(lows), workspace_high=tuple(highs), **kw,
                   source=source or "a mapping")

    @classmethod
    def load(cls, path) -> RobotLimits:
        """Limits from a ``.toml`` or ``.json`` file; LimitsError (one line) on any problem,
        a key given twice in one table or object included (in either format)."""
        path = os.fspath(path)
        ext = os.path.splitext(path)[1].lower()
        if ext not in (".toml", ".json"):
            raise LimitsError(f"limits file {path!r} must end in .toml or .json")
        try:
            with open(path, "rb") as f:
                raw = f.read(1024 * 1024 + 1)
        except OSError as e:
            raise LimitsError(f"cannot read limits file {path!r}: {e.strerror or e}") from None
        if len(raw) > 1024 * 1024:
            raise LimitsError(f"limits file {path!r} is larger than 1 MiB")

        def unique_keys(pairs):  # a key given twice is refused, as TOML refuses it
            out = {}
            for k, v in pairs:
                if k in out:
                    raise LimitsError(f"duplicate key {k[:64]!r}")
                out[k] = v
            return out

        try:
            text = raw.decode("utf-8")
            if ext == ".toml":
                d = tomllib.loads(text)
            else:
                d = json.loads(text, parse_constant=_no_constant, object_pairs_hook=unique_keys)
        except (UnicodeDecodeError, ValueError, RecursionError) as e:  # TOMLDecodeError too
            msg = " ".join(str(e).split())[:200]
            raise LimitsError(f"limits file {path!r} is not valid {ext[1:].upper()}: "
                              f"{msg}") from None
        try:
            return cls.from_dict(d, source=path)
        except LimitsError as e:
            raise LimitsError(f"limits file {path!r}: {e}") from None

    # -- use ----------------------------------------------------------------------------------

    def tightened(self, max_speed: float | None = None, min_clearance: float | None = None,
                  workspace_margin: float | None = None, deadline: float | None = None,
                  max_observation_age: float | None = None) -> RobotLimits:
        """These limits with overrides that may only tighten them: a lower speed, a larger
        clearance, a positive margin shrinking every box, an earlier deadline. LimitsError for
        a value that is not finite or would loosen a limit."""
        out = self
        if max_speed is not None:
            v = _number("--max-speed", max_speed, low=0.0, low_open=True)
            if v > self.max_speed:
                raise LimitsError(f"--max-speed {v:g} m/s would loosen the robot's limit of "
                                  f"{self.max_speed:g} m/s; overrides may only tighten")
            out = dataclasses.replace(out, max_speed=v)
        if min_clearance is not None:
            v = _number("--min-clearance", min_clearance, low=0.0, high=MAX_CLEARANCE)
            if v < self.min_clearance:
                raise LimitsError(f"--min-clearance {v:g} m would loosen the robot's limit of "
                                  f"{self.min_clearance:g} m; overrides may only tighten")
            out = dataclasses.replace(out, min_clearance=v)
        if workspace_margin is not None:
            m = _number("--workspace-margin", workspace_margin, low=0.0)
            low = np.asarray(out.workspace_low) + m
            high = np.asarray(out.workspace_high) - m
            if np.any(low >= high):
                raise LimitsError(f"--workspace-margin {m:g} m leaves an empty workspace box")
            out = dataclasses.replace(out, workspace_low=tuple(map(tuple, low.tolist())),
                                      workspace_high=tuple(map(tuple, high.tolist())))
        if deadline is not None:
            v = _number("--deadline-ms", deadline * 1e3, low=0.0, low_open=True) / 1e3
            if v > self.deadline:
                raise LimitsError(f"--deadline-ms {v * 1e3:g} would loosen the robot's deadline "
                                  f"of {self.deadline * 1e3:g} ms; overrides may only tighten")
            out = dataclasses.replace(out, deadline=v)
        if max_observation_age is not None:
            v = _number("--max-observation-age-ms", max_observation_age * 1e3, low=0.0,
                        low_open=True) / 1e3
            if v > self.max_observation_age:
                raise LimitsError(f"--max-observation-age-ms {v * 1e3:g} would loosen the "
                                  f"robot's limit of {self.max_observation_age * 1e3:g} ms; "
                                  f"overrides may only tighten")
            out = dataclasses.replace(out, max_observation_age=v)
        return out

    def safety_limits(self, speed_scale: float = 1.0) -> SafetyLimits:
        """The safety layer's limits; ``speed_scale`` in (0, 1] slows the speed cap down."""
        s = _number("--speed-scale", speed_scale, low=0.0, high=1.0, low_open=True)
        return SafetyLimits(workspace_low=np.asarray(self.workspace_low, np.float32),
                            workspace_high=np.asarray(self.workspace_high, np.float32),
                            max_step=self.max_speed * s * self.control_period,
                            min_clearance=self.min_clearance, deadline_s=self.deadline,
                            finger_low=self.finger_min, finger_high=self.finger_max)

    def check_served(self, info: Mapping[str, Any], task: str | None = None) -> None:
        """Refuses (LimitsError, one line) a served policy whose control period differs from
        the robot's, whose task differs from ``task`` or the limits' ``task``, or whose action
        layout is not the robot's (2 arms x [dx, dy, dz, finger])."""
        if not isinstance(info, Mapping):
            raise LimitsError("GET /info did not answer a JSON object")
        served = info.get("task")
        for want, where in ((task, "--task"), (self.task, f"the limits ({self.source})")):
            if want and served != want:
                raise LimitsError(f"the service serves a {served!r} policy, not {want!r} "
                                  f"({where})")
        env = info.get("env")
        served_period_s = env.get("dt") if isinstance(env, Mapping) else None
        if (isinstance(served_period_s, bool) or not isinstance(served_period_s, (int, float))
                or not math.isfinite(served_period_s)
                or abs(served_period_s - self.control_period)
                > 1e-9 + 1e-6 * self.control_period):
            raise LimitsError(f"the served policy's control period {served_period_s!r} s differs "
                              f"from the robot's {self.control_period:g} s")
        layout = (info.get("action_size"), info.get("num_arms", NUM_ARMS),
                  info.get("arm_action", ARM_ACTION))
        if layout != (NUM_ARMS * ARM_ACTION, NUM_ARMS, ARM_ACTION):
            raise LimitsError(f"the served policy's action layout (size, arms, per arm) "
                              f"{layout} is not the robot's "
                              f"{(NUM_ARMS * ARM_ACTION, NUM_ARMS, ARM_ACTION)}")

    def base_transforms(self) -> np.ndarray:
        """World <- base transforms [2, 4, 4] of the arms (left, right): the calibration, else
        the nominal cell."""
        if self.calibration is None:
            return np.stack([ur3.base_transform(a) for a in robot.ARMS])
        out = np.zeros((NUM_ARMS, 4, 4))
        for i, arm in enumerate(ARM_KEYS):
            c = self.calibration[arm]
            out[i] = np.eye(4)
            out[i, :3, :3] = robot.rotvec_to_matrix(c["base_rotvec"])
            out[i, :3, 3] = c["base_pos"]
        return out

    def check_calibration(self) -> None:
        """Refuses (LimitsError, one line) a calibration whose arm carries fewer than
        `MIN_CALIBRATION_POINTS` residuals (none: not written by ``daddpg-calibrate``), or
        whose residuals' RMS (recomputed, and ``rms_mm`` as written) or largest residual exceeds
        ``calibration_max_rms_mm`` / ``calibration_max_residual_mm``. No calibration (the
        nominal bases) passes."""
        if self.calibration is None:
            return
        for arm in ARM_KEYS:
            c = self.calibration[arm]
            res = np.asarray(c.get("residuals_mm", ()), float)
            where = f"the calibration of the {arm} arm ({self.source})"
            if len(res) < MIN_CALIBRATION_POINTS:
                raise LimitsError(f"{where} carries {len(res)} residuals (at least "
                                  f"{MIN_CALIBRATION_POINTS} needed): rerun daddpg-calibrate")
            rms = max(float(np.sqrt(np.mean(res ** 2))), float(c.get("rms_mm", 0.0)))
            if rms > self.calibration_max_rms_mm:
                raise LimitsError(f"{where} has an RMS residual of {rms:.3g} mm, over "
                                  f"calibration_max_rms_mm {self.calibration_max_rms_mm:g}: "
                                  f"rerun daddpg-calibrate")
            k = int(np.argmax(res))
            if res[k] > self.calibration_max_residual_mm:
                raise LimitsError(f"{where} has a residual of {res[k]:.3g} mm at point {k + 1}, "
                                  f"over calibration_max_residual_mm "
                                  f"{self.calibration_max_residual_mm:g}: rerun daddpg-calibrate")

    def describe(self, speed_scale: float = 1.0) -> str:
        """One line: the limits in use and where they come from."""
        box = "; ".join(f"{a} {list(lo)}..{list(hi)}" for a, lo, hi in
                        zip(ARM_KEYS, self.workspace_low, self.workspace_high))
        scale = f" x speed scale {speed_scale:g}" if speed_scale != 1.0 else ""
        return (f"limits ({self.source}): max speed {self.max_speed:g} m/s{scale}, min "
                f"clearance {self.min_clearance:g} m, control period "
                f"{self.control_period * 1e3:g} ms, deadline {self.deadline * 1e3:g} ms, "
                f"observation age {self.max_observation_age * 1e3:g} ms, fingers "
                f"{self.finger_min:g}..{self.finger_max:g} m, task {self.task or 'any'}; "
                f"workspace (world m) {box}; bases "
                f"{'calibrated' if self.calibration else 'nominal (not calibrated)'}")


def _no_constant(name):
    raise ValueError(f"{name} is not allowed")


def _number(name: str, v, low: float | None = None, high: float | None = None,
            low_open: bool = False) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
        raise LimitsError(f"{name} must be a number, got {v!r}")
    v = float(v)
    if not math.isfinite(v):
        raise LimitsError(f"{name} must be finite, got {v!r}")
    if low is not None and (v < low or (low_open and v == low)):
        raise LimitsError(f"{name} must be {'>' if low_open else '>='} {low:g}, got {v:g}")
    if high is not None and v > high:
        raise LimitsError(f"{name} must be <= {high:g}, got {v:g}")
    return v


MAX_RESIDUAL_ROWS = 64
MIN_CALIBRATION_POINTS = 6
"""Fewest points per arm of a calibration (``daddpg-calibrate``, `check_calibration`)."""


def _calibration(v) -> dict:
    """The checked calibration table (see `RobotLimits`)."""
    if not isinstance(v, Mapping) or set(v) != set(ARM_KEYS):
        raise LimitsError("calibration must hold a left and a right table")
    out = {}
    for arm in ARM_KEYS:
        t = v[arm]
        if not isinstance(t, Mapping) or not {"base_pos", "base_rotvec"} <= set(t) or not (
                set(t) <= {"base_pos", "base_rotvec", "residuals_mm", "rms_mm"}):
            raise LimitsError(f"calibration.{arm} must hold base_pos and base_rotvec (and "
                              f"optionally residuals_mm, rms_mm)")
        row = {}
        for key, bound in (("base_pos", MAX_COORD), ("base_rotvec", math.pi + 1e-9)):
            x = t[key]
            if not isinstance(x, (list, tuple)) or len(x) != 3:
                raise LimitsError(f"calibration.{arm}.{key} must be 3 numbers, got {x!r}")
            row[key] = tuple(_number(f"calibration.{arm}.{key}", c, low=-bound, high=bound)
                             for c in x)
        res = t.get("residuals_mm", ())
        if not isinstance(res, (list, tuple)) or len(res) > MAX_RESIDUAL_ROWS:
            raise LimitsError(f"calibration.{arm}.residuals_mm must be a list of numbers")
        row["residuals_mm"] = tuple(_number(f"calibration.{arm}.residuals_mm", r, low=0.0)
                                    for r in res)
        if "rms_mm" in t:
            row["rms_mm"] = _number(f"calibration.{arm}.rms_mm", t["rms_mm"], low=0.0)
        out[arm] = row
    return out


def _camera(v) -> dict:
    """The ``[camera]`` table, checked by the camera package (`camera_from_limits`)."""
    if not isinstance(v, Mapping):
        raise LimitsError(f"camera must be a table, got {type(v).__name__}")
    try:  # lazy: the camera package needs OpenCV (the optional extra [camera])
        from daddpg_jax.deploy.camera.config import CameraConfigError, camera_from_limits
    except ImportError as e:
        raise LimitsError(f"the [camera] table needs OpenCV (pip install 'daddpg-jax[camera]'): "
                          f"{e}") from None
    try:
        camera_from_limits({"camera": v})
    except CameraConfigError as e:
        raise LimitsError(str(e)) from None
    return dict(v)


def _box(name: str, v) -> np.ndarray:
    rows = list(v) if isinstance(v, (list, tuple)) else None
    if rows is None or len(rows) != NUM_ARMS or any(
            not isinstance(r, (list, tuple)) or len(r) != 3 for r in rows):
        raise LimitsError(f"{name} must be 3 numbers [x, y, z] per arm, got {v!r}")
    for arm, r in zip(ARM_KEYS, rows):
        for axis, x in zip("xyz", r):
            _number(f"{arm} {name}.{axis}", x, low=-MAX_COORD, high=MAX_COORD)
    return np.asarray(rows, float)
