"""The simulated arms: `SimArms`, the simulator's implementation of the arms interface
(``daddpg-robot-client --arms sim``), and a simulated UR controller pair for rehearsals
(``--arms ur-sim``): the subset of ur_rtde's API that `daddpg_jax.deploy.arms.URArms` calls,
standing on the MuJoCo simulator (`mjx_envs.numpy_env.NumpyDualArmEnv`), so that the UR
implementation runs unchanged. Both stand on one `SimCell`.

`SimCell` is the physical cell: one simulator with both arms. Each arm's base is at
`daddpg_jax.deploy.ur3.BASE_POS` / ``BASE_YAW`` plus a calibration error (``offset`` [2, 3] m,
``yaw`` [2] rad), applied to the model as `mjx_envs.randomize` does for ``base_offset`` /
``base_yaw`` (the mounts and the tool orientation move with the base). `SimRTDEControl` and
`SimRTDEReceive` answer in each arm's true base frame with rotation vectors, the TCP at the
fingertip centre (the ``grip`` site). The cell advances one control period once both arms have
received their servoL of the period (the grippers' commands of the period come first), so an
unpaced run steps exactly like the simulator. `SimGripper` is the simulated gripper and
`SimObjectSource` the cell's object. A protective or emergency stop can be raised on an arm
(``cell.protective[i] = True``) to rehearse the stop path.

The simulated controllers keep a clock that advances with wall time, as a real controller's
does (RTDE's ``getTimestamp``), also in a dry run, and a watchdog: once armed with
``setWatchdog(f)``, a controller not kicked within ``1 / f`` s stops its script (the next
servoL returns False and moves nothing), as ur_rtde's does. ``moveL`` runs a straight line at
its speed, one control period at a time.
"""

from __future__ import annotations

import time

import numpy as np

from daddpg_jax.deploy import robot, ur3
from daddpg_jax.deploy.arms import (
    ArmsEnv,
    ArmsReading,
    CallGuard,
    Gripper,
    URArms,
    base_transform,
    invert,
    raise_if_stopped,
)
from mjx_envs import observation as obs_lib
from mjx_envs import randomize
from mjx_envs.registry import OBJECTS

HOME_TOLERANCE = 0.002
"""moveL: the cell steps until each TCP is within this of its target, m"""
HOME_MAX_STEPS = 200


