"""The one gate before the arms (daddpg_jax/deploy/gate.py) and the failures it closes, one test
per class: targets outside the limits (a valid box that does not hold the start pose, a margin
that shrinks the box past it), the robot's own task model against a lying service, readings
that stop or slow down, driver calls that fail, return False, hang or overrun, the controllers'
watchdog, malformed answers mid-episode, SIGINT/SIGTERM, and numeric flags and paths. Every
simulated command is also checked by the independent recorder (tests/arm_recorder.py).

In-process, no JAX: the hand-built reach controller (tests/reach_controller.py) served from a
thread or called directly. Cost: ~0.05-2 s per test, ~12 s the module."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import socket
import threading
import time

import numpy as np
import pytest

from daddpg_jax.cli import robot_client
from daddpg_jax.deploy import NumpyPolicy, robot
from daddpg_jax.deploy.arms import ArmsError, CallGuard, bounded, probe_rtde, safety_of_spec
from daddpg_jax.deploy.gate import GatedArms, GateRefusal, step_cap
from daddpg_jax.deploy.limits import SHIPPED, RobotLimits
from daddpg_jax.deploy.policy import task_settings
from daddpg_jax.deploy.robot_session import ENDS_RUN, outcome
from daddpg_jax.deploy.safety import SafetyFilter
from daddpg_jax.deploy.server import PolicyServer
from daddpg_jax.deploy.ursim import SimRTDEControl, sim_env, sim_ur_env
from mjx_envs import limit_rules
from mjx_envs.numpy_env import NumpyDualArmEnv
from tests.reach_controller import write_reach_controller

pytestmark = pytest.mark.usefixtures("arm_recorder")  # every command checked

SIM = os.path.join(SHIPPED, "sim.toml")
CELL = os.path.join(SHIPPED, "ur3_cell.toml")


@pytest.fixture(scope="module")
def policy(tmp_path_factory):
    return NumpyPolicy.load(write_reach_controller(tmp_path_factory.mktemp("p") / "rc.npz"))


def _spec(policy):
    return NumpyDualArmEnv(task_settings(policy.task, policy.env), task=policy.task)


class _Client:
    """The policy in-process; ``answers``: step (1-based) -> what the service answers."""

    def __init__(self, policy, answers=None):
        self.policy, self.answers, self.n = policy, answers or {}, 0

    def act(self, obs, goal):
        self.n += 1
        if self.n in self.answers:
            return self.answers[self.n], {}
        return self.policy.act(obs, goal).tolist(), {}


def _limits_file(tmp_path, **change) -> str:
    import tomllib

    with open(SIM, "rb") as f:
        d = tomllib.load(f)
    for arm in ("left", "right"):
        d[arm].update(change.pop(arm, {}))
    d.update(change)
    path = tmp_path / "limits.json"
    path.write_text(json.dumps({"deadline": 2.0, "max_observation_age": 2.0, **d}))
    return str(path)


def _serve_and_run(policy, capsys, *args):
    with PolicyServer(policy, port=0) as srv:
        code = robot_client.main(["--server", srv.url, "--fast", "--episodes", "1", *args])
    return code, capsys.readouterr()


# -- the gate itself ---------------------------------------------------------------------------

def test_the_gate_refuses_each_rule_and_holds(policy):
    """~0.3 s: a pose outside the box, a step over the cap, a turned tool, a move into the
    other arm, an opening outside the finger range: each is not sent (the last pose is sent
    again, the finger command dropped) and counted by rule."""
    env = sim_env(_spec(policy), _spec(policy))
    env.reset(np.random.default_rng(0))
    gate = env.arms
    assert isinstance(gate, GatedArms)
    start = gate.last_pose.copy()
    sent = []
    inner = gate.arms.servo
    gate.arms.servo = lambda p: (sent.append(np.array(p)), inner(p))
    far = env.to_base_poses(env.target + [[0.0, 0.0, 0.5], [0.0, 0.0, 0.0]])
    step = env.to_base_poses(env.target + [[0.09, 0.0, 0.0], [0.0, 0.0, 0.0]])
    turned = start.copy()
    turned[0, 3:] += 0.2
    for poses, rule in ((far, "box"), (step, "step"), (turned, "orientation")):
        assert gate.check_servo(poses).startswith(rule)
        gate.servo(poses)
        np.testing.assert_array_equal(sent[-1], start)  # held
    # towards each other until the clearance rule refuses
    toward = env.target.copy()
    for _ in range(40):
        toward += [[0.0, -0.02, 0.0], [0.0, 0.02, 0.0]]
        env.step_targets(toward, np.zeros((2, 2), np.float32))
    assert gate.refusals.get("clearance", 0) > 0
    gate.grip([0.5, 0.0])
    assert gate.refusals["fingers"] == 1
    assert {"box", "step", "orientation", "clearance", "fingers"} <= set(gate.refusals)


@pytest.mark.parametrize("max_speed", [0.05, 0.02])
def test_the_filter_never_leaves_the_gate_a_target_to_refuse(policy, max_speed):
    """~1 s each: the rules before the gate (clamp, then the speed cap, then the clearance rule
    with capped fallbacks) under a full-speed policy with a tiny box and a low cap (2 mm and
    0.8 mm per period): the gate never has to refuse."""
    spec = _spec(policy)
    lim = RobotLimits.load(SIM)
    lim = dataclasses.replace(lim, workspace_low=((0.2, 0.0, 0.50), (0.2, -0.22, 0.50)),
                              workspace_high=((0.3, 0.22, 0.60), (0.3, 0.0, 0.60)),
                              max_speed=max_speed)
    safety = lim.safety_limits()
    env = sim_env(spec, _spec(policy), safety=safety)
    out = robot.run_episodes(env, _Client(policy, {k: [1.0, -1, 1, 1, -1, 1, -1, 0]
                                                   for k in range(1, 60)}),
                             SafetyFilter(safety), 1, deadline_s=10.0, ends_run=ENDS_RUN)
    assert out["aborted"] is None and env.arms.refusals == {}
    assert out["safety_counts"].get("workspace", 0) > 0 and out["safety_counts"]["speed"] > 0


def test_capped_float32_moves_pass_the_step_rule_and_a_micrometre_more_does_not():
    """~0.5 s: the speed cap's float32 targets (`mjx_envs.limit_rules.cap_speed`, as the client
    and the trainer cap) at 0.8 mm, 2.5 mm (ur3_cell.toml at --speed-scale 0.25) and 10 mm per
    period, from 20,000 random targets within 0.9 m: every capped step, measured in float64 as
    the gate measures it, passes `step_cap`; before the coordinates' rounding was allowed for,
    a third of the 0.8 mm ones did not. The allowance stays under a micrometre."""
    rng = np.random.default_rng(0)
    cur = rng.uniform(-0.9, 0.9, (20_000, 2, 3)).astype(np.float32)
    prop = cur + rng.normal(size=cur.shape).astype(np.float32) * np.float32(0.02)
    for max_step in (0.0008, 0.0025, 0.01):
        rules = limit_rules.Limits(low=None, high=None, max_step=np.float32(max_step),
                                   min_clearance=0.0, finger_low=0.0, finger_high=0.04)
        t, capped = limit_rules.cap_speed(np, rules, cur, prop)
        assert bool(capped)
        step = np.linalg.norm(t.astype(np.float64) - cur.astype(np.float64), axis=-1)
        assert step.max() <= step_cap(max_step)
        old = max_step * (1.0 + 1e-5) + 1e-9     # the allowance before: length only
        assert (step > old).any() or max_step > 0.005
        assert max_step < step_cap(max_step) < max_step + 1e-6


# -- targets outside the limits: nothing moves -------------------------------------------------

def test_a_box_that_does_not_hold_the_start_pose_moves_nothing(policy, tmp_path, capsys,
                                                               arm_recorder):
    """~1 s: a valid limits file whose box tops at z 0.50 (the start pose is at 0.55): before,
    a moveL 5 cm outside the box and a 5 cm servoL; now one line, exit 2, nothing sent."""
    lim = _limits_file(tmp_path, left={"workspace_high": [0.40, 0.36, 0.50]},
                       right={"workspace_high": [0.40, 0.14, 0.50]})
    for arms in ("sim", "ur-sim"):
        code, cap = _serve_and_run(policy, capsys, "--limits", lim, "--arms", arms)
        assert code == 2, cap.err
        assert "start pose" in cap.err and "outside its box" in cap.err
        assert "Traceback" not in cap.err
    assert arm_recorder.commands == 0


def test_a_margin_past_the_start_pose_moves_nothing(policy, capsys, arm_recorder):
    """~1 s: --workspace-margin 0.115 on ur3_cell.toml (before: 1.5 cm outside the box): one
    line, exit 2, nothing sent."""
    code, cap = _serve_and_run(policy, capsys, "--limits", CELL, "--workspace-margin", "0.115",
                               "--deadline-ms", "30")
    assert code == 2 and "outside its box" in cap.err.splitlines()[-1]
    assert arm_recorder.commands == 0


def test_the_start_move_runs_at_the_cap_s_speed(policy, tmp_path, capsys, arm_recorder):
    """~2 s: with a 0.02 m/s cap the start moveL goes at 0.02 m/s (the recorder checks every
    moveL's speed and every servo's step)."""
    lim = _limits_file(tmp_path, max_speed=0.02)
    code, cap = _serve_and_run(policy, capsys, "--limits", lim, "--arms", "ur-sim")
    assert code == 0, cap.err
    assert arm_recorder.commands > 0


# -- the robot's own model -------------------------------------------------------------------

class _Lying:
    def __init__(self, policy, env=None, info=None):
        self._p, self._env, self._info = policy, env or {}, info or {}

    def __getattr__(self, name):
        return getattr(self._p, name)

    def info(self):
        out = self._p.info()
        out["env"] = {**out["env"], **self._env}
        out.update(self._info)
        return out


@pytest.mark.parametrize("env,info,words", [
    ({"scene": "/etc/passwd"}, {}, "scene"),
    ({"scene": "scene_push.xml"}, {}, "scene"),
    ({"episode_length": 1_000_000_000}, {}, "episode_length"),
    ({"timestep": 0.005, "n_substeps": 8}, {}, "timestep"),
    ({"max_delta": 0.5}, {}, "max_delta"),
    ({"finger_stroke": 0.08}, {}, "finger_stroke"),
    ({"action_history": 2}, {}, "action_history"),
    ({}, {"num_agents": 8}, "num_agents"),
    ({}, {"obs_size": 99}, "obs_size"),
])
def test_the_service_is_checked_against_the_robot_s_own_task(policy, tmp_path, capsys, env,
                                                             info, words, arm_recorder):
    """~0.3 s each: /info may only be compared with the robot's own task: a scene path from
    the network, an episode length of 1e9, another timestep, action scale, finger stroke,
    observation layout or agent count is one line and exit 2; nothing is read from the path
    and nothing moves."""
    with PolicyServer(_Lying(policy, env, info), port=0) as srv:
        code = robot_client.main(["--server", srv.url, "--fast", "--episodes", "1", "--limits",
                                  _limits_file(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and words in err.splitlines()[-1] and "Traceback" not in err
    assert arm_recorder.commands == 0


# -- readings it can trust ---------------------------------------------------------------------

def _ur_sim(policy, **kw):
    return sim_ur_env(_spec(policy), _spec(policy), 0.04, **kw)


def test_frozen_readings_hold_then_end_the_run(policy):
    """~1 s: the RTDE timestamps stop advancing at step 10 (the stream froze; the poses are
    stale): the arms hold (no new target) and after max_reading_gap the run ends with the
    readings' error (exit 4). Before: 0 stale observations and a 6.7 cm fallback move."""
    env = _ur_sim(policy)
    receives = env.arms.arms.receives
    client = _Client(policy)
    frozen = {}

    def stamp(r):
        if client.n >= 10:
            return frozen.setdefault(id(r), r.wall() - r.started)
        return r.wall() - r.started

    for r in receives:
        r.getTimestamp = (lambda r=r: stamp(r))
    now = [0.0]

    def clock():  # 10 ms a call: the frozen time grows however fast this machine steps
        now[0] += 0.01
        return now[0]

    env.clock = clock
    out = robot.run_episodes(env, client, SafetyFilter(safety_of_spec(env.spec)), 1,
                             deadline_s=10.0, max_observation_age=0.08, max_reading_gap=0.3,
                             ends_run=ENDS_RUN, monitor=robot.OutageMonitor(clock=clock))
    assert out["aborted"]["kind"] == "readings" and "frozen" in out["aborted"]["reason"]
    assert out["stale"] > 0 and outcome(out, 1)[0] == 4
    assert client.n < 15  # the service was not asked once the readings were judged frozen


