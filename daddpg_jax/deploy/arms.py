"""One arms interface for the robot client's loop, with two implementations (NumPy only at
import; ``ur_rtde`` is imported lazily by `connect_ur`).

The loop (`daddpg_jax.deploy.robot.run_episode`) drives an object with the env API
``reset(rng, goal, qpos)``, ``command_targets(action)``, ``finger_ctrl(cmd)``,
``step_targets(target, ctrl)``, ``target``, ``episode_length``, ``config`` (world frame, m).
For every kind of arms that object is `ArmsEnv`, which puts an implementation of the
interface `Arms` behind the env API with the task's rules (goals, success), the frame
conversion, the joint-limit check and an object source. `Arms`:

- ``read()``: each tool pose ``[x, y, z, rx, ry, rz]`` (rotation vector) and speed in its arm's
  base frame, the joint angles (the clearance check builds the link points from them with
  `daddpg_jax.deploy.ur3`, unless the arms measure the link points themselves) and the finger
  openings, with the capture time (`ArmsReading`);
- ``servo(poses)``: one Cartesian target per arm in its base frame, the tool pointing down
  (`daddpg_jax.deploy.robot.tool_down_rotvec`);
- ``grip(openings)``: each gripper's finger opening, m;
- ``home(poses)``: move slowly to the episode's start poses (blocking);
- ``stop()`` / ``close()``.

Implementations (`make_env`):

- ``--arms sim``: `daddpg_jax.deploy.ursim.SimArms`, the simulator
  (`mjx_envs.numpy_env.NumpyDualArmEnv`, one `daddpg_jax.deploy.ursim.SimCell` with both
  arms) answering the interface directly in each base frame; it also reports the simulator's
  own link points, so that an episode observes, moves and succeeds as when the simulator is
  stepped directly (`tests/test_arms.py`), except that a target a UR3 cannot reach with the
  tool down is refused here, as for UR arms (`ArmsEnv._reachable`), where the simulator would
  follow it as far as its arm goes;
- ``--arms ur``: `URArms`, two ``ur_rtde`` connections (``RTDEControlInterface`` +
  ``RTDEReceiveInterface`` per arm) and one `Gripper` per arm;
- ``--arms ur-sim``: the same `URArms` on `daddpg_jax.deploy.ursim`'s simulated controllers.

The simulator stepped directly through its own env API (no `Arms`) remains the library's
stand-in for in-process evaluation and `daddpg_jax.deploy.robot.replay_episode`.

Frames: ``bases`` [2, 4, 4] are world <- base transforms of the two arms: the nominal
`daddpg_jax.deploy.ur3.BASE_POS` / ``BASE_YAW`` or the calibration of the limits file
(`daddpg_jax.deploy.limits.RobotLimits.base_transforms`, written by ``daddpg-calibrate``). Every
conversion between the policy's world frame and the arms' base frames uses them.

Object poses come from an `ObjectSource`: `NoObject` (reach; real-arm reach runs need no
object) or the simulated cell's (`daddpg_jax.deploy.ursim.SimObjectSource`). A camera belongs
here too: a class with ``reset(qpos)`` (a person places the object; the drawn placement is only
a suggestion) and ``read()`` returning the world-frame dict of
`mjx_envs.observation.read_object_sensors` (``pos``, ``quat`` (w, x, y, z), ``linvel``,
``angvel``, ``object_point`` [2, 3], ``present``), passed to `ArmsEnv` as ``objects``.
"""

from __future__ import annotations

import socket
import time
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from daddpg_jax.deploy.arm_frames import (  # noqa: F401 - the frame helpers stay importable here
    IK_ITERATIONS,
    IK_TOLERANCE,
    JOINT_MARGIN,
    base_transform,
    invert,
    joint_solution,
    link_points_base,
    nominal_bases,
    tool_down_rotvec,
    within_joint_limits,
)
from mjx_envs import observation as obs_lib

NUM_ARMS = 2
ARM_NAMES = ("left", "right")

