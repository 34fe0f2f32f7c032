"""The arms interface (daddpg_jax/deploy/arms.py), its simulator implementation (--arms sim)
and the simulated UR controllers (daddpg_jax/deploy/ursim.py), and frame calibration
(daddpg_jax/deploy/calibrate.py, daddpg-calibrate). In-process, no JAX, no MJX; the policy is a
hand-built reach controller (tests/reach_controller.py). Cost: ~0.1-3.5 s per test, ~9 s the
module."""

from __future__ import annotations

import dataclasses
import inspect
import json
import os
import re
import shutil
import socket
import threading
import tomllib

import numpy as np
import pytest

from daddpg_jax.cli import calibrate as calibrate_cli
from daddpg_jax.cli import robot_client
from daddpg_jax.deploy import NumpyPolicy, calibrate, robot, ur3
from daddpg_jax.deploy.arms import (
    CONTROL_CALLS,
    RECEIVE_CALLS,
    Arms,
    ArmsEnv,
    ArmsStopped,
    RobotiqGripper,
    URArms,
    base_transform,
    connect_ur,
    joint_solution,
    link_points_base,
    safety_of_spec,
)
from daddpg_jax.deploy.arms_factory import make_env
from daddpg_jax.deploy.gate import GateRefusal
from daddpg_jax.deploy.limits import SHIPPED, LimitsError, RobotLimits
from daddpg_jax.deploy.policy import task_settings
from daddpg_jax.deploy.safety import SafetyFilter
from daddpg_jax.deploy.server import PolicyServer
from daddpg_jax.deploy.ursim import SimArms, SimCell, sim_env, sim_ur_env
from mjx_envs import randomize, rules
from mjx_envs.numpy_env import NumpyDualArmEnv
from tests.reach_controller import write_reach_controller

pytestmark = pytest.mark.usefixtures("arm_recorder")  # every command checked

SIM_LIMITS = os.path.join(SHIPPED, "sim.toml")
BOARD = os.path.join(SHIPPED, "board_example.json")
ERROR = ([[0.02, 0.01, 0.0], [-0.01, -0.02, 0.005]], np.radians([2.0, -2.0]))
ERROR_FLAG = "0.02,0.01,0,2,-0.01,-0.02,0.005,-2"


@pytest.fixture(scope="module")
def policy(tmp_path_factory):
    return NumpyPolicy.load(write_reach_controller(tmp_path_factory.mktemp("p") / "rc.npz"))


class _Client:
    """The policy in-process (no HTTP): what PolicyClient.act returns."""

    def __init__(self, policy, bad_steps=()):
        self.policy, self.bad, self.n = policy, set(bad_steps), 0

    def act(self, obs, goal):
        self.n += 1
        if self.n in self.bad:
            return None, {"error": "no answer"}
        return self.policy.act(obs, goal).tolist(), {}


def _env(policy):
    return NumpyDualArmEnv(task_settings(policy.task, policy.env), task=policy.task)


def _run(policy, env, episodes, client=None):
    limits = RobotLimits.load(SIM_LIMITS).safety_limits()
    return robot.run_episodes(env, client or _Client(policy), SafetyFilter(limits), episodes,
                              seed=0, deadline_s=10.0)


class _Recorder:
    """Wraps a ur_rtde-style object and records (method, number of arguments) of each call."""

    def __init__(self, inner, calls):
        self._inner, self._calls = inner, calls

    def __getattr__(self, name):
        f = getattr(self._inner, name)

        def call(*args, **kw):
            assert not kw, f"{name} called with keyword arguments"
            self._calls.append((name, len(args)))
            return f(*args)

        return call


def _recorded_ur_sim(policy, calls):
    env = sim_ur_env(_env(policy), _env(policy), 0.04, watchdog=1.0)
    ur = env.arms.arms  # URArms behind the gate
    ur.controls = [_Recorder(c, calls) for c in ur.controls]
    ur.receives = [_Recorder(r, calls) for r in ur.receives]
    return env


# -- the UR implementation on the simulated controllers ----------------------------------------

