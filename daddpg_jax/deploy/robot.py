"""Real-robot conventions for the dual-UR3 policy (NumPy only).

Units: metres, radians, seconds everywhere. Frames:

- **world** (the simulator's and the policy's frame): x forward from the arms' frame towards
  the table, z up; the left arm (index 0) at y = +0.25 m, the right arm (index 1) at
  y = -0.25 m, both bases 0.40 m above the floor (``daddpg_jax.deploy.ur3.BASE_POS``), each
  turned by ``BASE_YAW`` = pi about z.
- **base** (per arm): the UR controller's base frame, in which ``getl()`` reports and
  ``servoL``/``movel`` take the tool pose ``[x, y, z, rx, ry, rz]`` (position + rotation
  vector). It equals frame 0 of UR's DH table (``daddpg_jax.deploy.ur3``), which is what the
  simulator's arms are built from: ``p_world = R_z(yaw) p_base + base_pos``.

Control: the policy runs every control period ``dt`` = ``timestep * n_substeps`` = 0.04 s
(25 Hz). Arm i's action ``a[4i:4i+4] = [dx, dy, dz, finger]`` in [-1, 1] moves that arm's
Cartesian tool target by ``max_delta * clip(a[:3], -1, 1)`` metres in the **world** frame
(0.05 m per axis at most: up to 1.25 m/s per axis at 25 Hz, so a real robot needs the speed cap
of ``daddpg_jax.deploy.safety``), with the tool pointing straight down; ``finger`` maps to the
opening of each finger ``(a + 1) / 2 * finger_stroke`` metres (jaw gap = twice that), or to
``locked_opening`` when the task locks the fingers (reach, push).

``run_episode`` / ``run_episodes`` are the robot client's control loop (policy service ->
safety layer -> targets), used with ``mjx_envs.numpy_env`` (sim-to-sim) and with UR arms or
their simulated controllers (``daddpg_jax.deploy.arms``, ``daddpg_jax.deploy.ursim``);
``OutageMonitor`` reports outages of the service and ends the run when one lasts too long, and
``summarize_episodes`` leaves the episodes with a missed deadline out of the results. See
docs/DEPLOYMENT.md and docs/RELIABILITY.md.
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np

from daddpg_jax.deploy import ur3
from mjx_envs import observation as obs_lib
from mjx_envs import perturb, pipeline, rules
from mjx_envs.settings import TaskConfig

ARMS = ("l", "r")  # index 0 = left, 1 = right
_DEFAULTS = TaskConfig()
CONTROL_PERIOD_S = _DEFAULTS.timestep * _DEFAULTS.n_substeps
"""Default env dt (``mjx_envs.settings``: timestep 0.01 s x 4 substeps, 0.04 s); the export
stores the run's own value."""
PERTURB_STREAM = perturb.STREAM
"""second seed word of the robot client's perturbation draws"""
SAMPLER = rules.NumpySampler()
TOOL_DOWN_QUAT_WORLD = np.array([0.0, 0.70710678, 0.70710678, 0.0])
"""Fixed tool orientation of the simulator's targets (w, x, y, z), world frame (assets/*.xml)."""


def _arm(arm) -> str:
    if arm in (0, "l", "left"):
        return "l"
    if arm in (1, "r", "right"):
        return "r"
    raise ValueError(f"arm must be 0/'l'/'left' or 1/'r'/'right', got {arm!r}")


def control_period(env: Mapping | None = None) -> float:
    """Seconds between policy queries: ``env['dt']`` of a policy export, else
    ``CONTROL_PERIOD_S``."""
    return float(env["dt"]) if env is not None else CONTROL_PERIOD_S


def rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def world_from_base(arm) -> np.ndarray:
    """4x4 transform world <- base of ``arm`` (same as ``daddpg_jax.deploy.ur3.base_transform``)."""
    return ur3.base_transform(_arm(arm))