class SimCell:
    """Both simulated arms in one simulator; ``env`` a `NumpyDualArmEnv` of the task."""

    def __init__(self, env, offset=None, yaw=None):
        self.env = env
        self.offset = np.zeros((2, 3)) if offset is None else np.asarray(offset, float)
        self.yaw = np.zeros(2) if yaw is None else np.asarray(yaw, float)
        self.bases = np.stack([base_transform(ur3.BASE_POS[a] + self.offset[i],
                                              ur3.BASE_YAW[a] + self.yaw[i])
                               for i, a in enumerate(robot.ARMS)])
        self.inv = np.stack([invert(T) for T in self.bases])
        if np.any(self.offset) or np.any(self.yaw):
            self._move_bases()
        m = env.model
        self.joint_adr = np.array([[m.jnt_qposadr[m.joint(f"{p}_j{k + 1}").id]
                                    for k in range(6)] for p in robot.ARMS])
        self.grip_site = [m.site(f"{p}_grip").id for p in robot.ARMS]
        self.targets = env.home_mocap.astype(float).copy()
        self.ctrl = env.finger_ctrl(np.zeros(2, np.float32)).astype(float)
        self.pending: set[int] = set()
        self.protective = [False, False]
        self.emergency = [False, False]
        self.steps = 0

    def _move_bases(self):
        env = self.env
        obj = OBJECTS.get(env.task)
        r = randomize.Randomization(base_offset=1.0, base_yaw=1.0)
        ix = randomize.ModelIndex(env.model, None if obj is None else obj[1], r)
        params = randomize.nominal_params()
        params[5:11] = self.offset.reshape(-1)
        params[11:13] = self.yaw
        fields = randomize.model_fields(np, ix, params)
        env.model.body_pos[:] = fields["body_pos"]
        env.model.body_quat[:] = fields["body_quat"]
        env.home_mocap = np.asarray(randomize.to_true(np, ix, params, env.home_mocap),
                                    np.float32)

    # -- the physical cell -------------------------------------------------------------------

    def reset(self, qpos):
        self.env.reset(goal=np.zeros((2, 3), np.float32), qpos=qpos)
        self.targets = self.env.home_mocap.astype(float).copy()
        self.pending.clear()

    def step(self):
        """One control period towards ``targets`` with the finger servo targets ``ctrl``."""
        self.env.step_targets(self.targets.astype(np.float32), self.ctrl.astype(np.float32))
        self.pending.clear()
        self.steps += 1

    def set_target(self, arm: int, pose):
        """Arm ``arm``'s target from a pose in its true base frame (position; the tool stays
        down)."""
        self.targets[arm] = self.bases[arm, :3, :3] @ np.asarray(pose[:3], float) \
            + self.bases[arm, :3, 3]

    def settle(self):
        """Step until each tool centre is within `HOME_TOLERANCE` of its target (at most
        `HOME_MAX_STEPS` periods)."""
        for _ in range(HOME_MAX_STEPS):
            if np.all(np.linalg.norm(self._grip_world() - self.targets, axis=-1)
                      <= HOME_TOLERANCE):
                break
            self.step()

    def servo(self, arm: int, pose):
        self.set_target(arm, pose)
        self.pending.add(arm)
        if len(self.pending) == 2:
            self.step()

    def move(self, arm: int, pose, speed: float):
        """A straight line of arm ``arm``'s target to ``pose`` (its true base frame) at
        ``speed`` m/s, one control period at a time, then `settle`."""
        start = self.targets[arm].copy()
        self.set_target(arm, pose)
        end = self.targets[arm].copy()
        length = float(np.linalg.norm(end - start))
        step = float(speed) * float(self.env.dt)
        n = int(np.ceil(length / step)) if step > 0 else 0
        for k in range(1, min(n, HOME_MAX_STEPS)):
            self.targets[arm] = start + (end - start) * (k / n)
            self.step()
        self.targets[arm] = end
        self.settle()

    def grip(self, arm: int, opening: float):
        self.ctrl[2 * arm:2 * arm + 2] = float(opening)

    def arm_sensors(self):
        """The arm sensors now (world frame, `mjx_envs.observation.read_arm_sensors`)."""
        return obs_lib.read_arm_sensors(np, self.env.sensors, self.env._sens)

    def _grip_world(self):
        return np.asarray(self.arm_sensors()["grip_pos"], float)

    def truth(self):
        """The true (arm readings, object readings) in the world frame (ground truth for
        `daddpg_jax.deploy.arms.ArmsEnv`'s success)."""
        env = self.env
        return (obs_lib.read_arm_sensors(np, env.sensors, env._sens),
                obs_lib.read_object_sensors(np, env.sensors, env._sens))

    # -- what a controller reports (base frame) ------------------------------------------------
    # ``sens``: the arm sensors of `arm_sensors`, when the caller already read them

    def tcp_pose(self, arm: int, sens=None):
        sens = self.arm_sensors() if sens is None else sens
        p = self.inv[arm, :3, :3] @ np.asarray(sens["grip_pos"][arm], float) \
            + self.inv[arm, :3, 3]
        R = self.inv[arm, :3, :3] @ self.env.data.site_xmat[self.grip_site[arm]].reshape(3, 3)
        return list(p) + list(robot.matrix_to_rotvec(R))

    def tcp_speed(self, arm: int, sens=None):
        sens = self.arm_sensors() if sens is None else sens
        v = self.inv[arm, :3, :3] @ np.asarray(sens["grip_vel"][arm], float)
        return list(v) + [0.0, 0.0, 0.0]

    def joints(self, arm: int):
        return [float(x) for x in self.env._qpos[self.joint_adr[arm]]]

    def fingers(self, arm: int, sens=None):
        sens = self.arm_sensors() if sens is None else sens
        return tuple(float(x) for x in sens["fingers"][arm])

    def finger_speeds(self, arm: int, sens=None):
        sens = self.arm_sensors() if sens is None else sens
        return tuple(float(x) for x in sens["finger_vel"][arm])

    def link_points(self, arm: int, sens=None):
        """The simulator's link points of arm ``arm`` [5, 3] (shoulder, elbow, wrist 1,
        flange, tool centre) in its true base frame."""
        sens = self.arm_sensors() if sens is None else sens
        pts = np.asarray(sens["link_points"][arm], float)
        return pts @ self.inv[arm, :3, :3].T + self.inv[arm, :3, 3]