def test_slow_readings_are_missed_periods(policy):
    """~1 s: reads slowed to 60 ms against a 30 ms deadline: every period holds (stale) and the
    run ends once they stay unusable past max_reading_gap. Before: 94 overruns, no hold,
    exit 0."""
    env = _ur_sim(policy)
    rec = env.arms.arms.receives[0]
    pose = rec.getActualTCPPose
    calls = {"n": 0}

    def slow():
        calls["n"] += 1
        if calls["n"] > 5:
            time.sleep(0.06)
        return pose()

    rec.getActualTCPPose = slow
    out = robot.run_episodes(env, _Client(policy), SafetyFilter(safety_of_spec(env.spec)), 1,
                             deadline_s=0.03, max_reading_gap=0.15, ends_run=ENDS_RUN)
    assert out["aborted"]["kind"] == "readings" and "slow arm reading" in out["aborted"]["reason"]


@pytest.mark.parametrize("fault,words", [
    ("false", "servoL (left arm) returned False"),
    ("raise", "servoL (left arm) failed: RTDE connection lost"),
    ("grip", "move (right gripper) failed: [Errno 32] Broken pipe"),
])
def test_a_driver_call_that_fails_stops_the_arms_in_one_line(policy, capsys, monkeypatch,
                                                             fault, words):
    """~1 s each: servoL returning False or raising RuntimeError, a gripper raising OSError,
    at step 5: servoStop on both arms, one line, exit 4, the summary still printed. Before:
    ignored, or a traceback and exit 1."""
    n = {"servo": 0}
    stops = []
    servo, stop = SimRTDEControl.servoL, SimRTDEControl.servoStop

    def servo_(self, *a):
        n["servo"] += 1
        if n["servo"] > 10 and self.arm == 0:
            if fault == "false":
                return False
            if fault == "raise":
                raise RuntimeError("RTDE connection lost")
        return servo(self, *a)

    def grip_(self, opening):
        if n["servo"] > 10 and self.arm == 1:
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(SimRTDEControl, "servoL", servo_)
    monkeypatch.setattr(SimRTDEControl, "servoStop", lambda self, a=10.0: stops.append(a))
    if fault == "grip":
        from daddpg_jax.deploy.ursim import SimGripper

        monkeypatch.setattr(SimGripper, "move", grip_)
    code, cap = _serve_and_run(policy, capsys, "--limits", SIM, "--arms", "ur-sim",
                               "--deadline-ms", "40")
    assert code == 4, cap.err
    last = cap.err.strip().splitlines()[-1]
    assert last.startswith("error: ") and words in last and "Traceback" not in cap.err
    assert json.loads(cap.out)["aborted"]["kind"] == "ArmsError"
    assert len(stops) == 2
    del stop


