"""An independent recorder of every command the simulated arms receive (``--arms sim`` and
``ur-sim``): it wraps the simulated cell's entry points (`SimCell.servo`, ``move``, ``grip``,
``reset``), through which both `SimArms` and the simulated ur_rtde controllers move the cell,
and checks each command against a limits file with arithmetic of its own: the file is parsed
here with ``tomllib`` / ``json``, poses are taken from each base frame to the world frame with
this module's own rotation code and the file's calibration (else the nominal cell), and nothing
from ``daddpg_jax.deploy.safety``, ``gate`` or ``limits`` is used.

Checked per command:
- servo: the target inside the arm's box (1e-6 m), at most ``max_speed * speed_scale *
  control_period`` from the arm's last commanded target (relative 1e-5, plus 0.25 µm for float32
  coordinates, as the gate allows), after a start move;
- move (the start move, moveL): its end inside the box, the measured start within 5 mm of the
  box, its speed at most ``max_speed * speed_scale``;
- grip: a finite opening in ``[finger_min, finger_max]``.

Use: the ``arm_recorder`` fixture (tests/conftest.py) records every cell a test makes; a test
that runs under other limits says so with ``arm_recorder.expect(path, ...)``;
``robot_client.main`` runs are expected automatically from their flags. Any violation fails
the test at teardown."""

from __future__ import annotations

import json
import math
import os
import tomllib

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SIM_TOML = os.path.join(ROOT, "daddpg_jax", "deploy", "limits", "sim.toml")
# the nominal cell (docs/DEPLOYMENT.md, ur3_cell.toml's header): bases 0.5 m apart, 0.40 m up,
# each turned by pi about z
NOMINAL_BASES = {0: ((0.0, 0.25, 0.40), math.pi), 1: ((0.0, -0.25, 0.40), math.pi)}
# the built-in limits of daddpg-robot-client without --limits (documented in its --help and
# docs/DEPLOYMENT.md): the simulator's boxes, 0.25 m/s, 40 ms, fingers 0..0.04 m
BUILT_IN = dict(max_speed=0.25, control_period=0.04, finger_min=0.0, finger_max=0.04,
                left=dict(workspace_low=[0.12, -0.14, 0.41], workspace_high=[0.40, 0.36, 0.65]),
                right=dict(workspace_low=[0.12, -0.36, 0.41], workspace_high=[0.40, 0.14, 0.65]))
MEASURED_SLACK = 0.005


