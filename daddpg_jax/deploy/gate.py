"""The one gate between the robot client and the arms (NumPy only).

Every command that leaves the client for an arm passes `GatedArms`, the last thing before the
driver (`daddpg_jax.deploy.arms.URArms`, `daddpg_jax.deploy.ursim.SimArms`): the move to the
start pose, each servo target, each hold and every gripper command, on every ``--arms`` kind.
It checks the command in the arm's physical frame (the base-frame pose taken to the world frame
through the calibrated bases) against the robot's limits (`daddpg_jax.deploy.safety.SafetyLimits`)
with arithmetic of its own, independent of the rules that ran before it:

- **box**: the tool-centre target lies inside the arm's workspace box;
- **step**: it lies at most ``max_step`` from the last commanded target (at the start of an
  episode: from the measured tool position), up to float32 rounding (`step_cap`);
- **orientation**: the tool points down (the simulator's fixed orientation);
- **clearance**: the arms' link capsules, moved to the new targets (first order, as
  `daddpg_jax.deploy.safety` predicts them), keep ``min_clearance``, or the move widens the gap;
- **fingers**: each opening is finite and inside ``[finger_low, finger_high]``.

A command that fails is not sent: the arms hold (the last commanded pose is sent again; a
finger command that fails is dropped), and the refusal is counted and kept (``refusals``).
Before the start move: if an arm's measured tool position or the task's start pose lies outside
its box, nothing moves (`GateRefusal`, one line; the client exits 2). The start move runs as a
straight line (both ends inside the convex box, so the whole path is) at no more than the speed
cap (``max_step / period``).
"""

from __future__ import annotations

import numpy as np

from daddpg_jax.deploy.arm_frames import link_points_base
from daddpg_jax.deploy.safety import LINK_FOLLOW, SafetyLimits
from mjx_envs.observation import arm_clearance

NUM_ARMS = 2
ARM_NAMES = ("left", "right")
BOX_TOLERANCE = 1e-6
"""m: float32 rounding of a clamped target is not a violation"""
STEP_TOLERANCE = 1e-5
"""relative: float32 rounding of a capped step's length is not a violation"""
STEP_ROUNDING = 2.5e-7
"""m: nor is float32 rounding of the two targets' coordinates, which does not shrink with the
step (up to 6e-8 m per coordinate below 1 m; ~4e-8 m seen on a capped step). Without it a
0.8 mm cap (0.02 m/s at 25 Hz) refused about a third of the capped moves the client sends. A
quarter of a micrometre per period is far below any arm's resolution."""
MEASURED_TOLERANCE = 0.005
"""m: a measured tool position this close outside its box (tracking error) may still start the
move back into it; farther, nothing moves"""
ORIENTATION_TOLERANCE = 1e-3
"""rad: largest difference between a commanded rotation and the tool-down rotation"""
HOME_SPEED = 0.05
"""m/s: the start move's speed, unless the speed cap is lower"""


class GateRefusal(Exception):
    """The arms cannot start safely (a measured or start pose outside its box); one line."""


def _rotvec_matrix(r) -> np.ndarray:
    r = np.asarray(r, float)
    angle = float(np.linalg.norm(r))
    if angle < 1e-12:
        return np.eye(3)
    k = r / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _fmt(v) -> str:
    return "[" + ", ".join(f"{x:.4f}" for x in np.asarray(v, float)) + "]"


def step_cap(max_step: float) -> float:
    """The longest step (m) the gate passes for a cap of ``max_step``: the cap plus float32
    rounding (`STEP_TOLERANCE`, `STEP_ROUNDING`)."""
    return float(max_step) * (1.0 + STEP_TOLERANCE) + STEP_ROUNDING