def test_a_hung_driver_call_is_reported_by_the_guard():
    """~0.3 s: a driver call that has not returned after the call timeout is reported from the
    guard thread (on an arm: one line and exit 4); one that returns late raises ArmsError."""
    lines = []
    guard = CallGuard(0.05, on_overrun=lines.append).start()
    with pytest.raises(ArmsError, match="took .* ms"):
        guard.call("servoL (left arm)", time.sleep, 0.2)
    guard.close()
    assert lines and "servoL (left arm) has not returned after 50 ms" in lines[0]


def test_a_connection_that_never_answers_is_bounded():
    """~0.5 s: a controller address that accepts TCP and never answers: the RTDE probe cuts it
    at the timeout with one line (before: >= 70 s without a line, inside ur_rtde's
    constructor, which holds the interpreter); a controller that answers the RTDE version
    passes; a Python-level constructor that hangs is cut by `bounded`."""
    with pytest.raises(ArmsError, match="did not answer within 0.2 s"):
        bounded(lambda: time.sleep(5), 0.2, "the left arm at 10.0.0.1")
    silent = socket.socket()
    silent.bind(("127.0.0.1", 0))
    silent.listen(4)
    port = silent.getsockname()[1]
    t0 = time.perf_counter()
    with pytest.raises(ArmsError, match="no RTDE answer on port .* within 0.3 s"):
        probe_rtde("127.0.0.1", 0.3, port=port)
    assert time.perf_counter() - t0 < 1.0
    silent.close()
    honest = socket.socket()
    honest.bind(("127.0.0.1", 0))
    honest.listen(4)

    def answer():
        conn, _ = honest.accept()
        conn.recv(5)
        conn.sendall(bytes([0, 4, 86, 1]))  # size 4, "V", accepted
        conn.close()

    t = threading.Thread(target=answer, daemon=True)
    t.start()
    probe_rtde("127.0.0.1", 1.0, port=honest.getsockname()[1])
    t.join(2)
    honest.close()