def test_link_points_from_joint_angles_match_the_simulator(policy):
    """~1 s: the clearance check's link points from getActualQ (ur3 DH) equal the MJCF's."""
    env = sim_ur_env(_env(policy), _env(policy), 0.04)
    res = env.reset(np.random.default_rng(3))
    truth = env.truth()[0]["link_points"]
    np.testing.assert_allclose(res.link_points, truth, atol=2e-4)
    q = np.zeros(6)
    np.testing.assert_allclose(link_points_base(q)[-1], ur3.forward_kinematics(q)[:3, 3])


def test_ur_sim_succeeds_at_the_sim_rate_and_identity_frames_fail(policy):
    """~3 s: 20 episodes through the simulator and through URArms on the simulated
    controllers (same goals): the rates agree within the sim's 95% CI; with the frame
    conversion replaced by the identity the gate refuses to start (the arms' measured poses
    lie outside their boxes in that frame): nothing moves."""
    sim = _run(policy, _env(policy), 20)
    ur = _run(policy, sim_ur_env(_env(policy), _env(policy), 0.04), 20)
    lo, hi = sim["success_ci95"]
    assert sim["success_rate"] >= 0.8
    assert lo <= ur["success_rate"] <= hi
    assert abs(ur["mean_final_distance"] - sim["mean_final_distance"]) < 0.002
    ident = sim_ur_env(_env(policy), _env(policy), 0.04, bases=np.stack([np.eye(4)] * 2))
    with pytest.raises(GateRefusal, match="measured tool position .* outside its box"):
        _run(policy, ident, 3)
    assert ident.arms.arms.receives[0].cell.steps == 0


def test_every_ur_rtde_call_exists_with_its_argument_count(policy):
    """~2 s: the ur_rtde methods URArms calls (recorded over an episode, a hold and the exit)
    exist in the installed package and accept the number of arguments used (signatures parsed
    from pybind11's docstrings, overloads included)."""
    rtde_control = pytest.importorskip("rtde_control")
    rtde_receive = pytest.importorskip("rtde_receive")
    calls = []
    env = _recorded_ur_sim(policy, calls)
    _run(policy, env, 1, client=_Client(policy, bad_steps={3}))
    env.close()
    used = set(calls)
    assert {n for n, _ in used} == set(CONTROL_CALLS) | set(RECEIVE_CALLS)
    for name, nargs in used:
        cls = (rtde_control.RTDEControlInterface if name in CONTROL_CALLS
               else rtde_receive.RTDEReceiveInterface)
        if name == "disconnect" and name in CONTROL_CALLS and name in RECEIVE_CALLS:
            classes = (rtde_control.RTDEControlInterface, rtde_receive.RTDEReceiveInterface)
        else:
            classes = (cls,)
        for c in classes:
            doc = getattr(c, name).__doc__
            ranges = _arg_ranges(name, doc)
            assert ranges, f"{c.__name__}.{name}: no signature in its docstring"
            assert any(lo <= nargs <= hi for lo, hi in ranges), (c.__name__, name, nargs, ranges)
    assert _arg_ranges("servoL", rtde_control.RTDEControlInterface.servoL.__doc__) == [(6, 6)]
    for c in (rtde_control.RTDEControlInterface, rtde_receive.RTDEReceiveInterface):
        # connect_ur and receive_only construct each with the host alone
        assert any(lo <= 1 <= hi for lo, hi in _arg_ranges("__init__", c.__init__.__doc__))


def _split_top(text):
    out, depth, cur = [], 0, ""
    for ch in text:
        depth += ch in "[(" and 1 or (ch in "])" and -1 or 0)
        if ch == "," and depth == 0:
            out.append(cur)
            cur = ""
        else:
            cur += ch
    return out + ([cur] if cur.strip() else [])


def _arg_ranges(name, doc):
    """(required, total) argument counts, self excluded, of each signature in ``doc``."""
    out = []
    for m in re.finditer(rf"(?m)^(?:\d+\. )?{name}\((.*)\) ->", doc or ""):
        params = [p.strip() for p in _split_top(m.group(1))][1:]  # drop self
        out.append((sum("=" not in p for p in params), len(params)))
    return out


