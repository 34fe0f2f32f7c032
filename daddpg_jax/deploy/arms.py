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

Implementations (`daddpg_jax.deploy.arms_factory.make_env`):

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
import struct
import threading
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
from daddpg_jax.deploy.gate import GatedArms
from daddpg_jax.deploy.safety import SafetyLimits
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
HOME_ACCEL = 0.25
"""moveL acceleration, m/s^2"""
SERVO_STOP_DECEL = 10.0
"""servoStop deceleration, m/s^2 (ur_rtde's default)"""

# the ur_rtde methods URArms calls and with how many arguments (checked against the installed
# package by tests/test_arms.py)
CONTROL_CALLS = {"servoL": 6, "servoStop": 1, "moveL": 3, "stopScript": 0, "disconnect": 0,
                 "setWatchdog": 1, "kickWatchdog": 0}
RECEIVE_CALLS = {"getActualTCPPose": 0, "getActualTCPSpeed": 0, "getActualQ": 0,
                 "getTimestamp": 0, "isProtectiveStopped": 0, "isEmergencyStopped": 0,
                 "disconnect": 0}


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
    controller_time: np.ndarray | None = None
    """[2] each controller's own clock, s (RTDE's timestamp): readings whose controller time
    does not advance are frozen (`ArmsEnv.observe`); None: not reported"""


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

    def home(self, poses, speed: float) -> None:
        """Move in a straight line at ``speed`` m/s to the start poses [2, 6] (blocking)."""
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
                 force: int = 50, timeout: float = 0.02, read_only: bool = False,
                 connect_timeout: float = 1.0):
        self.stroke, self.read_only, self.timeout = float(stroke), bool(read_only), timeout
        try:
            self.sock = socket.create_connection((host, port), timeout=connect_timeout)
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

CALL_TIMEOUT_S = 0.5
"""Default bound of one driver call, s (`URArms`; the limits file's ``call_timeout``)."""
CONNECT_TIMEOUT_S = 2.0
"""Default bound of connecting to an arm or a gripper, s (the limits' ``connect_timeout``)."""


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split())[:200] or type(e).__name__


def bounded(fn, timeout: float, what: str):
    """``fn()`` run on a helper thread, its result; ArmsError (one line) when it raises or has
    not returned after ``timeout`` s (the thread is left behind, a daemon: drivers such as
    ur_rtde's constructors take no timeout of their own)."""
    box: dict = {}

    def call():
        try:
            box["out"] = fn()
        except BaseException as e:  # noqa: BLE001 - reported on the caller's thread
            box["err"] = e

    t = threading.Thread(target=call, daemon=True, name=f"connect {what}")
    t.start()
    t.join(timeout)
    if t.is_alive():
        raise ArmsError(f"{what} did not answer within {timeout:g} s")
    if "err" in box:
        e = box["err"]
        if isinstance(e, ArmsError):
            raise e
        raise ArmsError(f"cannot connect to {what}: {_one_line(e)}")
    return box["out"]


RTDE_PORT = 30004
RTDE_REQUEST_PROTOCOL_VERSION = 86  # "V"
RTDE_PROTOCOL_VERSION = 2


def probe_rtde(host: str, timeout: float, port: int = RTDE_PORT) -> None:
    """Asks the controller at ``host`` for RTDE protocol version 2 with plain sockets, each
    step bounded by ``timeout`` s; ArmsError (one line) when it does not answer in time or
    refuses. ur_rtde's constructors hold the interpreter while they connect (no thread or
    signal can cut them), so an address that accepts TCP and never answers is found here,
    before they run."""
    deadline = time.monotonic() + timeout
    try:
        with socket.create_connection((host, port), timeout=timeout) as s:
            s.sendall(struct.pack(">HBH", 5, RTDE_REQUEST_PROTOCOL_VERSION,
                                  RTDE_PROTOCOL_VERSION))
            head = b""
            while len(head) < 4:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError
                s.settimeout(left)
                chunk = s.recv(4 - len(head))
                if not chunk:
                    raise ArmsError(f"RTDE port {port} closed the connection")
                head += chunk
    except TimeoutError:
        raise ArmsError(f"no RTDE answer on port {port} within {timeout:g} s") from None
    except OSError as e:
        raise ArmsError(f"RTDE port {port}: {e.strerror or e}") from None
    size, kind, accepted = struct.unpack(">HBB", head)
    if kind != RTDE_REQUEST_PROTOCOL_VERSION or not accepted:
        raise ArmsError(f"RTDE port {port} refused protocol version {RTDE_PROTOCOL_VERSION}")