class SimArms:
    """The simulator as an implementation of the arms interface
    (`daddpg_jax.deploy.arms.Arms`), talking to a `SimCell` directly: ``read`` reports what
    the cell's sensors measure in each true base frame (the tool pose and speed, the joint
    angles, the finger openings and speeds, and the simulator's own link points), ``servo``
    steps the cell one control period, ``home`` steps it until both tools are at their start
    poses. A protective or emergency stop raised on the cell (``cell.protective[i] = True``)
    ends the run as on real arms."""

    def __init__(self, cell: SimCell, clock=time.perf_counter):
        self.cell, self.clock = cell, clock
        self.stopped = False
        self.wall = time.perf_counter  # the controllers' clock: wall time, as on a robot

    def read(self) -> ArmsReading:
        cell = self.cell
        raise_if_stopped(cell.emergency, cell.protective)
        t = self.clock()
        stamp = self.wall()
        sens, arms = cell.arm_sensors(), range(2)
        return ArmsReading(
            tool_pose=np.array([cell.tcp_pose(i, sens) for i in arms], float),
            tool_speed=np.array([cell.tcp_speed(i, sens) for i in arms], float),
            joints=np.array([cell.joints(i) for i in arms], float),
            fingers=np.array([cell.fingers(i, sens) for i in arms], float),
            captured_at=t,
            finger_speed=np.array([cell.finger_speeds(i, sens) for i in arms], float),
            link_points=np.stack([cell.link_points(i, sens) for i in arms]),
            controller_time=np.array([stamp, stamp]))

    def servo(self, poses) -> None:
        poses = np.asarray(poses, float).reshape(2, 6)
        for i in range(2):
            self.cell.servo(i, poses[i])

    def grip(self, openings) -> None:
        for i, o in enumerate(np.asarray(openings, float).reshape(2)):
            self.cell.grip(i, o)

    def home(self, poses, speed: float) -> None:
        poses = np.asarray(poses, float).reshape(2, 6)
        for i in range(2):
            self.cell.move(i, poses[i], speed)

    def stop(self) -> None:
        """The simulated arms rest between control periods: nothing to send."""
        self.stopped = True

    def close(self) -> None:
        self.stop()


class SimRTDEControl:
    """``rtde_control.RTDEControlInterface``'s subset, on arm ``arm`` of a `SimCell`."""

    def __init__(self, cell: SimCell, arm: int, wall=time.perf_counter):
        self.cell, self.arm, self.wall = cell, arm, wall
        self.servoing = False
        self.connected = True
        self.running = True  # the control script; a tripped watchdog stops it
        self.watchdog_s: float | None = None
        self.kicked = 0.0

    def _watchdog_ok(self) -> bool:
        if self.watchdog_s is not None and self.wall() - self.kicked > self.watchdog_s:
            self.running = self.servoing = False
        return self.running

    def setWatchdog(self, min_frequency=10.0):  # noqa: N802
        self.watchdog_s = 1.0 / float(min_frequency)
        self.kicked = self.wall()
        return True

    def kickWatchdog(self):  # noqa: N802
        if self._watchdog_ok():
            self.kicked = self.wall()
        return self.running

    def servoL(self, pose, speed, acceleration, time, lookahead_time, gain):  # noqa: N802
        if not self._watchdog_ok():
            return False
        self.servoing = True
        self.cell.servo(self.arm, pose)
        return True

    def servoStop(self, a=10.0):  # noqa: N802
        self.servoing = False
        return True

    def moveL(self, pose, speed=0.25, acceleration=1.2, asynchronous=False):  # noqa: N802
        if not self._watchdog_ok():
            return False
        self.cell.move(self.arm, pose, speed)
        return True

    def stopScript(self):  # noqa: N802
        self.servoing = False

    def disconnect(self):
        self.connected = False