def test_a_hold_streams_the_held_pose_and_servo_stop_comes_only_at_exit(policy):
    """~1 s: a missed answer makes both arms stream servoL of the held pose; servoStop is sent
    once, on close."""
    calls = []
    env = _recorded_ur_sim(policy, calls)
    sent = []
    servo = env.arms.arms.servo  # what passes the gate
    env.arms.arms.servo = lambda poses: (sent.append(np.array(poses)), servo(poses))
    out = _run(policy, env, 1, client=_Client(policy, bad_steps={5, 6}))
    assert out["stops"] == 2
    assert len(sent) == env.episode_length
    np.testing.assert_allclose(sent[4], sent[3])  # step 5 held step 4's pose
    np.testing.assert_allclose(sent[5], sent[3])
    assert [c for c in calls if c[0] == "servoStop"] == []
    env.close()
    assert [c for c in calls if c[0] == "servoStop"] == [("servoStop", 1)] * 2


def test_a_protective_stop_ends_the_run(policy):
    """~1 s: an arm in a protective stop raises ArmsStopped out of the loop (one line)."""
    env = sim_ur_env(_env(policy), _env(policy), 0.04)
    cell = env.arms.receives[1].cell

    class Stopper(_Client):
        def act(self, obs, goal):
            if self.n == 4:
                cell.protective[1] = True
            return super().act(obs, goal)

    with pytest.raises(ArmsStopped, match="right arm is in a protective stop"):
        _run(policy, env, 1, client=Stopper(policy))


def test_dry_run_moves_nothing_and_records_what_it_would_send(policy):
    """~1 s: a dry run never steps the simulated cell; every servoL is recorded."""
    env = sim_ur_env(_env(policy), _env(policy), 0.04, dry_run=True)
    cell = env.arms.receives[0].cell
    _run(policy, env, 1)
    assert cell.steps == 0
    servos = [c for c in env.arms.sent if "servoL" in c]
    assert len(servos) == env.episode_length
    assert np.asarray(servos[-1]["servoL"]).shape == (2, 6)


def test_connect_ur_unreachable_is_one_line():
    """~0.1 s: no controller listening -> ArmsError naming the arm and the host."""
    pytest.importorskip("rtde_receive")
    from daddpg_jax.deploy.arms import ArmsError

    with pytest.raises(ArmsError, match=r"cannot connect to the left arm at 127\.0\.0\.1"):
        connect_ur(["127.0.0.1", "127.0.0.1"], 0.04)


def test_robot_client_arms_errors_exit_cleanly(policy, capsys):
    """~1 s: --arms ur without a controller exits 4 with one line; usage errors exit 2."""
    pytest.importorskip("rtde_receive")
    with PolicyServer(policy, port=0) as srv:
        url = srv.url
        base = ["--server", url, "--limits", SIM_LIMITS, "--episodes", "1"]
        assert robot_client.main(base + ["--arms", "ur", "--ur-hosts",
                                         "127.0.0.1,127.0.0.1"]) == 4
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith("error: cannot connect to the left arm")
        assert robot_client.main(base + ["--arms", "ur"]) == 2
        assert "--ur-hosts" in capsys.readouterr().err
        assert robot_client.main(base + ["--dry-run"]) == 2
        assert robot_client.main(base + ["--arms", "ur", "--fast"]) == 2
        assert robot_client.main(base + ["--arms", "ur-sim", "--sim-base-error", "1,2"]) == 2
        assert "Traceback" not in capsys.readouterr().err


# -- the simulator behind the arms interface (--arms sim) ----------------------------------------

def test_sim_arms_and_ur_arms_implement_every_method_of_the_arms_interface():
    """~0.1 s: URArms and SimArms have every method of the Protocol Arms, with its parameters;
    --arms sim is an ArmsEnv on SimArms converting with the simulator's own bases (a limits
    file's calibration is for real or rehearsed UR arms), and still refuses --dry-run."""
    methods = [n for n, f in vars(Arms).items() if inspect.isfunction(f) and n[0] != "_"]
    assert set(methods) == {"read", "servo", "grip", "home", "stop", "close"}
    for cls in (URArms, SimArms):
        for name in methods:
            want = list(inspect.signature(getattr(Arms, name)).parameters)
            assert list(inspect.signature(getattr(cls, name)).parameters) == want, (cls, name)
    env = make_env("sim", None, "reach", 0.04, bases=np.stack([np.eye(4)] * 2))
    assert isinstance(env, ArmsEnv) and isinstance(env.arms.arms, SimArms)
    np.testing.assert_allclose(env.bases, env.arms.cell.bases)  # its own exact bases
    from daddpg_jax.deploy.arms import ArmsUsageError

    with pytest.raises(ArmsUsageError, match="--dry-run needs --arms ur or ur-sim"):
        make_env("sim", None, "reach", 0.04, dry_run=True)