class CallGuard:
    """Bounds every driver call of `URArms` to ``timeout`` s: a call that has not returned by
    then is reported through ``on_overrun(line)`` from a guard thread (default: the line on
    stderr and exit 4, since the call cannot be interrupted; the controller's watchdog stops the
    arms once nothing kicks it). A call that returns late raises ArmsError on its own thread."""

    def __init__(self, timeout: float, on_overrun=None, clock=time.perf_counter):
        self.timeout, self.clock = float(timeout), clock
        self.on_overrun = on_overrun or _exit_on_overrun
        self._what: str | None = None
        self._since = 0.0
        self._limit = self.timeout
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> CallGuard:
        self._thread = threading.Thread(target=self._watch, daemon=True, name="driver guard")
        self._thread.start()
        return self

    def _watch(self):
        while not self._stop.wait(min(0.05, self.timeout / 4)):
            what, since, limit = self._what, self._since, self._limit
            if what is not None and self.clock() - since > limit:
                self._what = None
                self.on_overrun(f"error: the driver call {what} has not returned after "
                                f"{limit * 1e3:g} ms; the run is stopped")

    def call(self, what: str, fn, *args, timeout: float | None = None, command: bool = True):
        """``fn(*args)``; ArmsError (one line) when it raises, takes longer than ``timeout``
        (default the guard's) or, for a ``command``, returns False."""
        limit = self.timeout if timeout is None else float(timeout)
        self._limit, self._what, self._since = limit, what, self.clock()
        try:
            out = fn(*args)
        except ArmsStopped:
            raise
        except Exception as e:  # noqa: BLE001 - any driver failure ends the run in one line
            raise ArmsError(f"{what} failed: {_one_line(e)}") from None
        finally:
            took = self.clock() - self._since
            self._what = None
        if command and out is False:
            raise ArmsError(f"{what} returned False (the controller refused the command)")
        if took > limit:
            raise ArmsError(f"{what} took {took * 1e3:.0f} ms (limit {limit * 1e3:g} ms)")
        return out

    def close(self):
        self._stop.set()


def _exit_on_overrun(line: str):  # pragma: no cover - ends the process
    import os  # noqa: PLC0415 - lazy: only on a hung driver call
    import sys  # noqa: PLC0415 - lazy: only on a hung driver call

    print(line, file=sys.stderr, flush=True)
    os._exit(4)