def test_the_controller_watchdog_stops_an_arm_the_client_stopped_talking_to(policy):
    """~1 s: URArms arms the simulated controllers' watchdog at its first servoL and kicks it
    every period; when the client falls silent longer than the watchdog, the next servoL is
    refused (False) and the cell does not move: the run ends with exit 4."""
    env = _ur_sim(policy, watchdog=0.1)
    controls = env.arms.arms.controls
    cell = controls[0].cell

    class Silent(_Client):
        def act(self, obs, goal):
            if self.n == 5:
                time.sleep(0.2)  # the client stops talking (a hung host)
            return super().act(obs, goal)

    out = robot.run_episodes(env, Silent(policy), SafetyFilter(safety_of_spec(env.spec)), 1,
                             deadline_s=10.0, ends_run=ENDS_RUN)
    assert all(c.watchdog_s == pytest.approx(0.1) for c in controls)
    assert out["aborted"]["kind"] == "ArmsError" and "returned False" in out["aborted"]["reason"]
    assert not controls[0].running
    steps = cell.steps
    assert controls[0].servoL([0.0] * 6, 0, 0, 0, 0, 0) is False and cell.steps == steps


# -- answers -------------------------------------------------------------------------------------

@pytest.mark.parametrize("bad", ["garbage", {"a": 1}, [10**400] * 8, [1.0] * 7, None,
                                 [float("nan")] * 8, ["1"] * 8])