def _same_step(a, b):
    np.testing.assert_allclose(b.observation, a.observation, atol=1e-5)
    np.testing.assert_allclose(b.target, a.target, atol=1e-5)
    np.testing.assert_allclose(b.link_points, a.link_points, atol=1e-5)
    np.testing.assert_allclose(b.goal_distance, a.goal_distance, atol=1e-5)
    np.testing.assert_allclose(b.arm_clearance, a.arm_clearance, atol=1e-5)
    assert b.success == a.success


def _sim_arms_without_clearance_rule(task):
    """--arms sim on the simulator's own limits with the gate's clearance rule off: random
    actions drive the arms into each other, which the gate refuses (tests/test_gate.py), while
    the simulator stepped directly lets them collide."""
    spec = NumpyDualArmEnv(task=task)
    safety = dataclasses.replace(safety_of_spec(spec), min_clearance=0.0)
    return sim_env(spec, NumpyDualArmEnv(task=task), safety=safety)


@pytest.mark.parametrize("task,episodes", [("reach", (0, 1, 2)), ("pickup", (0,))])
def test_arms_sim_observes_moves_and_succeeds_as_the_simulator(task, episodes):
    """~0.5 s per task: the same goals and random actions through --arms sim (ArmsEnv on
    SimArms) and through the simulator stepped directly give the same observations, targets,
    link points, clearances, goal distances and success at every step (to 1e-5; in fact
    bit-identical here)."""
    sim = NumpyDualArmEnv(task=task)
    arms = _sim_arms_without_clearance_rule(task)
    for ep in episodes:
        _same_step(sim.reset(np.random.default_rng(ep)), arms.reset(np.random.default_rng(ep)))
        rng = np.random.default_rng(100 + ep)
        for _ in range(sim.episode_length):
            act = rng.uniform(-1, 1, 8).astype(np.float32)
            _same_step(sim.step_targets(*sim.command_targets(act)),
                       arms.step_targets(*arms.command_targets(act)))
    assert arms.refused == 0


def test_arms_sim_differs_from_the_simulator_only_where_a_ur3_cannot_reach():
    """~0.3 s: the one way the two paths part: the simulator's workspace box holds tool-down
    poses outside a UR3's reach, which the simulator follows as far as its arm goes, while the
    arms interface's joint-limit check (ArmsEnv._reachable) refuses them (the arm keeps its
    previous target, counted in ``refused``). Reach, goals of seed 3, random actions: the same
    up to step 27, whose left target (0.375, -0.124, 0.601) m has no joint solution."""
    sim = NumpyDualArmEnv(task="reach")
    arms = _sim_arms_without_clearance_rule("reach")
    sim.reset(np.random.default_rng(3))
    arms.reset(np.random.default_rng(3))
    rng = np.random.default_rng(103)
    for step in range(sim.episode_length):
        act = rng.uniform(-1, 1, 8).astype(np.float32)
        before = arms.target
        wanted, ctrl = arms.command_targets(act)
        a = sim.step_targets(*sim.command_targets(act))
        b = arms.step_targets(wanted, ctrl)
        if arms.refused:
            refused_at = step
            break
        _same_step(a, b)
    assert refused_at == 27 and arms.refused == 1
    np.testing.assert_allclose(wanted[0], [0.375, -0.124, 0.601], atol=1e-3)
    np.testing.assert_array_equal(b.target[0], before[0])  # the left arm kept its target
    np.testing.assert_array_equal(b.target[1], a.target[1])
    np.testing.assert_array_equal(a.target[0], wanted[0])  # the simulator took it
    pose = arms.to_base_poses(wanted)[0]
    assert joint_solution(arms._q[0], pose, iterations=100) is None