class URArms:
    """Two UR arms through ur_rtde-style objects (real ``RTDEControlInterface`` /
    ``RTDEReceiveInterface`` or `daddpg_jax.deploy.ursim`'s): ``controls`` (None in a dry run:
    read-only, nothing is sent; ``sent`` records what would have been), ``receives``,
    ``grippers`` (one `Gripper` per arm). A hold is a servoL of the held pose; servoStop comes
    only from ``stop()`` (abort or exit).

    Every driver call passes ``guard`` (`CallGuard`): one that raises, returns False or
    overruns ends the run (ArmsError, one line). ``watchdog``: seconds; at the first servoL the
    controllers' own watchdog is armed (``setWatchdog(1 / watchdog)``) and it is kicked every
    period, so that an arm stops when the client stops talking."""

    def __init__(self, controls, receives, grippers, period: float, clock=time.perf_counter,
                 guard: CallGuard | None = None, watchdog: float | None = None):
        self.controls, self.receives, self.grippers = controls, receives, list(grippers)
        self.period, self.clock = float(period), clock
        self.guard = guard or CallGuard(CALL_TIMEOUT_S, clock=clock)
        self.watchdog = watchdog
        self.watchdog_armed = False
        self.dry_run = controls is None
        self.sent: list[dict] = []
        self.stopped = False

    def _each(self, what: str, objs, method: str, *args, command: bool = False) -> list:
        return [self.guard.call(f"{method} ({name} {what})", getattr(o, method), *args,
                                command=command) for name, o in zip(ARM_NAMES, objs)]

    def read(self) -> ArmsReading:
        g = self.guard.call
        raise_if_stopped(self._each("arm", self.receives, "isEmergencyStopped"),
                         self._each("arm", self.receives, "isProtectiveStopped"))
        t = self.clock()
        pose = np.array(self._each("arm", self.receives, "getActualTCPPose"), float)
        speed = np.array(self._each("arm", self.receives, "getActualTCPSpeed"), float)
        q = np.array(self._each("arm", self.receives, "getActualQ"), float)
        stamps = np.array(self._each("arm", self.receives, "getTimestamp"), float)
        fingers = np.array([g(f"openings ({n} gripper)", gr.openings, command=False)
                            for n, gr in zip(ARM_NAMES, self.grippers)], float)
        speeds = [gr.speeds() for gr in self.grippers]
        fs = None if any(v is None for v in speeds) else np.array(speeds, float)
        if pose.shape != (NUM_ARMS, 6) or q.shape != (NUM_ARMS, 6) or not (
                np.all(np.isfinite(pose)) and np.all(np.isfinite(q))):
            raise ArmsError("the arms reported a pose or joint angles that are not 6 finite "
                            "numbers")
        return ArmsReading(pose, speed, q, fingers, t, fs, controller_time=stamps)

    def _dry(self, command: str, values) -> bool:
        """In a dry run, records what `command` would send (in ``sent``) and returns True."""
        if self.dry_run:
            self.sent.append({command: values.round(6).tolist()})
        return self.dry_run

    def servo(self, poses) -> None:
        poses = np.asarray(poses, float).reshape(NUM_ARMS, 6)
        if self._dry("servoL", poses):
            return
        if self.watchdog and not self.watchdog_armed:
            self._each("arm", self.controls, "setWatchdog", 1.0 / self.watchdog, command=True)
            self.watchdog_armed = True
        for name, c, p in zip(ARM_NAMES, self.controls, poses):
            if self.watchdog_armed:
                self.guard.call(f"kickWatchdog ({name} arm)", c.kickWatchdog)
            self.guard.call(f"servoL ({name} arm)", c.servoL, p.tolist(), SERVO_SPEED,
                            SERVO_ACCEL, self.period, SERVO_LOOKAHEAD_S, SERVO_GAIN)

    def grip(self, openings) -> None:
        openings = np.asarray(openings, float).reshape(NUM_ARMS)
        if self._dry("grip", openings):
            return
        for name, g, o in zip(ARM_NAMES, self.grippers, openings):
            self.guard.call(f"move ({name} gripper)", g.move, float(o))

    def home(self, poses, speed: float) -> None:
        poses = np.asarray(poses, float).reshape(NUM_ARMS, 6)
        if self._dry("moveL", poses):
            return
        reading = self.read()
        for i, (name, c, p) in enumerate(zip(ARM_NAMES, self.controls, poses)):
            # a straight line at the cap's speed: bounded by its length and speed (twice, and
            # the acceleration's share), not by one period's call timeout
            length = float(np.linalg.norm(p[:3] - reading.tool_pose[i, :3]))
            limit = self.guard.timeout + 2.0 * (length / speed + speed / HOME_ACCEL)
            if self.watchdog_armed:  # the client is talking: a tripped watchdog stays tripped
                self.guard.call(f"kickWatchdog ({name} arm)", c.kickWatchdog)
            self.guard.call(f"moveL ({name} arm)", c.moveL, p.tolist(), float(speed),
                            HOME_ACCEL, timeout=limit)

    def stop(self) -> None:
        """servoStop on both arms (each tried, whatever the other does)."""
        if not self.dry_run and not self.stopped:
            for c in self.controls:
                try:
                    c.servoStop(SERVO_STOP_DECEL)
                except Exception:  # noqa: BLE001, S110 - the other arm must stop too
                    pass
        self.stopped = True

    def close(self) -> None:
        try:
            self.stop()
        finally:
            self.guard.close()
            for x in [*(self.controls or ()), *self.receives, *self.grippers]:
                for method in ("stopScript", "disconnect", "close"):
                    if hasattr(x, method) and not (x in self.receives and method == "close"):
                        try:
                            getattr(x, method)()
                        except Exception:  # noqa: BLE001, S110 - release the others
                            pass