# servoL settings (UR script servol(pose, a, v, t, lookahead_time, gain)): ``time`` is the
# control period (the command is valid until the next one), ``lookahead_time`` in [0.03, 0.2] s
# smooths the trajectory (larger: smoother, more lag), ``gain`` in [100, 2000] is the
# proportional gain of the position servo (larger: stiffer, more overshoot). speed and
# acceleration are unused by servoL in ur_rtde 1.6 but must be passed.
SERVO_SPEED = 0.5
SERVO_ACCEL = 0.5
SERVO_LOOKAHEAD_S = 0.1
SERVO_GAIN = 300.0
HOME_SPEED = 0.05
"""moveL to the episode's start pose: tool speed, m/s (slow)"""
HOME_ACCEL = 0.25
"""moveL acceleration, m/s^2"""
SERVO_STOP_DECEL = 10.0
"""servoStop deceleration, m/s^2 (ur_rtde's default)"""

# the ur_rtde methods URArms calls and with how many arguments (checked against the installed
# package by tests/test_arms.py)
CONTROL_CALLS = {"servoL": 6, "servoStop": 1, "moveL": 3, "stopScript": 0, "disconnect": 0}
RECEIVE_CALLS = {"getActualTCPPose": 0, "getActualTCPSpeed": 0, "getActualQ": 0,
                 "isProtectiveStopped": 0, "isEmergencyStopped": 0, "disconnect": 0}


class ArmsError(RuntimeError):
    """The arms cannot be used (no connection, ur_rtde missing); one line."""


class ArmsUsageError(ArmsError):
    """Arguments that cannot select arms (a usage error, exit 2)."""


class ArmsStopped(RuntimeError):
    """An arm reports a protective or emergency stop; the run must end (one line)."""


@dataclass
class ArmsReading:
    """What `Arms.read` returns; poses and speeds in each arm's base frame."""

    tool_pose: np.ndarray  # [2, 6] x, y, z (m), rotation vector (rad)
    tool_speed: np.ndarray  # [2, 6] linear (m/s), angular (rad/s)
    joints: np.ndarray  # [2, 6] rad
    fingers: np.ndarray  # [2, 2] opening of each finger, m
    captured_at: float  # monotonic seconds (time.perf_counter)
    finger_speed: np.ndarray | None = None  # [2, 2] m/s, when the grippers report it
    link_points: np.ndarray | None = None
    """[2, 5, 3] shoulder, elbow, wrist 1, flange, tool centre in each base frame, when the arms
    measure them (the simulator); None: built from ``joints`` with the DH table"""


class Arms(Protocol):
    """The arms interface that `ArmsEnv` drives (`URArms`, `daddpg_jax.deploy.ursim.SimArms`);
    every pose is in its arm's base frame."""

    def read(self) -> ArmsReading:
        """Both arms' state now; `ArmsStopped` when an arm is in a protective or emergency
        stop."""
        ...

    def servo(self, poses) -> None:
        """Stream this control period's Cartesian targets [2, 6] (tool down)."""
        ...

    def grip(self, openings) -> None:
        """Each gripper's finger opening [2], m (not blocking)."""
        ...

    def home(self, poses) -> None:
        """Move slowly to the start poses [2, 6] (blocking)."""
        ...

    def stop(self) -> None:
        """Stop streaming and bring the arms to rest (abort or exit)."""
        ...

    def close(self) -> None:
        """`stop`, then release the connections."""
        ...


def raise_if_stopped(emergency, protective) -> None:
    """`ArmsStopped` (one line naming the arm) when an arm of ``emergency`` / ``protective``
    ([2] bools, left and right) is stopped."""
    for name, e, p in zip(ARM_NAMES, emergency, protective):
        if e:
            raise ArmsStopped(f"the {name} arm is emergency stopped")
        if p:
            raise ArmsStopped(f"the {name} arm is in a protective stop")


# -- grippers --------------------------------------------------------------------------------

class Gripper:
    """One two-finger gripper. ``move(opening)``: each finger's opening, m (jaw gap twice
    that), not blocking; ``openings()``: (finger 1, finger 2) openings, m; ``close()``.

    To add another gripper, subclass this with those three methods and pass one per arm to
    `URArms` (``grippers=``); the limits' ``finger_min``/``finger_max`` bound what it is sent.
    """

    def move(self, opening: float) -> None:
        raise NotImplementedError

    def openings(self) -> tuple[float, float]:
        raise NotImplementedError

    def speeds(self) -> tuple[float, float] | None:
        """(finger 1, finger 2) opening speeds, m/s, if the gripper reports them; None: the
        change of the openings over the last control period is used."""
        return None

    def close(self) -> None:
        pass