def test_robot_client_arms_sim_gives_the_simulator_s_results(policy, tmp_path, capsys):
    """~2.5 s: daddpg-robot-client --arms sim --fast (in-process, HTTP to an in-process
    service; 20 episodes, seed 0, sim.toml) against the loop on the simulator stepped directly
    with the same goals: the same success, final distances, clearance interventions and
    smallest arm gap (the first 20 episodes of docs/DEPLOYMENT.md's sim rows), no target
    refused. The limits are sim.toml's with a 2 s deadline (allowed unpaced), so that a loaded
    machine does not turn periods into holds."""
    direct = _run(policy, _env(policy), 20)
    out_json = tmp_path / "out.json"
    slow = tmp_path / "sim_slow.json"
    with open(SIM_LIMITS, "rb") as f:
        slow.write_text(json.dumps({**tomllib.load(f), "deadline": 2.0,
                                    "max_observation_age": 2.0}))
    with PolicyServer(policy, port=0) as srv:
        code = robot_client.main(["--server", srv.url, "--limits", str(slow), "--arms", "sim",
                                  "--fast", "--episodes", "20", "--seed", "0",
                                  "--json", str(out_json)])
    assert code == 0, capsys.readouterr().err
    out = json.loads(out_json.read_text())
    assert out["arms"] == "sim" and out["joint_refusals"] == 0 and out["stops"] == 0
    for key in ("success_rate", "mean_final_distance", "safety_counts", "min_arm_clearance"):
        assert out[key] == pytest.approx(direct[key], abs=1e-9), key
    assert out["success_rate"] >= 0.8


def test_sim_arms_protective_stop_ends_the_run(policy):
    """~0.5 s: a protective stop raised on the simulated cell ends an --arms sim run as on
    real arms (ArmsStopped, one line)."""
    env = sim_env(_env(policy), _env(policy))
    cell = env.arms.cell

    class Stopper(_Client):
        def act(self, obs, goal):
            if self.n == 4:
                cell.emergency[0] = True
            return super().act(obs, goal)

    with pytest.raises(ArmsStopped, match="left arm is emergency stopped"):
        _run(policy, env, 1, client=Stopper(policy))


# -- the gripper ------------------------------------------------------------------------------