def receive_only(hosts, timeout: float = CONNECT_TIMEOUT_S) -> list:
    """Read-only ``RTDEReceiveInterface`` connections to ``hosts`` (left, right); ArmsError
    (one line) when ur_rtde is missing or an arm cannot be reached within ``timeout`` s."""
    try:  # lazy: the optional extra [ur]
        import rtde_receive
    except ImportError:
        raise ArmsError("ur_rtde is not installed: pip install 'daddpg-jax[ur]'") from None
    out = []
    for name, host in zip(ARM_NAMES, hosts):
        try:
            try:
                probe_rtde(host, timeout)
            except ArmsError as e:
                raise ArmsError(f"cannot connect to the {name} arm at {host}: {e}") from None
            out.append(bounded(lambda h=host: rtde_receive.RTDEReceiveInterface(h), timeout,
                               f"the {name} arm at {host}"))
        except ArmsError:
            for r in out:
                r.disconnect()
            raise
    return out


def connect_ur(hosts, period: float, dry_run: bool = False, gripper_factory=None,
               connect_timeout: float = CONNECT_TIMEOUT_S, call_timeout: float = CALL_TIMEOUT_S,
               watchdog: float | None = None) -> URArms:
    """`URArms` on two real controllers (``hosts``: left, right). ``ur_rtde`` is imported here
    (the optional extra ``[ur]``). ArmsError (one line) when it is missing or an arm or gripper
    cannot be reached within ``connect_timeout`` s. gripper_factory(host, read_only) -> Gripper
    (default `RobotiqGripper`); call_timeout, watchdog: see `URArms`."""
    try:  # lazy: the optional extra [ur]; the rest of the robot side runs without it
        import rtde_control
        import rtde_receive
    except ImportError:
        raise ArmsError("ur_rtde is not installed: pip install 'daddpg-jax[ur]'") from None
    factory = gripper_factory or (lambda h, ro: RobotiqGripper(h, read_only=ro,
                                                               connect_timeout=connect_timeout))
    controls, receives, grippers = [], [], []
    try:
        for name, host in zip(ARM_NAMES, hosts):
            what = f"the {name} arm at {host}"
            try:
                probe_rtde(host, connect_timeout)
            except ArmsError as e:
                raise ArmsError(f"cannot connect to {what}: {e}") from None
            receives.append(bounded(lambda h=host: rtde_receive.RTDEReceiveInterface(h),
                                    connect_timeout, what))
            if not dry_run:
                controls.append(bounded(lambda h=host: rtde_control.RTDEControlInterface(h),
                                        connect_timeout, what))
            grippers.append(bounded(lambda h=host: factory(h, dry_run), connect_timeout,
                                    f"the {name} gripper at {host}"))
    except ArmsError:
        for x in controls + receives:
            try:
                x.disconnect()
            except Exception:  # noqa: BLE001, S110 - release the others
                pass
        for g in grippers:
            g.close()
        raise
    guard = CallGuard(call_timeout).start()
    return URArms(None if dry_run else controls, receives, grippers, period, guard=guard,
                  watchdog=watchdog)


# -- the env API on top of an Arms ------------------------------------------------------------

