"""Robot side: NumPy env vs the trainer's env, safety limits, real-robot conventions, the
client loop against a served policy (fast end-to-end; slow: trained reach vs trainer eval), and
the client's outage handling (counting logic; a service killed or frozen mid-run)."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import time

import jax
import numpy as np
import pytest

import mjx_envs
from daddpg_jax.algo.config import TrainConfig, preset
from daddpg_jax.algo.train import make_train_fns
from daddpg_jax.deploy import NumpyPolicy, robot, ur3
from daddpg_jax.deploy.safety import SafetyFilter, SafetyLimits
from daddpg_jax.deploy.server import PolicyClient, PolicyServer
from daddpg_jax.running.export import _env_settings, export_run, export_state
from mjx_envs.numpy_env import NumpyDualArmEnv

pytestmark = pytest.mark.usefixtures("arm_recorder")  # every command checked

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NO_CLEARANCE_RULE = -1e9


@pytest.fixture(scope="module")
def jenv():
    return mjx_envs.make("reach", physics="c")


@pytest.fixture(scope="module")
def settings(jenv):
    return _env_settings(jenv)


@pytest.fixture(scope="module")
def jax_step(jenv):
    return jax.jit(jenv.step), jax.jit(jenv.reset)


# -- the NumPy env mirrors the trainer's C-engine env -------------------------------------------

def test_numpy_env_matches_trainer_env(jenv, settings, jax_step):
    step, reset = jax_step
    nenv = NumpyDualArmEnv(settings)
    rng = np.random.default_rng(0)
    for ep in range(2):
        s = reset(jax.random.PRNGKey(ep))
        r = nenv.reset(goal=np.asarray(s.obs["desired_goal"]))
        np.testing.assert_array_equal(r.observation, np.asarray(s.obs["observation"]))
        for _ in range(jenv.episode_length):
            a = rng.uniform(-1.3, 1.3, 8).astype(np.float32)  # includes out-of-range values
            s, r = step(s, a), nenv.step(a)
            np.testing.assert_allclose(r.observation, np.asarray(s.obs["observation"]), atol=1e-5)
            np.testing.assert_allclose(r.achieved_goal, np.asarray(s.obs["achieved_goal"]),
                                       atol=1e-5)
            np.testing.assert_allclose(r.target, np.asarray(s.data.mocap_pos[:2]), atol=1e-6)
            assert r.success == bool(s.metrics["success"])
            assert r.arm_clearance == pytest.approx(float(s.metrics["arm_clearance"]), abs=1e-5)
        assert r.step == jenv.episode_length


def test_numpy_env_goals_and_float64_mode(settings):
    env = NumpyDualArmEnv(settings)
    rng = np.random.default_rng(1)
    goals = np.stack([env.sample_goal(rng) for _ in range(500)])
    lo, hi = np.asarray(settings["goal_low"]), np.asarray(settings["goal_high"])
    assert np.all(goals >= lo - 1e-7) and np.all(goals <= hi + 1e-7)
    assert goals.std(0).min() > 0.02
    r = env.reset(rng)
    np.testing.assert_allclose(r.achieved_goal, env.home_mocap, atol=2e-3)
    loose = NumpyDualArmEnv(settings, exact=False)
    r2 = loose.reset(goal=r.desired_goal)
    for _ in range(20):
        a = np.array([1, 0, 0, 0, 0, -1, 0, 0], np.float32)
        r, r2 = env.step(a), loose.step(a)
    np.testing.assert_allclose(r.achieved_goal, r2.achieved_goal, atol=5e-3)
    with pytest.raises((ValueError, NotImplementedError)):
        NumpyDualArmEnv(settings, task="no_such_task")


# -- safety layer --------------------------------------------------------------------------------

def _limits(**kw):
    base = dict(workspace_low=np.array([[0.1, -0.2, 0.4], [0.1, -0.4, 0.4]], np.float32),
                workspace_high=np.array([[0.4, 0.4, 0.7], [0.4, 0.2, 0.7]], np.float32),
                max_step=0.05, min_clearance=0.02, deadline_s=0.04)
    base.update(kw)
    return SafetyLimits(**base)


def _parallel_arms(y_gap: float):
    """Link points of two straight arms along x at y = +-y_gap/2 (z = 0.5)."""
    xs = np.array([0.0, 0.1, 0.2, 0.3, 0.4], np.float32)
    left = np.stack([xs, np.full(5, y_gap / 2), np.full(5, 0.5)], -1)
    right = left * np.array([1, -1, 1], np.float32)
    return np.stack([left, right]).astype(np.float32)


def test_validate_action():
    f = SafetyFilter(_limits())
    assert f.validate_action([0.1] * 8).dtype == np.float32
    for bad in ([0.1] * 7, [[0.1] * 4] * 2, [0.1] * 7 + [float("nan")], [0.1] * 7 + [float("inf")],
                ["a"] * 8, None, {"a": 1}):
        assert f.validate_action(bad) is None, bad


def test_speed_cap_and_workspace_clamp():
    f = SafetyFilter(_limits())
    cur = np.array([[0.25, 0.1, 0.5], [0.25, -0.1, 0.5]], np.float32)
    far = cur + np.array([[0.3, 0.4, 0.0], [0.01, 0.0, 0.0]], np.float32)
    t, capped = f.cap_speed(cur, far)
    assert capped
    np.testing.assert_allclose(np.linalg.norm(t - cur, axis=-1), [0.05, 0.01], atol=1e-6)
    np.testing.assert_allclose((t - cur)[0] / 0.05, [0.6, 0.8, 0.0], atol=1e-5)  # same direction
    t2, capped2 = f.cap_speed(cur, cur + 0.02)
    assert not capped2 and np.allclose(t2, cur + 0.02)
    out = np.array([[0.0, 0.5, 0.9], [0.5, -0.5, 0.2]], np.float32)
    c, clamped = f.clamp_workspace(out)
    assert clamped
    np.testing.assert_allclose(c, [[0.1, 0.4, 0.7], [0.4, -0.4, 0.4]])
    d = f.filter(cur, out, _parallel_arms(0.6))
    assert not d.stopped and "speed" in d.reasons
    assert np.all(np.linalg.norm(d.target - cur, axis=-1) <= 0.05 + 1e-6)
    assert np.all(d.target >= f.limits.workspace_low)
    assert np.all(d.target <= f.limits.workspace_high)


def test_clearance_rule_refuses_approach_and_allows_separation():
    f = SafetyFilter(_limits(min_clearance=0.02, max_step=1.0))
    radii = 0.06 + 0.06  # gripper capsules (largest) facing each other
    lp = _parallel_arms(radii + 0.04)  # 4 cm gap
    assert f.clearance(lp) == pytest.approx(0.04, abs=1e-5)
    cur = lp[:, -1].copy()  # targets at the tool points
    # left arm moves 3 cm towards the right arm: predicted gap 1 cm < 2 cm -> refused; half
    # of it (gap 2.5 cm) goes
    prop = cur + np.array([[0.0, -0.03, 0.0], [0.0, 0.0, 0.0]], np.float32)
    d = f.filter(cur, prop, lp, tool=cur)
    assert "clearance" in d.reasons and not d.stopped
    np.testing.assert_allclose(d.target, cur + 0.5 * (prop - cur), atol=1e-6)
    # both approach by 3 cm: half is too far (gap 1 cm), a quarter goes (gap 2.5 cm)
    prop = cur + np.array([[0.0, -0.03, 0.0], [0.0, 0.03, 0.0]], np.float32)
    d = f.filter(cur, prop, lp, tool=cur)
    np.testing.assert_allclose(d.target, cur + 0.25 * (prop - cur), atol=1e-6)
    assert d.clearance_after >= 0.02 - 1e-6
    # both approach by 2 cm: half of it ends at the 2 cm limit
    prop = cur + np.array([[0.0, -0.02, 0.0], [0.0, 0.02, 0.0]], np.float32)
    d = f.filter(cur, prop, lp, tool=cur)
    assert "clearance" in d.reasons and d.clearance_after >= 0.02 - 1e-6
    np.testing.assert_allclose(d.target, cur + 0.5 * (prop - cur), atol=1e-6)
    # left approaches by 10 cm, right moves 10 cm sideways: even a quarter is too far; the
    # arm that moves less (a tie: left) stops and right goes on
    prop = cur + np.array([[0.0, -0.1, 0.0], [-0.1, 0.0, 0.0]], np.float32)
    d = f.filter(cur, prop, lp, tool=cur)
    np.testing.assert_allclose(d.target[0], cur[0])
    np.testing.assert_allclose(d.target[1], prop[1])
    # both approach by 10 cm: nothing but stopping both keeps the gap
    prop = cur + np.array([[0.0, -0.1, 0.0], [0.0, 0.1, 0.0]], np.float32)
    d = f.filter(cur, prop, lp, tool=cur)
    np.testing.assert_allclose(d.target, cur)
    # left approaches a little (predicted gap 3 cm >= limit): allowed
    prop = cur + np.array([[0.0, -0.01, 0.0], [0.0, 0.0, 0.0]], np.float32)
    d = f.filter(cur, prop, lp, tool=cur)
    assert "clearance" not in d.reasons
    np.testing.assert_allclose(d.target, prop)
    # left approaches, right moves away by more: one arm may go, the gap is kept
    prop = cur + np.array([[0.0, -0.03, 0.0], [0.0, -0.01, 0.0]], np.float32)
    d = f.filter(cur, prop, lp, tool=cur)
    assert d.clearance_after >= 0.02 - 1e-6
    # arms already too close (5 mm) may separate but not approach
    close = _parallel_arms(radii + 0.005)
    cur = close[:, -1].copy()
    apart = cur + np.array([[0.0, 0.01, 0.0], [0.0, -0.01, 0.0]], np.float32)
    d = f.filter(cur, apart, close, tool=cur)
    assert "clearance" not in d.reasons
    np.testing.assert_allclose(d.target, apart)
    sideways = cur + np.array([[0.01, -0.001, 0.0], [0.0, 0.0, 0.0]], np.float32)
    d = f.filter(cur, sideways, close, tool=cur)
    assert "clearance" in d.reasons
    assert f.counts["clearance"] >= 3


def test_hold_and_limits_from_env(settings):
    f = SafetyFilter(_limits())
    cur = np.array([[0.25, 0.1, 0.5], [0.25, -0.1, 0.5]], np.float32)
    d = f.filter(cur, np.full((2, 3), np.nan), _parallel_arms(0.6))
    assert d.stopped and d.reasons == ["malformed"]
    np.testing.assert_array_equal(d.target, cur)
    tool = cur + 0.01
    d = f.hold(cur, measured_tool=tool)
    assert d.stopped
    np.testing.assert_allclose(d.target, tool)
    lim = SafetyLimits.from_env(settings)
    assert lim.deadline_s == pytest.approx(0.04)
    assert lim.max_step == pytest.approx(math.sqrt(3) * 0.05)
    assert lim.min_clearance == settings["arm_clearance"]
    lim = SafetyLimits.from_env(settings, max_speed=0.5, margin=0.01, min_clearance=0.05)
    assert lim.max_step == pytest.approx(0.02)
    np.testing.assert_allclose(lim.workspace_low, np.asarray(settings["workspace_low"]) + 0.01)
    with pytest.raises(ValueError):
        SafetyLimits.from_env(settings, margin=1.0)


# -- real-robot conventions ----------------------------------------------------------------------

def test_frames():
    for arm in ("l", "r"):
        np.testing.assert_allclose(robot.base_to_world(arm, [0, 0, 0]), ur3.BASE_POS[arm])
        # yaw = pi: the base x axis points along world -x, base y along world -y
        np.testing.assert_allclose(robot.base_to_world(arm, [1, 0, 0]),
                                   ur3.BASE_POS[arm] + [-1, 0, 0], atol=1e-12)
        np.testing.assert_allclose(robot.vector_base_to_world(arm, [0, 1, 0]), [0, -1, 0],
                                   atol=1e-12)
        p = np.random.default_rng(0).normal(size=(10, 3))
        np.testing.assert_allclose(robot.world_to_base(arm, robot.base_to_world(arm, p)), p,
                                   atol=1e-12)
        np.testing.assert_allclose(robot.base_from_world(arm) @ robot.world_from_base(arm),
                                   np.eye(4), atol=1e-12)
        q = np.random.default_rng(1).uniform(-np.pi, np.pi, 6)
        np.testing.assert_allclose(
            robot.base_to_world(arm, ur3.forward_kinematics(q)[:3, 3]),
            ur3.forward_kinematics(q, base=ur3.base_transform(arm))[:3, 3], atol=1e-12)
    assert robot._arm(0) == "l" and robot._arm("right") == "r"
    with pytest.raises(ValueError):
        robot._arm(2)


def test_sim_home_pose_matches_dh_in_base_frames(settings):
    """The simulator's tool points at home = UR DH forward kinematics of the home joint angles,
    mapped with the base transforms: getl() positions convert with base_to_world."""
    env = NumpyDualArmEnv(settings)
    res = env.reset(goal=np.zeros((2, 3)))
    m = env.model
    for i, arm in enumerate("lr"):
        q = [env.home_qpos[m.jnt_qposadr[m.joint(f"{arm}_j{k + 1}").id]] for k in range(6)]
        tcp_base = ur3.forward_kinematics(np.asarray(q, float))[:3, 3]
        np.testing.assert_allclose(robot.base_to_world(arm, tcp_base), res.achieved_goal[i],
                                   atol=2e-3)


def test_tool_orientation_and_commands():
    R_world = robot.quat_to_matrix(robot.TOOL_DOWN_QUAT_WORLD)
    np.testing.assert_allclose(R_world[:, 2], [0, 0, -1], atol=1e-8)  # tool z points down
    for arm in ("l", "r"):
        r = robot.tool_down_rotvec(arm)
        R_base = robot.rotvec_to_matrix(r)
        np.testing.assert_allclose(robot.world_from_base(arm)[:3, :3] @ R_base, R_world, atol=1e-8)
        np.testing.assert_allclose(robot.matrix_to_rotvec(robot.rotvec_to_matrix(r)), r, atol=1e-8)
    a = np.array([1, 0, -0.5, -1, 0, -2, 0, 1], float)
    d = robot.cartesian_deltas_world(a, 0.05)
    np.testing.assert_allclose(d, [[0.05, 0, -0.025], [0, -0.05, 0]])
    np.testing.assert_allclose(robot.vector_world_to_base("l", d[0]), [-0.05, 0, -0.025],
                               atol=1e-12)
    np.testing.assert_allclose(robot.finger_openings(a, 0.04), [0.0, 0.04])
    np.testing.assert_allclose(robot.finger_openings(np.zeros(8), 0.04), [0.02, 0.02])
    np.testing.assert_allclose(robot.finger_openings(a, 0.04, lock_fingers=True), [0.0, 0.0])
    pose = np.zeros((2, 6))
    pose[:, :3] = [[-0.25, 0.1, 0.15], [-0.25, -0.1, 0.15]]
    cmd, world = robot.servol_targets(a, pose, 0.05)
    start = np.stack([robot.base_to_world(i, pose[i, :3]) for i in range(2)])
    np.testing.assert_allclose(world - start, d, atol=1e-12)
    np.testing.assert_allclose(cmd[0, :3], pose[0, :3] + [-0.05, 0, -0.025], atol=1e-12)
    np.testing.assert_allclose(cmd[:, 3:], [robot.tool_down_rotvec(0), robot.tool_down_rotvec(1)])
    for bad in (np.zeros(7), np.full(8, np.nan)):
        with pytest.raises(ValueError):
            robot.split_action(bad)


def test_control_period(jenv, settings):
    assert robot.CONTROL_PERIOD_S == pytest.approx(jenv.dt) == pytest.approx(0.04)
    assert robot.control_period(settings) == pytest.approx(jenv.dt)
    assert robot.control_period() == 0.04


# -- the client loop against a served policy ----------------------------------------------------

@pytest.fixture(scope="module")
def tiny_served(jenv, tmp_path_factory):
    """An untrained tiny daddpg policy behind the service, and the JAX functions it came from."""
    cfg = TrainConfig(hidden=(16, 16), num_envs=2, n_cycles=1, n_batches=1, batch_size=8,
                      buffer_size=200, n_test_episodes=2, seed=5)
    fns = make_train_fns(jenv, cfg)
    state = fns.init(jax.random.PRNGKey(5))
    path = export_state(state, cfg, jenv, str(tmp_path_factory.mktemp("tiny") / "tiny.npz"))
    srv = PolicyServer(NumpyPolicy.load(path), port=0).start()
    yield srv, fns, state, path
    srv.stop()


def test_client_loop_matches_trainer_rollout(tiny_served, jenv, settings, jax_step):
    """End to end (fast): service + safety layer + NumPy env reproduce the trainer's own
    deterministic rollout of the same policy and goal."""
    srv, fns, state, _ = tiny_served
    step, reset = jax_step
    s = reset(jax.random.PRNGKey(42))
    for _ in range(jenv.episode_length):
        s = step(s, fns.act(state, s.obs["observation"], s.obs["desired_goal"]))
    client = PolicyClient(srv.url, timeout=5.0)
    safety = SafetyFilter(SafetyLimits.from_env(settings, min_clearance=NO_CLEARANCE_RULE,
                                                deadline_s=5.0))
    env = NumpyDualArmEnv(settings)
    out = robot.run_episode(env, client, safety, goal=np.asarray(s.obs["desired_goal"]))
    assert out["stops"] == 0 and not out["errors"]
    final = env._result()
    np.testing.assert_allclose(final.achieved_goal, np.asarray(s.obs["achieved_goal"]), atol=1e-4)
    assert out["success"] == bool(s.metrics["success"])
    assert srv.stats["requests"] >= jenv.episode_length
    summary = robot.run_episodes(env, client, safety, episodes=2, seed=3)
    assert summary["episodes"] == 2 and 0.0 <= summary["success_rate"] <= 1.0
    assert summary["stops"] == 0
    client.close()


@pytest.fixture(scope="module")
def fast_limits(tmp_path_factory):
    """--limits and --fast for the client commands: the simulator's limits with a 2 s deadline
    and observation age (allowed unpaced), so that a loaded machine does not turn answers into
    missed deadlines."""
    import tomllib

    from daddpg_jax.deploy.limits import SHIPPED

    with open(os.path.join(SHIPPED, "sim.toml"), "rb") as f:
        d = tomllib.load(f)
    path = tmp_path_factory.mktemp("limits") / "sim_2s.json"
    path.write_text(json.dumps({**d, "deadline": 2.0, "max_observation_age": 2.0}))
    return ["--limits", str(path), "--fast"]


def test_robot_client_cli(tiny_served, tmp_path, fast_limits):
    srv = tiny_served[0]
    script = os.path.join(ROOT, "experiments", "robot_client.py")
    env = dict(os.environ, JAX_PLATFORMS="cpu")

    def client(*args):
        return subprocess.run([sys.executable, script, "--server", srv.url, *fast_limits, *args],
                              capture_output=True, text=True, timeout=120, cwd=ROOT, env=env)

    out_json = tmp_path / "client.json"
    r = client("--task", "reach", "--episodes", "2", "--seed", "1", "--json", str(out_json))
    assert r.returncode == 0, r.stderr
    res = json.loads(out_json.read_text())
    assert res["episodes"] == 2 and res["task"] == "reach" and res["stops"] == 0
    assert res["excluded_episodes"] == 0 and res["aborted"] is None and res["outages"] == 0
    assert "policy service outage" not in r.stderr
    r = client("--episodes", "1")  # the task from GET /info
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["task"] == "reach"
    r = client("--task", "push", "--episodes", "1")
    assert r.returncode != 0 and "serves a 'reach' policy" in r.stderr
    r = subprocess.run([sys.executable, script, "--server", "http://127.0.0.1:1"],
                       capture_output=True, text=True, timeout=120, cwd=ROOT, env=env)
    assert r.returncode == 2 and "not reachable" in r.stderr and "Traceback" not in r.stderr


class _StubClient:
    def __init__(self, answer, delay=0.0):
        self.answer, self.delay = answer, delay

    def act(self, observation, desired_goal):
        if self.delay:
            time.sleep(self.delay)
        return self.answer, {}


def test_stop_when_service_is_down_late_or_malformed(settings):
    env = NumpyDualArmEnv(settings)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    home = env.reset(goal=np.zeros((2, 3))).achieved_goal
    cases = [(PolicyClient(f"http://127.0.0.1:{port}", timeout=0.2), None, "stop"),
             (_StubClient([1.0] * 8, delay=0.01), 0.002, "late"),
             (_StubClient([1.0] * 7), None, "stop"),
             (_StubClient([float("nan")] * 8), None, "stop"),
             (_StubClient(None), None, "stop")]
    for client, deadline, reason in cases:
        safety = SafetyFilter(SafetyLimits.from_env(settings, deadline_s=deadline))
        out = robot.run_episode(env, client, safety, goal=np.zeros((2, 3)), deadline_s=deadline)
        assert out["stops"] == env.episode_length, reason
        assert safety.counts[reason] == env.episode_length
        # holding: the grippers stay where they were
        np.testing.assert_allclose(env._result().achieved_goal, home, atol=5e-3)
    # a good answer in time moves the arms
    safety = SafetyFilter(SafetyLimits.from_env(settings, deadline_s=1.0))
    out = robot.run_episode(env, _StubClient([1.0, 0, 0, 0] * 2), safety, goal=np.zeros((2, 3)))
    assert out["stops"] == 0
    assert np.all(env._result().achieved_goal[:, 0] > home[:, 0] + 0.05)


# -- outages of the policy service ------------------------------------------------------------

class _FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_outage_monitor_counts_and_limits():
    clock, lines = _FakeClock(), []
    m = robot.OutageMonitor(max_missed=3, max_outage_s=10.0, report=lines.append, clock=clock)
    m.answered()
    for _ in range(2):  # a short outage: one line when it starts, one when it ends
        m.missed_deadline("down", sent_at=clock.t, where="episode 1, step 1")
        clock.t += 0.04
    m.answered()
    assert len(lines) == 2 and lines[0].startswith("policy service outage at episode 1, step 1")
    assert "answering again after 2 missed" in lines[1]
    assert (m.outages, m.total_missed, m.missed) == (1, 2, 0)
    m.missed_deadline("down", sent_at=clock.t)
    m.missed_deadline("down")
    with pytest.raises(robot.ServiceOutage, match="3 consecutive missed deadlines") as e:
        m.missed_deadline("refused")  # the count limit
    assert e.value.missed == 3 and e.value.last_error == "refused"
    assert len(lines) == 3 and m.outages == 2
    # the time limit, from when the first failed request was sent
    clock, lines = _FakeClock(), []
    m = robot.OutageMonitor(max_missed=1000, max_outage_s=1.0, report=lines.append, clock=clock)
    start = clock.t
    clock.t += 0.25
    m.missed_deadline("timeout", sent_at=start)
    for _ in range(2):
        clock.t += 0.25
        m.missed_deadline("timeout")
    clock.t += 0.25
    with pytest.raises(robot.ServiceOutage) as e:
        m.missed_deadline("timeout")
    assert e.value.outage_s == pytest.approx(1.0) and e.value.missed == 4 and len(lines) == 1
    # limits off: never gives up; silent without a report callable
    m = robot.OutageMonitor(max_missed=0, max_outage_s=None, clock=clock)
    for _ in range(500):
        clock.t += 1.0
        m.missed_deadline("down")
    assert m.total_missed == 500 and m.limits_text() == "none"


def _ep(stops, success, dist=0.1):
    return dict(success=success, final_distance=[dist, dist], stops=stops, errors=["x"] * stops,
                min_arm_clearance=0.05, rtt_ms_p50=1.0, rtt_ms_max=2.0)


def test_summary_excludes_episodes_with_missed_deadlines():
    eps = [_ep(0, True), _ep(3, True), _ep(0, False, 0.3), _ep(50, True), _ep(0, True)]
    s = robot.summarize_episodes(eps)
    assert (s["episodes"], s["episodes_run"], s["excluded_episodes"]) == (3, 5, 2)
    assert s["success_rate"] == pytest.approx(2 / 3)  # not 4/5: excluded successes don't count
    assert s["mean_final_distance"] == pytest.approx((0.1 + 0.3 + 0.1) / 3)
    assert s["stops"] == 53 and s["aborted"] is None
    s = robot.summarize_episodes([_ep(1, True)], aborted={"episode": 1})
    assert s["episodes"] == 0 and s["success_rate"] is None and s["mean_final_distance"] is None
    assert s["excluded_episodes"] == 1


class _FlakyClient:
    """Answers a fixed action, except on the calls in ``down`` (0-based) or from ``dead_from``."""

    def __init__(self, down=(), dead_from=None):
        self.down, self.dead_from, self.calls = set(down), dead_from, 0

    def act(self, observation, desired_goal):
        k, self.calls = self.calls, self.calls + 1
        if k in self.down or (self.dead_from is not None and k >= self.dead_from):
            return None, {"error": "ConnectionRefusedError: down"}
        return [0.1, 0.0, 0.0, 0.0] * 2, {}


def test_run_episodes_excludes_outage_episodes_and_aborts(settings):
    env = NumpyDualArmEnv(settings)
    L = env.episode_length
    lines = []
    safety = SafetyFilter(SafetyLimits.from_env(settings, deadline_s=5.0))
    # a short outage in episode 2: reported once, episode 2 excluded, the run goes on
    mon = robot.OutageMonitor(max_missed=10, report=lines.append)
    out = robot.run_episodes(env, _FlakyClient(down=range(L + 5, L + 9)), safety, 3, monitor=mon)
    assert out["aborted"] is None and out["outages"] == 1 and out["stops"] == 4
    assert (out["episodes"], out["episodes_run"], out["excluded_episodes"]) == (2, 3, 1)
    assert len(lines) == 2 and "episode 2, step 6" in lines[0]
    # the service dies in episode 3: abort after 10 missed deadlines, in episode 4
    lines.clear()
    mon = robot.OutageMonitor(max_missed=10, report=lines.append)
    client = _FlakyClient(dead_from=3 * L - 4)
    out = robot.run_episodes(env, client, safety, 400, monitor=mon)
    assert out["aborted"]["episode"] == 4 and out["aborted"]["missed"] == 10
    assert (out["episodes"], out["episodes_run"], out["excluded_episodes"]) == (2, 4, 2)
    assert client.calls == 3 * L + 6 and len(lines) == 1
    assert "10 consecutive missed deadlines" in out["aborted"]["reason"]


SERVE = os.path.join(ROOT, "experiments", "serve.py")
CLIENT = os.path.join(ROOT, "experiments", "robot_client.py")


def _start_service(path):
    proc = subprocess.Popen([sys.executable, SERVE, path, "--port", "0"], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=dict(os.environ, JAX_PLATFORMS="cpu"))
    m = re.search(r" on (http://\S+) \(", proc.stdout.readline())
    assert m, proc.stderr.read()
    return proc, m.group(1)


def _client_against(path, after_requests, fault, *args, limits=()):
    """Starts a service in a subprocess and the robot client (400 episodes) against it; once the
    service has answered ``after_requests`` requests, applies ``fault`` to the service process.
    Returns (client's CompletedProcess-like result, seconds from the fault to the client's exit)."""
    srv, url = _start_service(path)
    cl = None
    try:
        cl = subprocess.Popen([sys.executable, CLIENT, "--server", url, "--episodes", "400",
                               *limits, *args], cwd=ROOT, text=True, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, env=dict(os.environ, JAX_PLATFORMS="cpu"))
        probe, polls = PolicyClient(url, timeout=5.0), 0
        deadline = time.monotonic() + 60
        while probe.health()["requests"] - polls < after_requests:
            polls += 1
            assert time.monotonic() < deadline and cl.poll() is None
            time.sleep(0.02)
        probe.close()
        fault(srv)
        t_fault = time.perf_counter()
        out, err = cl.communicate(timeout=60)
        return subprocess.CompletedProcess(cl.args, cl.returncode, out, err), \
            time.perf_counter() - t_fault
    finally:
        for p in (cl, srv):
            if p is not None and p.poll() is None:
                if p is srv:
                    p.send_signal(signal.SIGCONT)
                p.kill()
                p.wait()


def _check_aborted(r, n_lines=2):
    assert r.returncode == 3, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    # the limits at start and the human-readable summary besides the outage lines
    lines = [ln for ln in r.stderr.strip().splitlines()
             if ln.startswith(("policy service", "error:"))]
    assert r.stderr.startswith("limits (") and "\nsuccess: " in r.stderr
    assert len(lines) == n_lines, lines
    assert lines[0].startswith("policy service outage at episode")  # when it started
    assert lines[-1].startswith("error: policy service outage: ") and "aborted in episode" in \
        lines[-1]
    out = json.loads(r.stdout)
    assert out["aborted"] and out["aborted"]["episode"] == out["episodes_run"]
    assert out["episodes"] >= 3 and out["excluded_episodes"] >= 1
    assert out["episodes"] + out["excluded_episodes"] == out["episodes_run"] < 400
    assert out["stops"] == out["aborted"]["missed"] and out["outages"] == 1
    n_success = out["success_rate"] * out["episodes"]
    assert abs(n_success - round(n_success)) < 1e-9  # a rate over the counted episodes
    return out


def test_robot_client_aborts_when_service_is_killed(tiny_served, fast_limits):
    """The service process is killed after 3 episodes: exit code 3, the outage reported when it
    starts and the abort in one line each, no traceback, the interrupted episodes not counted."""
    path, n = tiny_served[3], 50
    r, after = _client_against(path, 3 * n + 3, lambda p: p.kill(), limits=fast_limits)
    out = _check_aborted(r)
    assert "50 consecutive missed deadlines" in out["aborted"]["reason"]
    print(f"\n[measured] service killed: client exit code 3 {after:.2f} s after the kill "
          f"(outage {out['aborted']['outage_s']:.3f} s, {out['aborted']['missed']} missed "
          f"deadlines; {out['episodes']} episodes counted, {out['excluded_episodes']} excluded)")


def test_robot_client_aborts_when_service_hangs(tiny_served, fast_limits):
    """A frozen service (SIGSTOP: connections accepted, never answered): the time limit."""
    path, n = tiny_served[3], 50
    r, after = _client_against(path, 3 * n + 3, lambda p: p.send_signal(signal.SIGSTOP),
                               "--deadline-ms", "400", "--max-outage-s", "0.8",
                               "--max-missed", "1000", limits=fast_limits)
    out = _check_aborted(r)
    assert 0.8 <= out["aborted"]["outage_s"] < 1.6
    assert 2 <= out["aborted"]["missed"] <= 3 and "timed out" in out["aborted"]["last_error"]
    print(f"\n[measured] service frozen: client exit code 3 {after:.2f} s after SIGSTOP "
          f"(outage {out['aborted']['outage_s']:.3f} s, {out['aborted']['missed']} missed "
          f"deadlines of 400 ms)")


# -- slow: a trained reach policy, served, against the trainer's own evaluation ----------------

@pytest.mark.slow
def test_sim_to_sim_success_matches_trainer_eval(tmp_path):
    from daddpg_jax.running.runner import train
    from tests.conftest import run_options

    n = 200
    cfg = TrainConfig(**{**preset("reach"), "n_epochs": 2}, seed=0, n_test_episodes=n, physics="c")
    run = str(tmp_path / "reach")
    res = train(cfg, run_options(run))
    trainer = res.test_success_rate
    policy = NumpyPolicy.load(export_run(run, str(tmp_path / "reach.npz")))
    srv = PolicyServer(policy, port=0).start()
    try:
        env = NumpyDualArmEnv(policy.env)
        client = PolicyClient(srv.url, timeout=5.0)
        # speed cap, workspace clamp and deadline on; the arm-clearance rule off (the trainer's
        # evaluation has no such rule: reach is trained without an arm-contact penalty)
        safety = SafetyFilter(SafetyLimits.from_env(policy.env, min_clearance=NO_CLEARANCE_RULE,
                                                    deadline_s=2.0))
        plain = robot.run_episodes(env, client, safety, episodes=n, seed=0)
        guarded_safety = SafetyFilter(SafetyLimits.from_env(policy.env, deadline_s=2.0))
        guarded = robot.run_episodes(env, client, guarded_safety, episodes=n, seed=0)
    finally:
        srv.stop()
    print(f"trainer eval {trainer:.3f}; client {plain['success_rate']:.3f}; client with the "
          f"clearance rule {guarded['success_rate']:.3f} (min gap "
          f"{guarded['min_arm_clearance']:.4f} vs {plain['min_arm_clearance']:.4f} m)")
    assert trainer >= 0.6
    assert abs(plain["success_rate"] - trainer) <= 0.10
    assert plain["stops"] == 0
    assert guarded["min_arm_clearance"] >= plain["min_arm_clearance"]