def test_robotiq_gripper_speaks_the_urcap_protocol():
    """~0.2 s: a fake URCap socket: activation, SET POS from an opening, GET POS back."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    got, pos = [], [0]

    def serve():
        conn, _ = srv.accept()
        buf = b""
        with conn:
            while True:
                data = conn.recv(256)
                if not data:
                    return
                buf += data
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    cmd = line.decode()
                    got.append(cmd)
                    if cmd.startswith("SET POS"):
                        pos[0] = int(cmd.split()[2])
                    conn.sendall(f"POS {pos[0]}\n".encode() if cmd == "GET POS" else b"ack\n")

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    g = RobotiqGripper("127.0.0.1", port=srv.getsockname()[1], timeout=1.0)
    g.move(0.085 / 4)  # half of the stroke's gap -> position 128 of 255
    o1, o2 = g.openings()
    g.close()
    t.join(2)
    srv.close()
    assert got[:4] == ["SET ACT 1", "SET SPE 255", "SET FOR 50", "SET GTO 1"]
    assert got[4] == "SET POS 127" or got[4] == "SET POS 128"
    assert o1 == o2 and abs(o1 - 0.085 / 4) < 0.0003


# -- calibration ------------------------------------------------------------------------------

def _board(arm):
    with open(BOARD) as f:
        return np.asarray(json.load(f)[arm])


def test_calibration_error_percentiles_over_100_seeded_trials():
    """~0.5 s: bases drawn as mjx_envs/randomize.py models them (base_offset 0.05 m, base_yaw
    5 deg bounds), 8 board points per arm, Gaussian noise of 0.5 mm RMS per point: over 100
    seeded trials (both arms) the 95th percentiles of the base position and rotation errors
    are within 1 mm and 0.1 deg."""
    pos, ang = [], []
    r = randomize.Randomization(base_offset=0.05, base_yaw=5.0)
    sigma = 0.5e-3 / np.sqrt(3.0)
    for trial in range(100):
        rng = np.random.default_rng(trial)
        p = randomize.unpack(np.asarray(randomize.draw(np, rules.NumpySampler(), rng, r)
                                        ["params"], float))
        for i, (arm, a) in enumerate(zip(("left", "right"), robot.ARMS)):
            T = base_transform(ur3.BASE_POS[a] + p["offset"][i], ur3.BASE_YAW[a] + p["yaw"][i])
            w = _board(arm)
            inv = np.linalg.inv(T)
            b = w @ inv[:3, :3].T + inv[:3, 3] + rng.normal(0.0, sigma, w.shape)
            est, res = calibrate.fit_base(w, b)
            assert res.shape == (8,) and np.all(res < 3e-3)
            e = calibrate.pose_error(est, T)
            pos.append(e[0])
            ang.append(e[1])
    assert np.percentile(pos, 95) < 1e-3
    assert np.percentile(ang, 95) < 0.1


def test_full_rotation_fit_recovers_a_tilted_base_exactly():
    """~0.1 s: Kabsch (model full) on noiseless non-coplanar points."""
    T = base_transform([0.01, 0.2, 0.41], 3.0)
    T[:3, :3] = T[:3, :3] @ robot.rotvec_to_matrix([0.02, -0.01, 0.0])
    w = np.concatenate([_board("left"), _board("left")[:4] + [0, 0, 0.1]])
    inv = np.linalg.inv(T)
    est, res = calibrate.fit_base(w, w @ inv[:3, :3].T + inv[:3, 3], model="full")
    assert calibrate.pose_error(est, T)[0] < 1e-9 and np.max(res) < 1e-9


@pytest.mark.parametrize("w, b, msg", [
    (np.zeros((5, 3)), np.zeros((5, 3)), "at least 6"),
    (np.c_[np.arange(6.0), np.zeros(6), np.zeros(6)] * 0.1,
     np.c_[np.arange(6.0), np.zeros(6), np.zeros(6)] * 0.1, "one line"),
    (np.full((4, 3), np.nan), np.zeros((4, 3)), "NaN"),
    (np.zeros((4, 2)), np.zeros((4, 3)), "rows of"),
])
def test_calibration_refuses_bad_points(w, b, msg):
    """~0.1 s each."""
    with pytest.raises(calibrate.CalibrationError, match=msg):
        calibrate.fit_base(w, b)


def test_write_calibration_replaces_its_block_and_limits_validate_it(tmp_path):
    """~0.1 s: written twice, one block; the limits read it back; a bad one is refused."""
    path = tmp_path / "cell.toml"
    shutil.copy(SIM_LIMITS, path)
    T = base_transform([0.01, 0.26, 0.4], np.pi + 0.02)
    for _ in range(2):
        lim = calibrate.write_calibration(path, {a: calibrate.entry(T, [1e-4] * 8)
                                                 for a in ("left", "right")})
    assert path.read_text().count(calibrate.MARKER) == 1
    np.testing.assert_allclose(lim.base_transforms()[0], T, atol=1e-6)
    np.testing.assert_allclose(RobotLimits().base_transforms()[1], ur3.base_transform("r"))
    with pytest.raises(LimitsError, match="calibration.left.base_pos"):
        RobotLimits(calibration={"left": {"base_pos": [float("nan"), 0, 0],
                                          "base_rotvec": [0, 0, 0]},
                                 "right": {"base_pos": [0, 0, 0], "base_rotvec": [0, 0, 0]}})


def test_calibrate_cli_bad_input_is_one_line(tmp_path, capsys):
    """~0.1 s: a missing points file and too few points: exit 2, one line, no traceback."""
    lim = tmp_path / "cell.toml"
    shutil.copy(SIM_LIMITS, lim)
    assert calibrate_cli.main(["--limits", str(lim), "--points", str(tmp_path / "no.json"),
                               "--arms", "ur-sim"]) == 2
    few = tmp_path / "few.json"
    few.write_text(json.dumps({"left": [[0.2, 0, 0.41]] * 3, "right": [[0.2, 0, 0.41]] * 3}))
    assert calibrate_cli.main(["--limits", str(lim), "--points", str(few), "--arms",
                               "ur-sim"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(e.startswith("error: ") for e in err)
    assert "calibration" not in lim.read_text()


def test_a_calibration_error_corrected_by_the_tool_keeps_the_success(policy, tmp_path):
    """~4 s: the simulated bases carry an error (2 cm, 2 deg): uncalibrated, the policy fails
    through ur-sim; daddpg-calibrate (rehearsed on the same controllers, 0.5 mm noise) writes
    the bases into the limits file, and with them the success is that of the exact frames."""
    lim = tmp_path / "cell.toml"
    shutil.copy(SIM_LIMITS, lim)
    off, yaw = ERROR
    before = _run(policy, sim_ur_env(_env(policy), _env(policy), 0.04, offset=off, yaw=yaw), 10)
    assert calibrate_cli.main(["--limits", str(lim), "--points", BOARD, "--arms", "ur-sim",
                               "--sim-base-error", ERROR_FLAG]) == 0
    bases = RobotLimits.load(lim).base_transforms()
    after = _run(policy, sim_ur_env(_env(policy), _env(policy), 0.04, bases=bases, offset=off,
                                    yaw=yaw), 10)
    exact = _run(policy, _env(policy), 10)
    assert before["success_rate"] <= 0.1
    assert after["success_rate"] >= exact["success_rate"] - 0.1
    cell = SimCell(_env(policy), off, yaw)
    for i in range(2):
        assert calibrate.pose_error(bases[i], cell.bases[i])[0] < 1e-3


def test_ur_sim_observes_what_the_simulator_observes_in_an_object_task():
    """~1 s: pick-up, 30 random actions through the simulator and through URArms on the
    simulated controllers (the object from the cell's object source): the observations agree
    to float32 rounding (frames, velocities, fingers, object terms)."""
    sim = NumpyDualArmEnv(task="pickup")
    ur = sim_ur_env(NumpyDualArmEnv(task="pickup"), NumpyDualArmEnv(task="pickup"), 0.04)
    a, b = sim.reset(np.random.default_rng(1)), ur.reset(np.random.default_rng(1))
    np.testing.assert_allclose(a.observation, b.observation, atol=1e-5)
    rng = np.random.default_rng(0)
    for _ in range(30):
        act = rng.uniform(-1, 1, 8).astype(np.float32)
        a = sim.step_targets(*sim.command_targets(act))
        b = ur.step_targets(*ur.command_targets(act))
        np.testing.assert_allclose(a.observation, b.observation, atol=1e-5)
    np.testing.assert_allclose(a.achieved_goal, b.achieved_goal, atol=1e-6)


def test_targets_without_a_joint_solution_within_the_limits_are_refused(policy):
    """~0.5 s: a target out of the arm's reach keeps that arm's previous target (counted);
    a reachable one is sent; joint_solution reproduces a known pose."""
    from daddpg_jax.deploy.arms import joint_solution, within_joint_limits

    env = sim_ur_env(_env(policy), _env(policy), 0.04)
    env.reset(np.random.default_rng(0))
    before = env.target
    far = before.copy()
    far[0] = [1.5, 0.25, 0.5]
    far[1] += [0.01, 0.0, 0.0]
    env.step_targets(far, np.zeros(4, np.float32))
    assert env.refused == 1
    np.testing.assert_allclose(env.target[0], before[0])
    np.testing.assert_allclose(env.target[1], far[1])
    q = np.array([0.3, -1.5, 1.9, -1.8, -1.57, 0.4])
    T = ur3.forward_kinematics(q)
    pose = np.concatenate([T[:3, 3], robot.matrix_to_rotvec(T[:3, :3])])
    sol = joint_solution(q + 0.02, pose)
    assert sol is not None and within_joint_limits(sol)
    np.testing.assert_allclose(ur3.forward_kinematics(sol)[:3, 3], T[:3, 3], atol=1e-4)
    assert not within_joint_limits(q + [0, 0, 0, 0, 0, 2 * np.pi])