def test_a_malformed_answer_mid_episode_is_a_missed_period(policy, bad):
    """~0.3 s each: after valid answers, one answer that is not 8 finite numbers (a string, a
    dict, 400-digit integers, ...) holds the arms for that period; the episode runs on. Before:
    a traceback mid-episode."""
    env = sim_env(_spec(policy), _spec(policy))
    out = robot.run_episodes(env, _Client(policy, {5: bad}),
                             SafetyFilter(safety_of_spec(env.spec)), 1, deadline_s=10.0)
    assert out["episodes_run"] == 1 and out["stops"] == 1 and out["aborted"] is None


# -- interrupts --------------------------------------------------------------------------------

@pytest.mark.parametrize("sig,code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupt_holds_the_arms_and_writes_the_summary(policy, tmp_path, capsys, sig,
                                                            code):
    """~1 s each: SIGINT / SIGTERM mid-run: the arms stop (servoStop), the summary is printed
    and --json and the logs written, exit 130 / 143. Before: a traceback, no summary."""
    out_json, logs = tmp_path / "out.json", tmp_path / "logs"
    before = signal.getsignal(sig)  # SIG_IGN for SIGINT when pytest runs as a background job
    timer = threading.Timer(0.6, os.kill, (os.getpid(), sig))
    with PolicyServer(policy, port=0) as srv:
        timer.start()
        try:
            rc = robot_client.main(["--server", srv.url, "--episodes", "50", "--limits", SIM,
                                    "--arms", "ur-sim", "--json", str(out_json), "--log",
                                    str(logs)])
        finally:
            timer.cancel()
    cap = capsys.readouterr()
    assert rc == code, cap.err
    out = json.loads(out_json.read_text())
    assert out["aborted"]["kind"] == "signal" and out["aborted"]["signal"] == sig
    assert "interrupted by" in cap.err.splitlines()[-1] and "Traceback" not in cap.err
    assert len(os.listdir(logs)) == out["episodes_run"]
    assert signal.getsignal(sig) == before  # the handler the run found is back


# -- flags and paths -----------------------------------------------------------------------------

@pytest.mark.parametrize("flags,words", [
    (["--max-outage-s", "nan"], "--max-outage-s"),
    (["--max-outage-s", "-1"], "--max-outage-s"),
    (["--max-outage-s", "0", "--max-missed", "0"], "keep at least one limit"),
    (["--seed", "-1"], "--seed"),
    (["--episodes", "0"], "--episodes"),
    (["--speed-scale", "inf"], "--speed-scale"),
    (["--server", "http://127.0.0.1:99999"], "URL"),
    (["--json", "/nonexistent/x.json"], "--json"),
    (["--limits", "/nonexistent/limits.toml"], "cannot read limits file"),
])
def test_bad_flags_and_paths_are_one_line(capsys, flags, words):
    """~0.05 s each: every numeric flag finite and in range, every path and URL error one line
    and exit 2 (before: tracebacks, or a run that a dead service never ends)."""
    code = robot_client.main(["--fast", "--episodes", "1", *flags] if "--episodes" not in flags
                             else ["--fast", *flags])
    err = capsys.readouterr().err
    assert code == 2 and words in err and "Traceback" not in err
    assert len(err.strip().splitlines()) <= 2