class SimRTDEReceive:
    """``rtde_receive.RTDEReceiveInterface``'s subset, on arm ``arm`` of a `SimCell`."""

    def __init__(self, cell: SimCell, arm: int, wall=time.perf_counter):
        self.cell, self.arm, self.wall = cell, arm, wall
        self.started = wall()

    def getTimestamp(self):  # noqa: N802
        """The controller's clock, s since it started: wall time, as on a robot."""
        return self.wall() - self.started

    def getActualTCPPose(self):  # noqa: N802
        return self.cell.tcp_pose(self.arm)

    def getActualTCPSpeed(self):  # noqa: N802
        return self.cell.tcp_speed(self.arm)

    def getActualQ(self):  # noqa: N802
        return self.cell.joints(self.arm)

    def isProtectiveStopped(self):  # noqa: N802
        return bool(self.cell.protective[self.arm])

    def isEmergencyStopped(self):  # noqa: N802
        return bool(self.cell.emergency[self.arm])

    def disconnect(self):
        pass


class SimGripper(Gripper):
    """The simulated two-finger gripper of arm ``arm`` (finger servo targets of the cell)."""

    def __init__(self, cell: SimCell, arm: int):
        self.cell, self.arm = cell, arm

    def move(self, opening: float) -> None:
        self.cell.grip(self.arm, opening)

    def openings(self) -> tuple[float, float]:
        return self.cell.fingers(self.arm)

    def speeds(self) -> tuple[float, float]:
        return self.cell.finger_speeds(self.arm)


class SimObjectSource:
    """The cell's object (world frame), placed at the episode's drawn start by ``reset``."""

    def __init__(self, cell: SimCell):
        self.cell = cell

    def reset(self, qpos) -> None:
        self.cell.reset(qpos)

    def read(self) -> dict:
        env = self.cell.env
        return obs_lib.read_object_sensors(np, env.sensors, env._sens)


def sim_ur_arms(env, period: float, offset=None, yaw=None, dry_run: bool = False,
                call_timeout: float | None = None, watchdog: float | None = None):
    """(`URArms` on a simulated cell, the cell, its object source): ``env`` a fresh
    `NumpyDualArmEnv` of the task (the cell's physics), the calibration error ``offset`` [2, 3]
    m and ``yaw`` [2] rad of the true bases; call_timeout, watchdog: see `URArms`."""
    cell = SimCell(env, offset, yaw)
    controls = None if dry_run else [SimRTDEControl(cell, i) for i in range(2)]
    receives = [SimRTDEReceive(cell, i) for i in range(2)]
    grippers = [SimGripper(cell, i) for i in range(2)]
    guard = None if call_timeout is None else CallGuard(call_timeout)
    return (URArms(controls, receives, grippers, period, guard=guard, watchdog=watchdog), cell,
            SimObjectSource(cell))


def sim_ur_env(spec, cell_env, period: float, bases=None, offset=None, yaw=None,
               dry_run: bool = False, safety=None, call_timeout: float | None = None,
               watchdog: float | None = None, sources=None):
    """`daddpg_jax.deploy.arms.ArmsEnv` of `URArms` on a simulated cell (``cell_env``, a
    `NumpyDualArmEnv` of the task) with its object source and ground truth; ``bases``: the robot
    side's world <- base transforms (default nominal), ``offset``/``yaw``: the cell's
    calibration error; ``safety``: the gate's `SafetyLimits` (None: the simulator's own);
    ``sources``: called with the cell, (object source, goal source), either None for the
    cell's own (`daddpg_jax.deploy.perception.Perception`: a camera)."""
    arms, cell, objects = sim_ur_arms(cell_env, period, offset, yaw, dry_run, call_timeout,
                                      watchdog)
    camera_objects, goals = (None, None) if sources is None else sources(cell)
    return ArmsEnv(spec, arms, bases=bases, objects=camera_objects or objects,
                   truth=cell.truth, safety=safety, goals=goals)


def sim_env(spec, cell_env, bases=None, offset=None, yaw=None, safety=None, sources=None):
    """`daddpg_jax.deploy.arms.ArmsEnv` of `SimArms` on a simulated cell (``cell_env``, a
    `NumpyDualArmEnv` of the task) with its object source and ground truth (``--arms sim``);
    ``bases``: the robot side's world <- base transforms (default nominal), ``offset``/``yaw``:
    the cell's calibration error (default none); ``safety``: the gate's `SafetyLimits` (None:
    the simulator's own); ``sources``: as `sim_ur_env`'s."""
    cell = SimCell(cell_env, offset, yaw)
    objects, goals = (None, None) if sources is None else sources(cell)
    return ArmsEnv(spec, SimArms(cell), bases=bases, objects=objects or SimObjectSource(cell),
                   truth=cell.truth, safety=safety, goals=goals)