class GatedArms:
    """An `daddpg_jax.deploy.arms.Arms` that checks every command before ``arms`` receives it.

    arms: the implementation (driver side); limits: the `SafetyLimits` in force; bases: world
    <- base [2, 4, 4] (the calibration); period: the control period, s; down: [2, 3] the
    tool-down rotation vector of each base (the poses `ArmsEnv` sends).
    """

    def __init__(self, arms, limits: SafetyLimits, bases, period: float, down):
        self.arms, self.limits, self.period = arms, limits, float(period)
        self.bases = np.asarray(bases, float).reshape(NUM_ARMS, 4, 4)
        self.down = np.asarray(down, float).reshape(NUM_ARMS, 3)
        self.low = np.asarray(limits.workspace_low, float)
        self.high = np.asarray(limits.workspace_high, float)
        self.last_pose: np.ndarray | None = None  # [2, 6] the last poses sent (base frames)
        self.last_world: np.ndarray | None = None  # [2, 3] their tool centres, world
        self.last_fingers: np.ndarray | None = None
        self.last_reading = None
        self.refusals: dict[str, int] = {}
        self.refused: list[str] = []  # the first refusals' lines

    # -- frames --------------------------------------------------------------------------------

    def world(self, pos_base) -> np.ndarray:
        """Tool centres [2, 3] in each base frame -> world frame."""
        p = np.asarray(pos_base, float).reshape(NUM_ARMS, 3)
        return np.einsum("aij,aj->ai", self.bases[:, :3, :3], p) + self.bases[:, :3, 3]

    def _outside(self, world, tol: float) -> int | None:
        bad = np.any((world < self.low - tol) | (world > self.high + tol), axis=-1)
        return int(np.argmax(bad)) if np.any(bad) else None

    def _refuse(self, rule: str, line: str) -> None:
        self.refusals[rule] = self.refusals.get(rule, 0) + 1
        if len(self.refused) < 20:
            self.refused.append(line)

    # -- the checks ------------------------------------------------------------------------------

    def check_servo(self, poses) -> str | None:
        """Why the servo poses [2, 6] (base frames) may not be sent, or None."""
        poses = np.asarray(poses, float)
        if poses.shape != (NUM_ARMS, 6) or not np.all(np.isfinite(poses)):
            return "malformed: not two finite poses"
        world = self.world(poses[:, :3])
        arm = self._outside(world, BOX_TOLERANCE)
        if arm is not None:
            return (f"box: the {ARM_NAMES[arm]} target {_fmt(world[arm])} lies outside "
                    f"{_fmt(self.low[arm])}..{_fmt(self.high[arm])}")
        why = self._orientation(poses)
        if why is not None:
            return f"orientation: {why}"
        if self.last_world is None:
            return "step: no start pose was commanded"
        step = np.linalg.norm(world - self.last_world, axis=-1)
        if np.any(step > step_cap(self.limits.max_step)):
            i = int(np.argmax(step))
            return (f"step: the {ARM_NAMES[i]} target moves {step[i] * 1e3:.2f} mm in one "
                    f"period (cap {self.limits.max_step * 1e3:.2f} mm)")
        return self._clearance(world)

    def _clearance(self, world) -> str | None:
        r = self.last_reading
        if r is None or self.limits.min_clearance <= 0:
            return None
        links, tool = self._reading_world(r)
        moved = links + LINK_FOLLOW[None, :, None] * (world - tool)[:, None, :]
        now = float(arm_clearance(np, links))
        after = float(arm_clearance(np, moved))
        if after >= self.limits.min_clearance - 1e-6 or after >= now - 1e-6:
            return None
        return (f"clearance: the arms' predicted gap {after * 1e3:.1f} mm < "
                f"{self.limits.min_clearance * 1e3:.1f} mm and shrinking")

    def _reading_world(self, r):
        """(link points [2, 5, 3], tool centres [2, 3]) of a reading, world frame."""
        R, p = self.bases[:, :3, :3], self.bases[:, :3, 3]
        tool = self.world(r.tool_pose[:, :3])
        links = (np.stack([link_points_base(q) for q in r.joints]) if r.link_points is None
                 else np.asarray(r.link_points, float))
        links = np.einsum("aij,akj->aki", R, links) + p[:, None, :]
        links[:, -1] = tool
        return links, tool

    def check_fingers(self, openings) -> str | None:
        o = np.asarray(openings, float)
        if o.shape != (NUM_ARMS,) or not np.all(np.isfinite(o)):
            return "fingers: not two finite openings"
        lo, hi = float(self.limits.finger_low), float(self.limits.finger_high)
        if np.any(o < lo - 1e-9) or np.any(o > hi + 1e-9):
            return f"fingers: opening {_fmt(o)} outside [{lo:g}, {hi:g}] m"
        return None

    # -- the Arms interface --------------------------------------------------------------------

    def read(self):
        r = self.arms.read()
        self.last_reading = r
        return r

    def servo(self, poses) -> np.ndarray:
        """Sends ``poses`` [2, 6] when they pass, else the last commanded poses (a hold).
        Returns what was sent."""
        why = self.check_servo(poses)
        if why is None:
            poses = np.asarray(poses, float).reshape(NUM_ARMS, 6)
            self.last_pose, self.last_world = poses.copy(), self.world(poses[:, :3])
        else:
            self._refuse(why.split(":", 1)[0], why)
            if self.last_pose is None:  # nothing was ever commanded: nothing to hold
                return None
            poses = self.last_pose
        self.arms.servo(poses)
        return poses

    def grip(self, openings) -> None:
        why = self.check_fingers(openings)
        if why is not None:
            self._refuse("fingers", why)
            return
        self.last_fingers = np.asarray(openings, float).reshape(NUM_ARMS)
        self.arms.grip(self.last_fingers)

    def home_speed(self) -> float:
        return min(HOME_SPEED, self.limits.max_step / self.period)

    def check_start(self, poses) -> None:
        """GateRefusal unless every arm's measured tool position and start pose lie in its
        box. Reads the arms (nothing is sent)."""
        poses = np.asarray(poses, float).reshape(NUM_ARMS, 6)
        self._require_inside(self.world(poses[:, :3]), BOX_TOLERANCE, "the task's start pose",
                             "the limits file's box must hold the start pose")
        self._require_inside(self.world(self.read().tool_pose[:, :3]), MEASURED_TOLERANCE,
                             "the measured tool position", "move it into the box by hand, or "
                             "check the limits and the calibration")
        why = self._orientation(poses)
        if why is not None:
            raise GateRefusal(f"the start pose: {why}; nothing moved")

    def _require_inside(self, world, tol: float, what: str, hint: str) -> None:
        """GateRefusal (one line) when a point of ``world`` [2, 3] lies outside its box."""
        arm = self._outside(world, tol)
        if arm is not None:
            raise GateRefusal(
                f"{what} {_fmt(world[arm])} of the {ARM_NAMES[arm]} arm lies outside its box "
                f"{_fmt(self.low[arm])}..{_fmt(self.high[arm])}; nothing moved ({hint})")

    def _orientation(self, poses) -> str | None:
        """Why a pose [2, 6] does not point the tool down, or None."""
        for i in range(NUM_ARMS):
            diff = _rotvec_matrix(poses[i, 3:]) @ _rotvec_matrix(self.down[i]).T
            angle = np.arccos(np.clip((np.trace(diff) - 1.0) / 2.0, -1.0, 1.0))
            if angle > ORIENTATION_TOLERANCE:
                return f"the {ARM_NAMES[i]} tool turned {angle:.3f} rad from down"
        return None

    def home(self, poses) -> None:
        """The start move: checked (`check_start`), then a straight line at `home_speed`."""
        self.check_start(poses)
        poses = np.asarray(poses, float).reshape(NUM_ARMS, 6)
        self.arms.home(poses, self.home_speed())
        self.last_pose, self.last_world = poses.copy(), self.world(poses[:, :3])

    def stop(self) -> None:
        self.arms.stop()

    def close(self) -> None:
        self.arms.close()

    def __getattr__(self, name):  # the implementation's extras (sent, cell, stopped, ...)
        if name == "arms":
            raise AttributeError(name)
        return getattr(self.arms, name)