class RobotiqGripper(Gripper):
    """A Robotiq-style two-finger gripper (2F-85) through the URCap's ASCII socket on the arm's
    controller (port 63352): ``SET ACT 1`` / ``SET GTO 1`` at start, ``SET POS n`` to move,
    ``GET POS`` to read, n in 0 (open) .. 255 (closed) over ``stroke`` m of jaw gap.
    ``read_only``: never sends SET (dry runs). Every exchange has ``timeout`` s."""

    PORT = 63352

    def __init__(self, host: str, port: int = PORT, stroke: float = 0.085, speed: int = 255,
                 force: int = 50, timeout: float = 0.02, read_only: bool = False):
        self.stroke, self.read_only, self.timeout = float(stroke), bool(read_only), timeout
        try:
            self.sock = socket.create_connection((host, port), timeout=1.0)
        except OSError as e:
            raise ArmsError(f"cannot connect to the gripper at {host}:{port}: "
                            f"{e.strerror or e}") from None
        self.sock.settimeout(timeout)
        self._buf = b""
        if not self.read_only:
            for cmd in ("SET ACT 1", f"SET SPE {int(speed)}", f"SET FOR {int(force)}",
                        "SET GTO 1"):
                self._ask(cmd)

    def _ask(self, cmd: str) -> str:
        self.sock.sendall(cmd.encode() + b"\n")
        deadline = time.monotonic() + self.timeout
        while b"\n" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise ArmsError(f"gripper did not answer {cmd!r} within "
                                f"{self.timeout * 1e3:g} ms")
            self.sock.settimeout(left)
            chunk = self.sock.recv(256)
            if not chunk:
                raise ArmsError("gripper closed the connection")
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        return line.decode("ascii", "replace").strip()

    def position_of(self, opening: float) -> int:
        gap = 2.0 * float(opening)
        return int(round(np.clip(1.0 - gap / self.stroke, 0.0, 1.0) * 255))

    def move(self, opening: float) -> None:
        if not self.read_only:
            self._ask(f"SET POS {self.position_of(opening)}")

    def openings(self) -> tuple[float, float]:
        ans = self._ask("GET POS").split()
        if len(ans) != 2 or ans[0] != "POS" or not ans[1].isdigit():
            raise ArmsError(f"gripper answered {' '.join(ans)!r} to GET POS")
        o = (1.0 - int(ans[1]) / 255.0) * self.stroke / 2.0
        return o, o

    def close(self) -> None:
        self.sock.close()


# -- object sources --------------------------------------------------------------------------

class NoObject:
    """Tasks without an object (reach): zero object terms."""

    def reset(self, qpos) -> None:
        pass

    def read(self) -> dict:
        return obs_lib.read_object_sensors(np, obs_lib.SensorLayout({}, 0), np.zeros(0))


# -- UR arms ---------------------------------------------------------------------------------