def base_from_world(arm) -> np.ndarray:
    T = world_from_base(arm)
    inv = np.eye(4)
    inv[:3, :3] = T[:3, :3].T
    inv[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return inv


def base_to_world(arm, p_base) -> np.ndarray:
    """Points [..., 3] in ``arm``'s base frame -> world frame (m)."""
    T = world_from_base(arm)
    return np.asarray(p_base, float) @ T[:3, :3].T + T[:3, 3]


def world_to_base(arm, p_world) -> np.ndarray:
    """Points [..., 3] in the world frame -> ``arm``'s base frame (m)."""
    T = world_from_base(arm)
    return (np.asarray(p_world, float) - T[:3, 3]) @ T[:3, :3]


def vector_world_to_base(arm, v_world) -> np.ndarray:
    """Free vectors (displacements, velocities) [..., 3]: rotation only."""
    return np.asarray(v_world, float) @ world_from_base(arm)[:3, :3]


def vector_base_to_world(arm, v_base) -> np.ndarray:
    return np.asarray(v_base, float) @ world_from_base(arm)[:3, :3].T


# -- rotations (UR poses carry a rotation vector) -------------------------------------------

def quat_to_matrix(q) -> np.ndarray:
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def matrix_to_rotvec(R) -> np.ndarray:
    """Rotation matrix -> rotation vector (axis * angle, rad), as UR poses use."""
    R = np.asarray(R, float)
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    if angle < 1e-9:
        return np.zeros(3)
    if np.pi - angle < 1e-6:  # axis from the symmetric part
        M = (R + np.eye(3)) / 2.0
        axis = np.sqrt(np.maximum(np.diag(M), 0.0))
        k = int(np.argmax(axis))
        axis = M[k] / np.sqrt(M[k, k])
        return axis / np.linalg.norm(axis) * angle
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    # normalized, not divided by 2 sin(angle): near pi that quotient is off by ~1e-6 and the
    # vector's length exceeded pi (a calibration file the limits then refused)
    return axis / np.linalg.norm(axis) * angle


def rotvec_to_matrix(r) -> np.ndarray:
    r = np.asarray(r, float)
    angle = np.linalg.norm(r)
    if angle < 1e-12:
        return np.eye(3)
    k = r / angle
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def tool_down_rotvec(arm) -> np.ndarray:
    """The simulator's fixed tool orientation as a rotation vector in ``arm``'s base frame."""
    R_world = quat_to_matrix(TOOL_DOWN_QUAT_WORLD)
    R_base = world_from_base(arm)[:3, :3].T @ R_world
    return matrix_to_rotvec(R_base)


# -- actions -> robot commands --------------------------------------------------------------

def split_action(action) -> np.ndarray:
    """Joint action [8] -> per arm [2, 4], each clipped to [-1, 1]."""
    a = np.asarray(action, float)
    if a.shape != (8,):
        raise ValueError(f"action must have shape [8], got {list(a.shape)}")
    if not np.all(np.isfinite(a)):
        raise ValueError("action contains NaN or infinite values")
    return np.clip(a.reshape(2, 4), -1.0, 1.0)


def cartesian_deltas_world(action, max_delta: float) -> np.ndarray:
    """Per-arm target displacement this control period, world frame [2, 3] (m)."""
    return max_delta * split_action(action)[:, :3]


def finger_openings(action, finger_stroke: float = _DEFAULTS.finger_stroke,
                    lock_fingers: bool = False, locked_opening: float = 0.0) -> np.ndarray:
    """Per-arm opening of each finger [2] (m); the jaw gap is twice this."""
    if lock_fingers:
        return np.full(2, float(locked_opening))
    return (split_action(action)[:, 3] + 1.0) * 0.5 * float(finger_stroke)


def servol_targets(action, tcp_pose_base, max_delta: float, tcp_target_world=None):
    """``servoL``-style target poses for one control period, each in its arm's base frame.

    action: [8]; tcp_pose_base: [2, 6] each arm's current ``getl()`` pose ([x, y, z, rx, ry, rz]
    in its base frame); tcp_target_world: [2, 3] the previous targets (world), which the
    simulator integrates (default: the measured positions). Returns ([2, 6] poses in base
    frames with the tool pointing down, [2, 3] new targets in world).
    """
    pose = np.asarray(tcp_pose_base, float).reshape(2, 6)
    if tcp_target_world is None:
        prev = np.stack([base_to_world(i, pose[i, :3]) for i in range(2)])
    else:
        prev = np.asarray(tcp_target_world, float).reshape(2, 3)
    new_world = prev + cartesian_deltas_world(action, max_delta)
    out = np.zeros((2, 6))
    for i in range(2):
        out[i, :3] = world_to_base(i, new_world[i])
        out[i, 3:] = tool_down_rotvec(i)
    return out, new_world


# -- the client's control loop (sim-to-sim with mjx_envs.numpy_env, or a real robot driver) --

MAX_MISSED = 50
"""Default limit of an outage of the policy service: consecutive missed deadlines."""
MAX_OUTAGE_S = 2.0
"""Default limit of an outage of the policy service: seconds (50 control periods at 25 Hz)."""


class ServiceOutage(Exception):
    """An outage of the policy service reached the client's limits (``OutageMonitor``).

    ``missed``: consecutive missed deadlines; ``outage_s``: seconds since the first failed
    request was sent; ``last_error``: why the last answer was unusable; ``episode``: the
    summary of the episode it interrupted (set by ``run_episode``).
    """

    def __init__(self, message: str, missed: int, outage_s: float, last_error: str):
        super().__init__(message)
        self.missed, self.outage_s, self.last_error = missed, outage_s, last_error
        self.episode: dict | None = None


class Interrupted(Exception):
    """The run was asked to stop (SIGINT, SIGTERM); ``signal``: the signal's number."""

    def __init__(self, message: str, signal: int):
        super().__init__(message)
        self.signal = signal
        self.episode: dict | None = None


class ReadingsLost(Exception):
    """The arms' readings stayed unusable (frozen, slower than the deadline) longer than the
    limits allow; the run ends (exit 4). ``episode``: the interrupted episode's summary."""

    def __init__(self, message: str):
        super().__init__(message)
        self.episode: dict | None = None


class OutageMonitor:
    """Follows the policy service's missed deadlines (control periods without a usable answer
    in time, in which the robot held) and gives up on a lasting outage.

    Reports one line through ``report`` when an outage starts (the first missed deadline after
    an answer) and one when the service answers again, never one per control period. Raises
    ``ServiceOutage`` once an outage reaches ``max_missed`` consecutive missed deadlines or
    lasts ``max_outage_s`` seconds from the start of its first failed request, whichever comes
    first; a limit of None or <= 0 is off. ``report``: callable taking one line (default:
    silent); ``clock``: monotonic seconds, also used by ``run_episode`` to time requests.
    """

    def __init__(self, max_missed: int | None = MAX_MISSED,
                 max_outage_s: float | None = MAX_OUTAGE_S, report=None, clock=time.perf_counter):
        self.max_missed = int(max_missed) if max_missed and max_missed > 0 else None
        self.max_outage_s = float(max_outage_s) if max_outage_s and max_outage_s > 0 else None
        self.report, self.clock = report, clock
        self.missed = 0  # consecutive missed deadlines of the current outage
        self.since: float | None = None  # when the current outage's first failed request left
        self.total_missed = 0
        self.outages = 0
        self.longest_s = 0.0

    def _say(self, line: str):
        if self.report is not None:
            self.report(line)

    def limits_text(self) -> str:
        parts = [f"{self.max_missed} missed deadlines" if self.max_missed else "",
                 f"{self.max_outage_s:g} s" if self.max_outage_s else ""]
        return " or ".join(p for p in parts if p) or "none"

    def missed_deadline(self, why: str, sent_at: float | None = None, where: str = "") -> None:
        """A control period without a usable answer; ``sent_at``: when its request left."""
        now = self.clock()
        if self.missed == 0:
            self.since = now if sent_at is None else float(sent_at)
            self.outages += 1
            at = f" at {where}" if where else ""
            self._say(f"policy service outage{at}: {why}; holding the arms (limits: "
                      f"{self.limits_text()})")
        self.missed += 1
        self.total_missed += 1
        outage_s = now - self.since
        self.longest_s = max(self.longest_s, outage_s)
        if ((self.max_missed is not None and self.missed >= self.max_missed)
                or (self.max_outage_s is not None and outage_s >= self.max_outage_s)):
            raise ServiceOutage(
                f"policy service outage: {self.missed} consecutive missed deadlines in "
                f"{outage_s:.2f} s (limits: {self.limits_text()}); last: {why}",
                self.missed, outage_s, why)

    def answered(self) -> None:
        """A usable answer in time: ends the current outage, if any."""
        if self.missed:
            outage_s = self.clock() - self.since
            self.longest_s = max(self.longest_s, outage_s)
            self._say(f"policy service answering again after {self.missed} missed deadline(s) "
                      f"in {outage_s:.2f} s")
            self.missed, self.since = 0, None


OVERRUN_TOLERANCE_S = 0.002
"""A control period that starts more than this late (its previous one overran) counts as an
overrun; the schedule then restarts from now instead of catching up."""


class Pacer:
    """Runs the control loop once per ``period`` seconds on a monotonic clock.

    ``wait()`` sleeps until the next period starts and returns its start time. When the work of
    a period took longer than the period (the next one would start more than
    ``OVERRUN_TOLERANCE_S`` late) it counts an overrun and restarts the schedule from now: the
    loop never runs periods back to back to catch up. ``restart()`` between episodes.
    """

    def __init__(self, period: float, clock=time.perf_counter, sleep=time.sleep):
        if not period > 0:
            raise ValueError(f"period must be > 0 s, got {period!r}")
        self.period, self.clock, self.sleep = float(period), clock, sleep
        self.next: float | None = None
        self.periods = 0
        self.overruns = 0
        self.longest_late_s = 0.0

    def restart(self):
        self.next = None

    def wait(self) -> float:
        now = self.clock()
        if self.next is None:
            self.next = now
        elif now - self.next > OVERRUN_TOLERANCE_S:
            self.overruns += 1
            self.longest_late_s = max(self.longest_late_s, now - self.next)
            self.next = now
        elif now < self.next:
            self.sleep(self.next - now)
        start = self.next
        self.next += self.period
        self.periods += 1
        return start


def _episode_summary(res, stops, errors, clear_min, rtts, complete=True, stale=0,
                     step_ms=None, perception=0) -> dict:
    step_ms = step_ms or [0.0]
    return dict(success=bool(res.success), final_distance=res.goal_distance.tolist(),
                stops=stops, stale=stale, perception=perception, errors=errors[:5],
                min_arm_clearance=float(clear_min),
                rtt_ms_p50=float(np.percentile(rtts, 50)), rtt_ms_max=float(np.max(rtts)),
                step_ms_p99=float(np.percentile(step_ms, 99)), step_ms_max=float(max(step_ms)),
                step_ms=[round(float(x), 3) for x in step_ms], complete=complete)


def _log_step(log, t, age, seen, goal, action, info, decision, ctrl, missed_why):
    log.append(dict(t=round(float(t), 6), obs_age_ms=round(age * 1e3, 3),
                    observation=np.asarray(seen, float).round(6).tolist(),
                    desired_goal=np.asarray(goal, float).round(6).tolist(),
                    action=None if action is None else np.asarray(action, float).tolist(),
                    target=np.asarray(decision.target, float).tolist(),
                    finger_ctrl=np.asarray(ctrl, float).tolist(), stopped=bool(decision.stopped),
                    reasons=list(decision.reasons), missed=missed_why,
                    rtt_ms=round(float(info.get("rtt_ms", 0.0)), 3),
                    server_ms=info.get("server_ms")))


def _judge(safety, answer, info, rtt, deadline, age, max_age):
    """(validated action or None, why the period is a missed deadline or None, the hold's
    reason: stop / late / stale)."""
    action = None if answer is None else safety.validate_action(answer)
    if action is None:
        return None, info.get("error") or "malformed answer", "stop"
    if rtt > deadline:
        return action, f"late answer ({rtt * 1e3:.1f} ms > {deadline * 1e3:.1f} ms)", "late"
    if max_age is not None and age > max_age:
        return action, (f"stale observation ({age * 1e3:.1f} ms old > {max_age * 1e3:.1f} "
                        f"ms)"), "stale"
    return action, None, None


def _reading_fault(res, deadline: float, max_age: float | None) -> str | None:
    """Why the arms' reading in ``res`` cannot be used (hold), or None: the read took longer
    than the deadline, or the controllers' clocks have not advanced for longer than the
    observation age (`daddpg_jax.deploy.arms.ArmsEnv.observe` sets ``read_s`` and
    ``frozen_s``; other envs have neither)."""
    read_s = getattr(res, "read_s", 0.0)
    if read_s > deadline:
        return f"slow arm reading ({read_s * 1e3:.1f} ms > {deadline * 1e3:.1f} ms)"
    frozen_s = getattr(res, "frozen_s", 0.0)
    if frozen_s > (max_age if max_age is not None else deadline):
        return f"frozen arm readings (the controller clock stopped {frozen_s * 1e3:.0f} ms ago)"
    return None


class _ReadingWatch:
    """How long the arms' readings have been unusable (`_reading_fault`); `ReadingsLost` once
    longer than ``max_gap`` s (None: never)."""

    def __init__(self, deadline: float, max_age: float | None, max_gap: float | None):
        self.deadline, self.max_age, self.max_gap = deadline, max_age, max_gap
        self.since: float | None = None

    def check(self, res, now: float) -> str | None:
        fault = _reading_fault(res, self.deadline, self.max_age)
        if fault is None:
            self.since = None
            return None
        self.since = now if self.since is None else self.since
        if self.max_gap is not None and now - self.since > self.max_gap:
            raise ReadingsLost(f"the arms' readings were unusable for {now - self.since:.2f} s "
                               f"(limit {self.max_gap:g} s): {fault}")
        return fault


def _interrupt(interrupted) -> None:
    """Raises `Interrupted` when ``interrupted()`` (if any) asks the run to stop."""
    stop = interrupted() if interrupted is not None else None
    if stop is not None:
        raise Interrupted(stop[1], stop[0])


def _report(monitor: OutageMonitor | None, why: str | None, sent_at: float, where: str):
    """Tells the monitor (if any) how the period went: answered, or a missed deadline."""
    if monitor is None:
        return
    if why is None:
        monitor.answered()
    else:
        monitor.missed_deadline(why, sent_at=sent_at, where=where)


def _limit_fingers(safety, ctrl, decision):
    """The finger command within the limits' range (counted as ``finger`` when clipped)."""
    limited = safety.finger_opening(ctrl)
    if np.any(limited != ctrl):
        decision.reasons.append("finger")
        safety.counts["finger"] = safety.counts.get("finger", 0) + 1
    return limited


def _fresh(env, res, seen, step, pacer, pipe, carry):
    """(result, what the policy sees) at a period's start: a paced driver with ``observe()``
    (real arms, `daddpg_jax.deploy.arms.ArmsEnv`) is read again, so that the policy sees the
    arms' current state rather than the one read right after the last command (not under a
    perturbation, whose observations are the pipeline's own)."""
    if step and pacer is not None and not pipe.perturbs and hasattr(env, "observe"):
        res = env.observe()
        return res, pipe.observe(carry, res.observation)[0]
    return res, seen


def run_episode(env, client, safety, rng: np.random.Generator | None = None, goal=None,
                qpos=None, deadline_s: float | None = None, grip_slice=(0, 3),
                monitor: OutageMonitor | None = None, episode: int = 0,
                perturbation=None, perturb_rng: np.random.Generator | None = None,
                action_history: int | None = None, pacer: Pacer | None = None,
                max_observation_age: float | None = None, log: dict | None = None,
                max_reading_gap: float | None = None, interrupted=None) -> dict:
    """One episode: every control period, query the policy service with the observation built
    by ``mjx_envs.observation``, pass the answer through the safety layer, move the targets.

    env: ``NumpyDualArmEnv`` or ``deploy.arms.ArmsEnv`` (`_fresh`); goal [2, 3], qpos [nq]: the
    start (None: from ``rng``); client: ``PolicyClient``; safety: ``SafetyFilter``. A missing,
    malformed or late answer (later than ``deadline_s``, default the limits' deadline), or one
    to an observation older than ``max_observation_age`` s (``stale``; capture time: the
    result's ``captured_at`` if the env sets one, else when the loop read it) is a missed
    deadline: both arms hold (``stops``).
    monitor: an ``OutageMonitor`` told of each period after the hold; its ``ServiceOutage``
    ends the episode, with the partial summary in ``.episode``. episode: the index, for reports.
    pacer: a ``Pacer`` runs one step per control period (None: as fast as the env steps).
    log: a dict that receives the episode's log (goal, initial state, and per step the
    observation, its age, the answer, the safety decision, the targets sent and the times);
    ``replay_episode`` replays it in the simulator.
    A period whose arm reading is unusable (`_reading_fault`: slower than the deadline, or the
    controllers' clocks frozen for longer than ``max_observation_age``) holds both arms without
    asking the service (``stale``); readings unusable for longer than ``max_reading_gap`` s
    raise `ReadingsLost`. An observation's ``perception_fault`` (`arms.ArmsEnv`: a camera frame
    too old, a tag not seen, the object lost) holds both arms too, without asking the service
    and without a missed deadline (``perception``; the episode counts as a failure).
    interrupted: callable returning None or (signal, reason), asked at every period's start;
    a request raises `Interrupted` (the episode's summary in ``.episode``).
    perturbation: a ``mjx_envs.perturb.Perturbation`` (the trainer's observation noise,
    dropout, bias, period and action latency, drawn from ``perturb_rng``) applied to what the
    policy sees and sends; the safety layer sees the true state. action_history: the policy's k
    (``mjx_envs.observation.with_action_history``; None = ``env.config``'s, 0 without one): the
    actions the service answered, before any latency; a held period counts as zero.
    Observations: the trainer's pipeline (`mjx_envs.pipeline`, over NumPy). Returns the summary.
    """
    if action_history is None:
        action_history = getattr(getattr(env, "config", None), "action_history", 0)
    pipe = pipeline.Pipeline(pipeline.stages(np, SAMPLER, perturbation, action_history))
    clock = time.perf_counter if monitor is None else monitor.clock
    deadline = safety.limits.deadline_s if deadline_s is None else float(deadline_s)
    res = env.reset(rng=rng, goal=goal, **({} if qpos is None else {"qpos": qpos}))
    log = {} if log is None else log
    log.update(episode=episode, goal=np.asarray(res.desired_goal, float).tolist(),
               qpos=np.asarray(getattr(env, "_qpos", []), float).tolist(), steps=[])
    perturb_rng = np.random.default_rng() if perturb_rng is None else perturb_rng
    seen, carry = pipe.start(perturb_rng, res.observation)
    ctrl = env.finger_ctrl(np.zeros(2, np.float32))
    stops, stale, held, rtts, errors, step_ms = 0, 0, 0, [], [], []
    clear_min = res.arm_clearance
    watch = _ReadingWatch(deadline, max_observation_age, max_reading_gap)
    if pacer is not None:
        pacer.restart()
    try:
        for step in range(env.episode_length):
            tick = pacer.wait() if pacer is not None else clock()
            _interrupt(interrupted)
            res, seen = _fresh(env, res, seen, step, pacer, pipe, carry)
            captured = getattr(res, "captured_at", None)
            captured = clock() if captured is None else float(captured)
            t0 = clock()
            fault, kind = _unusable(watch, res, t0)
            answer, info = ((None, {"error": fault}) if fault is not None
                            else client.act(seen, res.desired_goal))
            t_answer = clock()
            rtt, age = t_answer - t0, t_answer - captured
            rtts.append(rtt * 1e3)
            action, why, reason = _judge(safety, answer, info, rtt, deadline, age,
                                         max_observation_age)
            reason = kind or reason
            if why is not None:
                stale, held = stale + (reason == "stale"), held + (reason == "perception")
                errors.append(why)
                decision = safety.hold(env.target, reason=reason)
                stops += reason != "perception"
                carry = pipe.hold(carry)
            else:
                action, carry = pipe.act(carry, action)
                proposed, ctrl = env.command_targets(action)
                grip = res.observation[:, grip_slice[0]:grip_slice[1]]
                decision = safety.filter(env.target, proposed, res.link_points, tool=grip)
                ctrl = _limit_fingers(safety, ctrl, decision)
            _log_step(log["steps"], tick, age, seen[:, :obs_lib.OBS_SIZE], res.desired_goal,
                      action, info, decision, ctrl, why)
            res = env.step_targets(decision.target, ctrl)
            step_ms.append((clock() - tick) * 1e3)
            log["steps"][-1]["step_ms"] = round(step_ms[-1], 3)
            seen, carry = pipe.observe(carry, res.observation)
            clear_min = min(clear_min, res.arm_clearance)
            if kind != "perception":  # a perception hold is no outage of the service
                _report(monitor, why, t0, f"episode {episode + 1}, step {step + 1}")
    except (ServiceOutage, Interrupted, ReadingsLost) as e:
        e.episode = log["summary"] = _episode_summary(
            res, stops, errors, clear_min, rtts or [0.0], complete=False, stale=stale,
            step_ms=step_ms, perception=held)
        raise
    log["summary"] = _episode_summary(res, stops, errors, clear_min, rtts, stale=stale,
                                      step_ms=step_ms, perception=held)
    return log["summary"]


def _unusable(watch, res, now):
    """(why the period holds without asking the service, the hold's reason) or (None, None):
    an unusable arm reading (``stale``, `_ReadingWatch`), else the observation's
    ``perception_fault`` (``perception``)."""
    fault = watch.check(res, now)
    if fault is not None:
        return fault, "stale"
    sight = getattr(res, "perception_fault", None)
    return (sight, "perception") if sight else (None, None)


def replay_episode(env, log: dict):
    """Replays an episode's log (``run_episode(..., log=...)``) in the simulator ``env``: the
    same goal and initial state, then the logged targets and finger commands step by step.
    Returns the final ``StepResult`` (compare its ``goal_distance`` with the log's
    ``summary['final_distance']``)."""
    qpos = log.get("qpos") or None
    res = env.reset(goal=np.asarray(log["goal"], np.float32),
                    qpos=None if qpos is None else np.asarray(qpos, np.float32))
    for st in log["steps"]:
        res = env.step_targets(np.asarray(st["target"], np.float32),
                               np.asarray(st["finger_ctrl"], np.float32))
    return res


def _pooled(eps, key, fn):
    """``fn`` over the lists ``key`` of every episode pooled (None when there are none)."""
    vals = [x for e in eps for x in e.get(key, ())]
    return round(float(fn(vals)), 3) if vals else None


def summarize_episodes(eps: list[dict], safety_counts: Mapping | None = None,
                       monitor: OutageMonitor | None = None, aborted: dict | None = None) -> dict:
    """The run's summary from the episodes' summaries (``run_episode``).

    An episode with a missed deadline (``stops`` > 0, including one cut short by an abort) is
    excluded from the results: ``episodes`` counts the others, over which ``success_rate`` and
    ``mean_final_distance`` are computed (None when there are none); ``episodes_run`` and
    ``excluded_episodes`` say how many ran and how many were left out. ``stops``, the smallest
    arm gap and the round-trip times cover every episode run. An episode held for perception
    (``perception`` > 0: the camera's frame too old, a tag not seen, the object lost) is
    counted, as a failure (``perception_held_episodes``; ``perception``: the periods held).
    ``episode_success`` lists every episode run in order: its success, None when excluded.
    """
    counted = [e for e in eps if e["stops"] == 0]

    def stat(fn, key, among):
        vals = [e[key] for e in among if key in e]
        return float(fn(vals)) if vals else None

    n_ok = sum(e["success"] and not e.get("perception", 0) for e in counted)
    return dict(episodes=len(counted), episodes_run=len(eps),
                episode_success=[bool(e["success"] and not e.get("perception", 0))
                                 if e["stops"] == 0 else None for e in eps],
                excluded_episodes=len(eps) - len(counted),
                success_rate=(n_ok / len(counted) if counted else None),
                success_ci95=list(wilson_interval(n_ok, len(counted))) if counted else None,
                mean_final_distance=stat(np.mean, "final_distance", counted),
                stops=int(sum(e["stops"] for e in eps)),
                stale=int(sum(e.get("stale", 0) for e in eps)),
                perception=int(sum(e.get("perception", 0) for e in eps)),
                perception_held_episodes=sum(bool(e.get("perception", 0)) for e in counted),
                step_ms_p99=_pooled(eps, "step_ms", lambda x: np.percentile(x, 99)),
                step_ms_max=_pooled(eps, "step_ms", np.max),
                outages=0 if monitor is None else monitor.outages,
                longest_outage_s=None if monitor is None else round(monitor.longest_s, 3),
                safety_counts=dict(safety_counts or {}),
                min_arm_clearance=stat(min, "min_arm_clearance", eps),
                rtt_ms_p50=stat(np.median, "rtt_ms_p50", eps),
                rtt_ms_max=stat(max, "rtt_ms_max", eps),
                first_errors=[err for e in eps for err in e["errors"]][:5],
                aborted=aborted)


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95% Wilson score interval of a success rate (n > 0)."""
    p = successes / n
    den = 1.0 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return round(float(max(0.0, mid - half)), 4), round(float(min(1.0, mid + half)), 4)


def format_summary(out: Mapping) -> str:
    """A short human-readable summary of a run (``run_episodes``' result)."""
    lines = []
    if out.get("success_rate") is None:
        lines.append(f"success: no episode counted ({out['episodes_run']} run)")
    else:
        lo, hi = out["success_ci95"]
        lines.append(f"success: {out['success_rate']:.3f} (95% CI {lo:.3f}-{hi:.3f}) over "
                     f"{out['episodes']} episodes; {out['excluded_episodes']} excluded for a "
                     f"missed deadline")
    lines.append(f"deadlines missed: {out['stops']} ({out.get('stale', 0)} stale "
                 f"observations) in {out['outages']} outage(s)")
    if out.get("perception"):
        lines.append(f"perception holds: {out['perception']} control period(s) in "
                     f"{out['perception_held_episodes']} episode(s), counted as failures")
    counts = out.get("safety_counts") or {}
    rules = ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) or "none"
    lines.append(f"safety interventions (control periods): {rules}")
    if out.get("paced"):
        lines.append(f"paced at {out['control_period_ms']:g} ms: {out['overruns']} overrun(s); "
                     f"step time p99 {out['step_ms_p99']:.1f} ms, max {out['step_ms_max']:.1f} ms")
    else:
        lines.append("unpaced (--fast): as fast as the simulator steps")
    if out.get("aborted"):
        lines.append(f"aborted: {out['aborted']['reason']}")
    return "\n".join(lines)


def run_episodes(env, client, safety, episodes: int, seed: int = 0,
                 deadline_s: float | None = None, monitor: OutageMonitor | None = None,
                 perturbation=None, pacer: Pacer | None = None,
                 max_observation_age: float | None = None, on_log=None,
                 max_reading_gap: float | None = None, interrupted=None,
                 ends_run: tuple = (), starts=None) -> dict:
    """``episodes`` episodes with goals from ``np.random.default_rng(seed)``, or the first
    ``episodes`` of ``starts`` (`mjx_envs.episode_starts.EpisodeStarts`: goals and initial
    states, e.g. those of ``daddpg-evaluate --save-starts``); the summary of
    ``summarize_episodes`` (success rate over the episodes without a missed deadline, ...).
    perturbation: see ``run_episode``; its draws come from ``np.random.default_rng([seed,
    PERTURB_STREAM])``, so the goals are those of the unperturbed run.

    pacer, max_observation_age: see ``run_episode``; on_log: called with each episode's log
    (``run_episode``'s ``log``) when the episode ends, aborted ones included.
    monitor: ``OutageMonitor`` (default: ``MAX_MISSED`` / ``MAX_OUTAGE_S``, silent). When it
    gives up, the run stops there and ``aborted`` holds ``reason``, ``episode`` (1-based),
    ``missed``, ``outage_s`` and ``last_error``; otherwise ``aborted`` is None.
    max_reading_gap, interrupted: see ``run_episode``; `ReadingsLost`, `Interrupted` and the
    exception classes in ``ends_run`` (the arms' errors) also end the run there, with
    ``aborted`` holding ``reason``, ``episode`` and ``kind`` (``readings``, ``signal`` with
    ``signal``, or the exception's class name).
    """
    if starts is not None and int(episodes) > len(starts):
        raise ValueError(f"{episodes} episodes asked, the starts hold {len(starts)}")
    rng = np.random.default_rng(seed)
    perturb_rng = np.random.default_rng([seed, PERTURB_STREAM])
    monitor = OutageMonitor() if monitor is None else monitor
    eps, aborted = [], None
    for k in range(int(episodes)):
        log = {} if on_log is not None else None
        try:
            start = {} if starts is None else dict(goal=starts.goal[k], qpos=starts.qpos[k])
            eps.append(run_episode(env, client, safety, rng=rng, deadline_s=deadline_s, **start,
                                   monitor=monitor, episode=k, perturbation=perturbation,
                                   perturb_rng=perturb_rng, pacer=pacer,
                                   max_observation_age=max_observation_age, log=log,
                                   max_reading_gap=max_reading_gap, interrupted=interrupted))
        except ServiceOutage as e:
            if e.episode is not None:
                eps.append(e.episode)
            aborted = dict(reason=str(e), episode=k + 1, missed=e.missed,
                           outage_s=round(e.outage_s, 3), last_error=e.last_error,
                           kind="outage")
            break
        except (Interrupted, ReadingsLost, *ends_run) as e:
            if getattr(e, "episode", None) is not None:
                eps.append(e.episode)
            kind = ("signal" if isinstance(e, Interrupted) else
                    "readings" if isinstance(e, ReadingsLost) else type(e).__name__)
            aborted = dict(reason=" ".join(str(e).split())[:300], episode=k + 1, kind=kind)
            if isinstance(e, Interrupted):
                aborted["signal"] = e.signal
            break
        finally:
            if on_log is not None and log:
                on_log(log)
    out = summarize_episodes(eps, safety.counts, monitor, aborted)
    out.update(paced=pacer is not None,
               overruns=None if pacer is None else pacer.overruns,
               control_period_ms=None if pacer is None else pacer.period * 1e3)
    return out