def test_limits_fields_for_the_driver_are_bounded():
    """~0.01 s: connect_timeout, call_timeout, max_reading_gap and watchdog are (0, 2] s; the
    shipped files load unchanged with the defaults."""
    from daddpg_jax.deploy.limits import LimitsError

    for name in ("connect_timeout", "call_timeout", "max_reading_gap", "watchdog"):
        for bad in (0.0, -1.0, 2.5, math.nan):
            with pytest.raises(LimitsError, match=name):
                RobotLimits(**{name: bad})
    cell = RobotLimits.load(CELL)
    assert (cell.connect_timeout, cell.call_timeout, cell.max_reading_gap, cell.watchdog) == (
        2.0, 0.5, 0.5, 0.2)


def test_a_start_pose_outside_the_box_refuses_at_the_gate(policy):
    """~0.3 s: the gate's own start check, without the client: GateRefusal, nothing sent."""
    spec = _spec(policy)
    lim = dataclasses.replace(RobotLimits.load(SIM),
                              workspace_high=((0.40, 0.36, 0.50), (0.40, 0.14, 0.50)))
    env = sim_env(spec, _spec(policy), safety=lim.safety_limits())
    with pytest.raises(GateRefusal, match="start pose"):
        env.reset(np.random.default_rng(0))
    assert env.arms.arms.cell.steps == 0


def test_arms_ur_against_a_silent_controller_is_one_line(policy, tmp_path, capsys):
    """~0.5 s: daddpg-robot-client --arms ur against an address whose RTDE port accepts TCP and
    never answers: one line and exit 4 after the limits' connect_timeout (0.3 s here)."""
    pytest.importorskip("rtde_receive")
    silent = socket.socket()
    silent.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        silent.bind(("127.0.0.2", 30004))
    except OSError:
        pytest.skip("127.0.0.2:30004 is taken")
    silent.listen(4)
    lim = _limits_file(tmp_path, connect_timeout=0.3, deadline=0.03, max_observation_age=0.08)
    t0 = time.perf_counter()
    with PolicyServer(policy, port=0) as srv:
        code = robot_client.main(["--server", srv.url, "--episodes", "1", "--limits", lim,
                                  "--arms", "ur", "--ur-hosts", "127.0.0.2,127.0.0.2"])
    silent.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 4 and "no RTDE answer on port 30004 within 0.3 s" in err[-1]
    assert time.perf_counter() - t0 < 3.0


def test_the_client_refuses_an_unchecked_calibration(policy, tmp_path, capsys, arm_recorder):
    """~0.3 s: a limits file whose calibration carries no residuals (not written by
    daddpg-calibrate), or residuals over the thresholds: one line, exit 2, nothing moves."""
    nominal = {"left": {"base_pos": [0.0, 0.25, 0.40], "base_rotvec": [0.0, 0.0, math.pi]},
               "right": {"base_pos": [0.0, -0.25, 0.40], "base_rotvec": [0.0, 0.0, math.pi]}}
    for cal, words in ((nominal, "residuals"),
                       ({a: {**v, "residuals_mm": [9.0] * 6} for a, v in nominal.items()},
                        "RMS residual")):
        lim = _limits_file(tmp_path, calibration=cal)
        code, cap = _serve_and_run(policy, capsys, "--limits", lim, "--arms", "ur-sim")
        assert code == 2 and words in cap.err.splitlines()[-1], cap.err
    assert arm_recorder.commands == 0


def test_a_base_turned_almost_half_a_turn_gives_a_loadable_calibration():
    """~0.01 s: a base yaw within 1e-5 rad of pi (the nominal cell's) gives a rotation vector
    no longer than pi, so the calibration file it is written to loads (the property test found
    one 9e-6 rad past pi: the axis was not normalized)."""
    from daddpg_jax.deploy.robot import matrix_to_rotvec, rot_z, rotvec_to_matrix

    for d in (-9.05e-6, 9.05e-6, -1e-7, 1e-3):
        r = matrix_to_rotvec(rot_z(math.pi + d))
        assert np.linalg.norm(r) <= math.pi
        np.testing.assert_allclose(rotvec_to_matrix(r), rot_z(math.pi + d), atol=1e-9)
        cal = {a: {"base_pos": [0.0, y, 0.4], "base_rotvec": r.tolist(),
                   "residuals_mm": [0.5] * 6} for a, y in (("left", 0.25), ("right", -0.25))}
        RobotLimits(calibration=cal).check_calibration()