class URArms:
    """Two UR arms through ur_rtde-style objects (real ``RTDEControlInterface`` /
    ``RTDEReceiveInterface`` or `daddpg_jax.deploy.ursim`'s): ``controls`` (None in a dry run:
    read-only, nothing is sent; ``sent`` records what would have been), ``receives``,
    ``grippers`` (one `Gripper` per arm). A hold is a servoL of the held pose; servoStop comes
    only from ``stop()`` (abort or exit)."""

    def __init__(self, controls, receives, grippers, period: float, clock=time.perf_counter):
        self.controls, self.receives, self.grippers = controls, receives, list(grippers)
        self.period, self.clock = float(period), clock
        self.dry_run = controls is None
        self.sent: list[dict] = []
        self.stopped = False

    def read(self) -> ArmsReading:
        raise_if_stopped([r.isEmergencyStopped() for r in self.receives],
                         [r.isProtectiveStopped() for r in self.receives])
        t = self.clock()
        pose = np.array([r.getActualTCPPose() for r in self.receives], float)
        speed = np.array([r.getActualTCPSpeed() for r in self.receives], float)
        q = np.array([r.getActualQ() for r in self.receives], float)
        fingers = np.array([g.openings() for g in self.grippers], float)
        speeds = [g.speeds() for g in self.grippers]
        fs = None if any(v is None for v in speeds) else np.array(speeds, float)
        return ArmsReading(pose, speed, q, fingers, t, fs)

    def _dry(self, command: str, values) -> bool:
        """In a dry run, records what `command` would send (in ``sent``) and returns True."""
        if self.dry_run:
            self.sent.append({command: values.round(6).tolist()})
        return self.dry_run

    def servo(self, poses) -> None:
        poses = np.asarray(poses, float).reshape(NUM_ARMS, 6)
        if self._dry("servoL", poses):
            return
        for c, p in zip(self.controls, poses):
            c.servoL(p.tolist(), SERVO_SPEED, SERVO_ACCEL, self.period, SERVO_LOOKAHEAD_S,
                     SERVO_GAIN)

    def grip(self, openings) -> None:
        openings = np.asarray(openings, float).reshape(NUM_ARMS)
        if self._dry("grip", openings):
            return
        for g, o in zip(self.grippers, openings):
            g.move(float(o))

    def home(self, poses) -> None:
        poses = np.asarray(poses, float).reshape(NUM_ARMS, 6)
        if self._dry("moveL", poses):
            return
        for c, p in zip(self.controls, poses):
            c.moveL(p.tolist(), HOME_SPEED, HOME_ACCEL)

    def stop(self) -> None:
        if not self.dry_run and not self.stopped:
            for c in self.controls:
                c.servoStop(SERVO_STOP_DECEL)
        self.stopped = True

    def close(self) -> None:
        try:
            self.stop()
        finally:
            for c in self.controls or ():
                c.stopScript()
                c.disconnect()
            for r in self.receives:
                r.disconnect()
            for g in self.grippers:
                g.close()


def receive_only(hosts) -> list:
    """Read-only ``RTDEReceiveInterface`` connections to ``hosts`` (left, right); ArmsError
    (one line) when ur_rtde is missing or an arm cannot be reached."""
    try:  # lazy: the optional extra [ur]
        import rtde_receive
    except ImportError:
        raise ArmsError("ur_rtde is not installed: pip install 'daddpg-jax[ur]'") from None
    out = []
    for name, host in zip(ARM_NAMES, hosts):
        try:
            out.append(rtde_receive.RTDEReceiveInterface(host))
        except RuntimeError as e:
            for r in out:
                r.disconnect()
            raise ArmsError(f"cannot connect to the {name} arm at {host}: "
                            f"{' '.join(str(e).split())[:200]}") from None
    return out


def connect_ur(hosts, period: float, dry_run: bool = False, gripper_factory=None) -> URArms:
    """`URArms` on two real controllers (``hosts``: left, right). ``ur_rtde`` is imported here
    (the optional extra ``[ur]``). ArmsError (one line) when it is missing or an arm or gripper
    cannot be reached. gripper_factory(host, read_only) -> Gripper (default `RobotiqGripper`)."""
    try:  # lazy: the optional extra [ur]; the rest of the robot side runs without it
        import rtde_control
        import rtde_receive
    except ImportError:
        raise ArmsError("ur_rtde is not installed: pip install 'daddpg-jax[ur]'") from None
    factory = gripper_factory or (lambda h, ro: RobotiqGripper(h, read_only=ro))
    controls, receives, grippers = [], [], []
    try:
        for name, host in zip(ARM_NAMES, hosts):
            try:
                receives.append(rtde_receive.RTDEReceiveInterface(host))
                if not dry_run:
                    controls.append(rtde_control.RTDEControlInterface(host))
            except RuntimeError as e:
                raise ArmsError(f"cannot connect to the {name} arm at {host}: "
                                f"{' '.join(str(e).split())[:200]}") from None
            grippers.append(factory(host, dry_run))
    except ArmsError:
        for x in controls + receives:
            x.disconnect()
        for g in grippers:
            g.close()
        raise
    return URArms(None if dry_run else controls, receives, grippers, period)


# -- the env API on top of an Arms ------------------------------------------------------------