def _rodrigues(r) -> np.ndarray:
    r = np.asarray(r, float)
    th = math.sqrt(float(r @ r))
    if th < 1e-15:
        return np.eye(3)
    x, y, z = r / th
    c, s, C = math.cos(th), math.sin(th), 1 - math.cos(th)
    return np.array([[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                     [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                     [z * x * C - y * s, z * y * C + x * s, c + z * z * C]])


class Expected:
    """The limits a run must keep, read from the file here (with the client's tightening
    flags applied by this class's own arithmetic)."""

    def __init__(self, raw: dict, speed_scale: float = 1.0, workspace_margin: float = 0.0,
                 max_speed: float | None = None):
        self.low = np.array([raw[a]["workspace_low"] for a in ("left", "right")], float)
        self.high = np.array([raw[a]["workspace_high"] for a in ("left", "right")], float)
        self.low += workspace_margin or 0.0
        self.high -= workspace_margin or 0.0
        speed = raw.get("max_speed", BUILT_IN["max_speed"])
        if max_speed is not None:
            speed = min(speed, max_speed)
        self.speed = speed * speed_scale
        self.cap = self.speed * raw.get("control_period", BUILT_IN["control_period"])
        self.fingers = (raw.get("finger_min", 0.0), raw.get("finger_max", 0.04))
        cal = raw.get("calibration")
        self.R, self.p = [], []
        for i, arm in enumerate(("left", "right")):
            if cal:
                self.R.append(_rodrigues(cal[arm]["base_rotvec"]))
                self.p.append(np.asarray(cal[arm]["base_pos"], float))
            else:
                pos, yaw = NOMINAL_BASES[i]
                self.R.append(_rodrigues([0.0, 0.0, yaw]))
                self.p.append(np.asarray(pos, float))

    @classmethod
    def of(cls, path=None, **tighten) -> Expected:
        if path is None:
            return cls(BUILT_IN, **tighten)
        with open(path, "rb") as f:
            raw = tomllib.load(f) if str(path).endswith(".toml") else json.load(f)
        return cls(raw, **tighten)

    def world(self, arm: int, pos_base) -> np.ndarray:
        return self.R[arm] @ np.asarray(pos_base, float)[:3] + self.p[arm]


class ArmRecorder:
    """Records and checks the commands of every simulated cell; ``violations`` lists them."""

    def __init__(self, expected: Expected | None = None):
        self.expected = expected or Expected.of(SIM_TOML)
        self.violations: list[str] = []
        self.commands = 0
        self.last: dict = {}  # (cell id, arm) -> last commanded world target

    def expect(self, path=None, **tighten) -> None:
        self.expected = Expected.of(path, **tighten)

    def _bad(self, line: str):
        if len(self.violations) < 50:
            self.violations.append(line)

    def _inside(self, w, arm, slack) -> bool:
        e = self.expected
        return bool(np.all(w >= e.low[arm] - slack) and np.all(w <= e.high[arm] + slack))

    def servo(self, cell, arm, pose):
        self.commands += 1
        e, w = self.expected, self.expected.world(arm, pose)
        if not self._inside(w, arm, 1e-6):
            self._bad(f"servo outside the box: arm {arm} {w.round(4)}")
        last = self.last.get((id(cell), arm))
        if last is None:
            self._bad(f"servo of arm {arm} before any start move")
        elif np.linalg.norm(w - last) > e.cap * (1 + 1e-5) + 2.5e-7:  # float32 coordinates
            self._bad(f"servo step {np.linalg.norm(w - last) * 1e3:.2f} mm > cap "
                      f"{e.cap * 1e3:.2f} mm (arm {arm})")
        self.last[(id(cell), arm)] = w

    def move(self, cell, arm, pose, speed):
        self.commands += 1
        e, w = self.expected, self.expected.world(arm, pose)
        measured = e.world(arm, cell.tcp_pose(arm)[:3])
        if not self._inside(measured, arm, MEASURED_SLACK):
            self._bad(f"start move from outside the box: arm {arm} {measured.round(4)}")
        if not self._inside(w, arm, 1e-6):
            self._bad(f"start move to outside the box: arm {arm} {w.round(4)}")
        if not speed <= e.speed * (1 + 1e-6):
            self._bad(f"start move at {speed} m/s > {e.speed} m/s")
        self.last[(id(cell), arm)] = w

    def grip(self, cell, arm, opening):
        self.commands += 1
        lo, hi = self.expected.fingers
        if not (math.isfinite(opening) and lo - 1e-9 <= opening <= hi + 1e-9):
            self._bad(f"finger opening {opening} outside [{lo}, {hi}]")

    def reset(self, cell):
        for arm in (0, 1):
            self.last.pop((id(cell), arm), None)


def install(monkeypatch, recorder: ArmRecorder) -> None:
    """Wraps `SimCell`'s entry points (every cell of the test) and the client's setup (its
    flags set the expected limits)."""
    from daddpg_jax.deploy import robot_session, ursim

    cls = ursim.SimCell
    servo, move, grip, reset = cls.servo, cls.move, cls.grip, cls.reset

    def servo_(self, arm, pose):
        recorder.servo(self, arm, pose)
        return servo(self, arm, pose)

    def move_(self, arm, pose, speed):
        recorder.move(self, arm, pose, speed)
        return move(self, arm, pose, speed)

    def grip_(self, arm, opening):
        recorder.grip(self, arm, float(opening))
        return grip(self, arm, opening)

    def reset_(self, qpos):
        recorder.reset(self)
        return reset(self, qpos)

    monkeypatch.setattr(cls, "servo", servo_)
    monkeypatch.setattr(cls, "move", move_)
    monkeypatch.setattr(cls, "grip", grip_)
    monkeypatch.setattr(cls, "reset", reset_)
    prepare = robot_session.prepare

    def prepare_(opt, *a, **kw):
        try:
            recorder.expect(opt.limits, speed_scale=opt.speed_scale,
                            workspace_margin=opt.workspace_margin, max_speed=opt.max_speed)
        except (OSError, ValueError, KeyError, TypeError):
            pass  # a file the client refuses too; nothing can move
        return prepare(opt, *a, **kw)

    monkeypatch.setattr(robot_session, "prepare", prepare_)