class ArmsEnv:
    """The loop's env API on an `Arms` (`URArms`, `daddpg_jax.deploy.ursim.SimArms`): goals,
    start placements, achieved goals and success from ``spec``'s task rules (a
    `mjx_envs.numpy_env.NumpyDualArmEnv` of the served task, never stepped), targets converted
    to each arm's base frame with ``bases`` [2, 4, 4] (world <- base), observations built with
    `mjx_envs.observation` from the arms' read-out and ``objects`` (an object source).
    ``truth``: a callable returning the true (arm readings, object readings) of a simulated
    cell (`daddpg_jax.deploy.ursim.SimCell.truth`); when given, achieved goals and success are
    the cell's ground truth, else (real arms) what the arms report in the calibrated frame.

    Every command passes the gate (`daddpg_jax.deploy.gate.GatedArms`, ``self.arms``) with
    ``safety`` (a `SafetyLimits`; None: the simulator's own limits, `safety_of_spec`).
    ``clock``: monotonic seconds; each observation carries ``read_s`` (how long the read took)
    and ``frozen_s`` (how long the controllers' clocks have not advanced).

    ``goals``: a goal source (``read(goal, keepalive) -> (goals the policy sees [2, 3], fault
    or None)``; ``keepalive()`` holds the arms, to be called before each frame),
    `daddpg_jax.deploy.perception.TagGoals`) asked at each reset, after the object is placed
    and before the arms move to the start pose (first to its ``park`` targets [2, 3], world,
    through the gate, when it has them: out of the camera's view); its goals are the
    observations' ``desired_goal`` (success is judged against the drawn goal when ``truth`` is
    given, else against those). Each observation carries ``perception_fault``: the goal
    source's fault of the episode, else the object reading's ``fault`` (a camera source), else
    None; the loop holds while it is set."""

    def __init__(self, spec, arms, bases=None, objects=None, truth=None, safety=None,
                 clock=time.perf_counter, goals=None):
        self.spec, self.truth, self.clock = spec, truth, clock
        self.bases = nominal_bases() if bases is None else np.asarray(bases, float)
        self.inv = np.stack([invert(T) for T in self.bases])
        self.down = np.stack([tool_down_rotvec(T) for T in self.bases])
        self.safety = safety_of_spec(spec) if safety is None else safety
        self.arms = GatedArms(arms, self.safety, self.bases, spec.dt, self.down)
        self.objects = objects if objects is not None else NoObject()
        self.goals = goals
        self._seen_goal: np.ndarray | None = None  # the goal the policy sees (goal source)
        self._goal_fault: str | None = None
        self.config, self.task = spec.config, spec.task
        self.episode_length, self.dt = spec.episode_length, spec.dt
        self._target = spec.home_mocap.copy()
        self._goal = np.zeros((NUM_ARMS, 3), np.float32)
        self._prev_fingers = self._last_fingers = None
        self._t, self._fingers_t = 0, 0
        self._stamp: np.ndarray | None = None  # the controllers' last clock readings
        self._advanced_at = np.zeros(NUM_ARMS)  # when each last advanced (``clock``)
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

    def _frozen_s(self, reading: ArmsReading, now: float) -> float:
        """How long the longest-frozen controller clock has not advanced, s (0: advancing or
        not reported)."""
        stamp = reading.controller_time
        if stamp is None:
            return 0.0
        stamp = np.asarray(stamp, float).reshape(NUM_ARMS)
        if self._stamp is None:
            self._advanced_at[:] = now
        else:
            moved = stamp > self._stamp
            self._advanced_at[moved] = now
        self._stamp = np.where(np.isfinite(stamp), stamp, -np.inf)
        return float(np.max(now - self._advanced_at))

    def observe(self):
        """A fresh `mjx_envs.numpy_env.StepResult` from the arms (``captured_at``, ``read_s``,
        ``frozen_s`` set)."""
        from mjx_envs.numpy_env import StepResult  # lazy: MuJoCo; NumPy only at import

        t0 = self.clock()
        r = self.arms.read()
        t1 = self.clock()
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
        feed = getattr(self.objects, "observe_arms", None)
        if feed is not None:  # a camera's object source carries a held object between frames
            feed(grip)
        obj = self.objects.read()
        obs = obs_lib.build_observation(np, arm, obj, self.dt)
        rules = self.spec.rules
        judged = (arm, obj) if self.truth is None else self.truth()
        ag = np.asarray(rules.achieved_goal(*judged), np.float32)
        seen = self._goal if self._seen_goal is None else self._seen_goal
        goal = self._goal if self.truth is not None else seen
        res = StepResult(observation=np.asarray(obs, np.float32), achieved_goal=ag,
                         desired_goal=seen.copy(), link_points=arm["link_points"],
                         target=self._target.copy(),
                         success=bool(rules.success(np, ag, goal)),
                         goal_distance=np.asarray(rules.goal_distance(np, ag, goal),
                                                  np.float32),
                         arm_clearance=float(obs_lib.arm_clearance(np, arm["link_points"])),
                         step=self._t)
        res.captured_at = r.captured_at
        res.read_s = t1 - t0
        res.frozen_s = self._frozen_s(r, t1)
        res.perception_fault = self._goal_fault or obj.get("fault")
        return res

    # the env API
    def reset(self, rng=None, goal=None, qpos=None):
        """A new episode: the goal and start drawn (or given), the object placed, the arms
        moved to the start pose through the gate (`GateRefusal` when it cannot start)."""
        if goal is None or qpos is None:
            rng = rng if rng is not None else np.random.default_rng()
            goal = self.spec.sample_goal(rng) if goal is None else goal
            qpos = self.spec.sample_qpos(rng) if qpos is None else qpos
        self._goal = np.asarray(goal, np.float32).reshape(NUM_ARMS, 3).copy()
        self._qpos = np.asarray(qpos, np.float32)
        self.objects.reset(self._qpos)
        self._seen_goal, self._goal_fault = None, None
        if self.goals is not None:  # read with the arms parked out of the view, if asked
            park = getattr(self.goals, "park", None)
            if park is not None:
                self.arms.home(self.to_base_poses(park))
            # the arms hold where they are between the frames (the controllers' watchdog)
            seen, self._goal_fault = self.goals.read(self._goal, keepalive=self._hold)
            seen = np.asarray(seen, np.float32).reshape(NUM_ARMS, 3)
            self._seen_goal = np.where(np.isfinite(seen), seen, self.spec.home_mocap)
        self._target = self.spec.home_mocap.copy()
        self.arms.home(self.to_base_poses(self._target))
        self._t, self._fingers_t = 0, 0
        self._prev_fingers = self._last_fingers = None
        res = self.observe()
        self._q = np.array(self._joints, float)
        return res

    def _hold(self) -> None:
        """Sends the last commanded poses again through the gate (the arms stay put)."""
        if self.arms.last_pose is not None:
            self.arms.servo(self.arms.last_pose)

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
        """Sends the targets [2, 3] (world) and the finger commands through the gate; the
        targets are what the gate let through (the last commanded ones when it refused)."""
        target = self._reachable(np.asarray(target, np.float32).reshape(NUM_ARMS, 3))
        ctrl = np.asarray(ctrl, np.float32).reshape(NUM_ARMS, 2)
        self.arms.grip(ctrl[:, 0])
        if self.arms.servo(self.to_base_poses(target)) is not None:
            self._target = np.asarray(self.arms.last_world, np.float32)
        self._t += 1
        return self.observe()

    @property
    def target(self):
        return self._target.copy()

    @property
    def goal(self):
        return self._goal.copy()

    def close(self):
        try:
            self.arms.close()
        finally:
            for source in (self.objects, self.goals):
                if hasattr(source, "close"):
                    source.close()


def safety_of_spec(spec):
    """The simulator's own limits of ``spec`` (its boxes, one full action step, its arm
    clearance, its finger stroke): what a library user gets without a limits file."""
    cfg = spec.config
    return SafetyLimits(workspace_low=np.asarray(spec.ws_low, np.float32),
                        workspace_high=np.asarray(spec.ws_high, np.float32),
                        max_step=float(np.sqrt(3.0) * spec.max_delta),
                        min_clearance=float(cfg.arm_clearance), deadline_s=float(spec.dt),
                        finger_low=0.0, finger_high=float(cfg.finger_stroke))