class ArmsEnv:
    """The loop's env API on an `Arms` (`URArms`, `daddpg_jax.deploy.ursim.SimArms`): goals,
    start placements, achieved goals and success from ``spec``'s task rules (a
    `mjx_envs.numpy_env.NumpyDualArmEnv` of the served task, never stepped), targets converted
    to each arm's base frame with ``bases`` [2, 4, 4] (world <- base), observations built with
    `mjx_envs.observation` from the arms' read-out and ``objects`` (an object source).
    ``truth``: a callable returning the true (arm readings, object readings) of a simulated
    cell (`daddpg_jax.deploy.ursim.SimCell.truth`); when given, achieved goals and success are
    the cell's ground truth, else (real arms) what the arms report in the calibrated frame."""

    def __init__(self, spec, arms, bases=None, objects=None, truth=None):
        self.spec, self.arms, self.truth = spec, arms, truth
        self.bases = nominal_bases() if bases is None else np.asarray(bases, float)
        self.inv = np.stack([invert(T) for T in self.bases])
        self.down = np.stack([tool_down_rotvec(T) for T in self.bases])
        self.objects = objects if objects is not None else NoObject()
        self.config, self.task = spec.config, spec.task
        self.episode_length, self.dt = spec.episode_length, spec.dt
        self._target = spec.home_mocap.copy()
        self._goal = np.zeros((NUM_ARMS, 3), np.float32)
        self._prev_fingers = self._last_fingers = None
        self._t, self._fingers_t = 0, 0
        self.refused = 0  # targets refused for want of a joint solution within the limits

    # frames
    def to_base_poses(self, target_world) -> np.ndarray:
        """Targets [2, 3] (world) -> servoL poses [2, 6] in each base frame, tool down."""
        t = np.asarray(target_world, float).reshape(NUM_ARMS, 3)
        pos = np.einsum("aij,aj->ai", self.inv[:, :3, :3], t) + self.inv[:, :3, 3]
        return np.concatenate([pos, self.down], axis=-1)

    def _world(self, reading: ArmsReading):
        R, p = self.bases[:, :3, :3], self.bases[:, :3, 3]
        grip = np.einsum("aij,aj->ai", R, reading.tool_pose[:, :3]) + p
        vel = np.einsum("aij,aj->ai", R, reading.tool_speed[:, :3])
        links = (np.stack([link_points_base(q) for q in reading.joints])       # [2, 5, 3]
                 if reading.link_points is None else np.asarray(reading.link_points, float))
        links = np.einsum("aij,akj->aki", R, links) + p[:, None, :]
        links[:, -1] = grip  # the measured tool centre
        return grip, vel, links

    def observe(self):
        """A fresh `mjx_envs.numpy_env.StepResult` from the arms (``captured_at`` set)."""
        from mjx_envs.numpy_env import StepResult  # lazy: MuJoCo; NumPy only at import

        r = self.arms.read()
        self._joints = r.joints
        grip, vel, links = self._world(r)
        fingers = r.fingers
        if self._t != self._fingers_t:  # a new control period: the last one's reading is prev
            self._prev_fingers, self._fingers_t = self._last_fingers, self._t
        self._last_fingers = fingers
        prev = fingers if self._prev_fingers is None else self._prev_fingers
        arm = dict(grip_pos=grip.astype(np.float32), grip_vel=vel.astype(np.float32),
                   fingers=fingers.astype(np.float32),
                   finger_vel=(((fingers - prev) / self.dt) if r.finger_speed is None
                               else r.finger_speed).astype(np.float32),
                   link_points=links.astype(np.float32))
        obj = self.objects.read()
        obs = obs_lib.build_observation(np, arm, obj, self.dt)
        rules = self.spec.rules
        judged = (arm, obj) if self.truth is None else self.truth()
        ag = np.asarray(rules.achieved_goal(*judged), np.float32)
        res = StepResult(observation=np.asarray(obs, np.float32), achieved_goal=ag,
                         desired_goal=self._goal.copy(), link_points=arm["link_points"],
                         target=self._target.copy(),
                         success=bool(rules.success(np, ag, self._goal)),
                         goal_distance=np.asarray(rules.goal_distance(np, ag, self._goal),
                                                  np.float32),
                         arm_clearance=float(obs_lib.arm_clearance(np, arm["link_points"])),
                         step=self._t)
        res.captured_at = r.captured_at
        return res

    # the env API
    def reset(self, rng=None, goal=None, qpos=None):
        if goal is None or qpos is None:
            rng = rng if rng is not None else np.random.default_rng()
            goal = self.spec.sample_goal(rng) if goal is None else goal
            qpos = self.spec.sample_qpos(rng) if qpos is None else qpos
        self._goal = np.asarray(goal, np.float32).reshape(NUM_ARMS, 3).copy()
        self._qpos = np.asarray(qpos, np.float32)
        self.objects.reset(self._qpos)
        self._target = self.spec.home_mocap.copy()
        self.arms.home(self.to_base_poses(self._target))
        self._t, self._fingers_t = 0, 0
        self._prev_fingers = self._last_fingers = None
        res = self.observe()
        self._q = np.array(self._joints, float)
        return res

    def finger_ctrl(self, finger_cmd):
        return self.spec.finger_ctrl(finger_cmd)

    def command_targets(self, action):
        a = np.clip(np.asarray(action, np.float32).reshape(NUM_ARMS, 4), -1.0, 1.0)
        target = np.clip(self._target + self.spec.max_delta * a[:, :3], self.spec.ws_low,
                         self.spec.ws_high)
        return target.astype(np.float32), self.finger_ctrl(a[:, 3])

    def _reachable(self, target):
        """``target`` [2, 3] with each arm whose pose has no joint solution within the joint
        limits (`joint_solution`, warm-started from the last one) kept at its previous
        target; counts those in ``refused``."""
        poses = self.to_base_poses(target)
        out = np.array(target, np.float32)
        for i in range(NUM_ARMS):
            q = joint_solution(self._q[i], poses[i])
            if q is None or not within_joint_limits(q):
                out[i] = self._target[i]
                self.refused += 1
            else:
                self._q[i] = q
        return out

    def step_targets(self, target, ctrl):
        self._target = self._reachable(np.asarray(target, np.float32).reshape(NUM_ARMS, 3))
        ctrl = np.asarray(ctrl, np.float32).reshape(NUM_ARMS, 2)
        self.arms.grip(ctrl[:, 0])
        self.arms.servo(self.to_base_poses(self._target))
        self._t += 1
        return self.observe()

    @property
    def target(self):
        return self._target.copy()

    @property
    def goal(self):
        return self._goal.copy()

    def close(self):
        self.arms.close()


ARMS_KINDS = ("sim", "ur", "ur-sim")


def make_env(kind: str, task_cfg, task: str, period: float, bases=None, hosts=None,
             dry_run: bool = False, base_error=None, exact: bool = True) -> ArmsEnv:
    """The loop's `ArmsEnv` for ``--arms kind``: ``sim`` `daddpg_jax.deploy.ursim.SimArms` on
    the simulator (whose bases are exactly the nominal ones: ``bases`` is not used);
    ``ur`` `URArms` on the controllers at ``hosts`` (left, right; reach only: no object source
    for a real cell is built in); ``ur-sim`` `URArms` on simulated controllers whose bases
    carry ``base_error`` ((offset [2, 3] m, yaw [2] rad)). ``bases``: the robot side's world <-
    base transforms of ``ur`` and ``ur-sim`` (`RobotLimits.base_transforms`). ArmsError (one
    line) when it cannot be made."""
    from mjx_envs.numpy_env import NumpyDualArmEnv  # lazy: MuJoCo; NumPy only at import

    if kind not in ARMS_KINDS:
        raise ArmsUsageError(f"--arms must be one of {', '.join(ARMS_KINDS)}, got {kind!r}")
    if kind == "sim" and dry_run:
        raise ArmsUsageError("--dry-run needs --arms ur or ur-sim (the simulator moves nothing)")
    spec = NumpyDualArmEnv(task_cfg, task=task, exact=exact)
    if kind == "sim":
        from daddpg_jax.deploy.ursim import sim_env  # lazy: ursim imports this module

        return sim_env(spec, NumpyDualArmEnv(task_cfg, task=task, exact=exact))
    if kind == "ur-sim":
        from daddpg_jax.deploy.ursim import sim_ur_env  # lazy: ursim imports this module

        offset, yaw = (None, None) if base_error is None else base_error
        return sim_ur_env(spec, NumpyDualArmEnv(task_cfg, task=task, exact=exact), period,
                          bases=bases, offset=offset, yaw=yaw, dry_run=dry_run)
    if spec.rules.has_object:
        raise ArmsUsageError(f"--arms ur runs reach only: the {task!r} task needs an object source "
                        f"(a camera; see docs/DEPLOYMENT.md)")
    if hosts is None or len(hosts) != 2 or not all(hosts):
        raise ArmsUsageError("--arms ur needs --ur-hosts LEFT,RIGHT")
    return ArmsEnv(spec, connect_ur(hosts, period, dry_run=dry_run), bases=bases)
