"""The paced control loop: one step per control period on a monotonic clock with overruns
counted, observations older than the limit held like a missed deadline, a per-episode log that
replays in the simulator, and the human-readable summary.

In-process (the NumPy simulator, a policy service in a thread, the checked-in export
tests/data/legacy_reach/policy.npz; no JAX): ~4 s."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from daddpg_jax.cli import robot_client
from daddpg_jax.deploy import NumpyPolicy, robot
from daddpg_jax.deploy.client import PolicyClient
from daddpg_jax.deploy.limits import SHIPPED, RobotLimits
from daddpg_jax.deploy.safety import SafetyFilter
from daddpg_jax.deploy.server import PolicyServer
from mjx_envs.numpy_env import NumpyDualArmEnv

pytestmark = pytest.mark.usefixtures("arm_recorder")  # every command checked

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GOOD = os.path.join(ROOT, "tests", "data", "legacy_reach", "policy.npz")


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t

    def sleep(self, s):
        assert s > 0
        self.t += s


def test_pacer_runs_once_per_period_and_counts_overruns():
    clock = FakeClock()
    pacer = robot.Pacer(0.04, clock=clock, sleep=clock.sleep)
    starts = []
    for work in (0.01, 0.01, 0.05, 0.01, 0.039, 0.01, 0.2, 0.0):
        starts.append(pacer.wait())
        clock.t += work
    d = np.diff(starts)
    # on time: 40 ms apart; after an overrun the schedule restarts at once (no catching up)
    np.testing.assert_allclose(d, [0.04, 0.04, 0.05, 0.04, 0.04, 0.04, 0.2], atol=1e-9)
    assert pacer.overruns == 2 and pacer.longest_late_s == pytest.approx(0.16)
    pacer.restart()
    t = pacer.wait()
    assert t == clock.t  # a new episode starts now


@pytest.fixture(scope="module")
def served():
    policy = NumpyPolicy.load(GOOD)
    with PolicyServer(policy, port=0) as srv:
        yield srv, policy


class _OldObservations:
    """The simulator, with observations captured ``age`` seconds before the loop reads them
    (a driver that reports its sensors late)."""

    def __init__(self, env, age, clock):
        self._env, self._age, self._clock = env, age, clock

    def __getattr__(self, name):
        return getattr(self._env, name)

    def _stamp(self, res):
        res.captured_at = self._clock() - self._age
        return res

    def reset(self, **kw):
        return self._stamp(self._env.reset(**kw))

    def step_targets(self, target, ctrl):
        return self._stamp(self._env.step_targets(target, ctrl))


def test_stale_observations_hold_like_a_missed_deadline(served):
    """Observations captured 0.5 s before the loop reads them, with a 0.25 s age limit: every
    period holds; fresh ones (the positive control) never do."""
    import time

    srv, policy = served
    env = NumpyDualArmEnv(policy.env, task="reach")
    env.episode_length = 10
    lim = RobotLimits.load(os.path.join(SHIPPED, "sim.toml"))
    client = PolicyClient(srv.url, timeout=2.0)
    safety = SafetyFilter(lim.safety_limits())
    out = robot.run_episode(_OldObservations(env, 0.5, time.perf_counter), client, safety,
                            goal=np.zeros((2, 3)), deadline_s=2.0, max_observation_age=0.25)
    assert out["stops"] == 10 and out["stale"] == 10 and "stale observation" in out["errors"][0]
    assert safety.counts["stale"] == 10
    fresh = robot.run_episode(_OldObservations(env, 0.0, time.perf_counter), client,
                              SafetyFilter(lim.safety_limits()), goal=np.zeros((2, 3)),
                              deadline_s=2.0, max_observation_age=0.25)
    assert fresh["stops"] == 0 and fresh["stale"] == 0  # positive control
    client.close()


def test_episode_log_replays_in_the_simulator(served, tmp_path, capsys):
    """--log writes one JSON per episode; replaying its targets reproduces the episode."""
    srv, policy = served
    limits = tmp_path / "l.json"
    import tomllib

    with open(os.path.join(SHIPPED, "sim.toml"), "rb") as f:
        limits.write_text(json.dumps({**tomllib.load(f), "deadline": 2.0,
                                      "max_observation_age": 2.0}))
    logs = tmp_path / "logs"
    code = robot_client.main(["--server", srv.url, "--fast", "--episodes", "2", "--limits",
                              str(limits), "--log", str(logs), "--seed", "3"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    out = json.loads(cap.out)
    files = sorted(os.listdir(logs))
    assert files == ["episode_00001.json", "episode_00002.json"]
    env = NumpyDualArmEnv(policy.env, task="reach")
    for name in files:
        log = json.loads((logs / name).read_text())
        assert len(log["steps"]) == env.episode_length
        s0 = log["steps"][0]
        assert {"t", "obs_age_ms", "observation", "action", "target", "finger_ctrl",
                "reasons", "stopped", "rtt_ms", "server_ms"} <= set(s0)
        assert s0["server_ms"] >= 0 and s0["obs_age_ms"] >= s0["rtt_ms"] - 1e-3
        res = robot.replay_episode(env, log)
        np.testing.assert_allclose(res.goal_distance, log["summary"]["final_distance"],
                                   atol=1e-6)
    # the human-readable summary ends the output
    tail = cap.err.strip().splitlines()
    assert tail[-4].startswith("success: ") and "95% CI" in tail[-4]
    assert tail[-3].startswith("deadlines missed: 0")
    assert tail[-2].startswith("safety interventions")
    assert tail[-1].startswith("unpaced (--fast)")
    lo, hi = out["success_ci95"]
    assert 0.0 <= lo <= out["success_rate"] <= hi <= 1.0


def test_paced_cli_run(served, tmp_path, capsys):
    """Without --fast the loop runs at the control period: 1 episode of 50 steps takes about
    2 s; ~2.5 s."""
    srv, _ = served
    code = robot_client.main(["--server", srv.url, "--episodes", "1", "--limits",
                              os.path.join(SHIPPED, "sim.toml")])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    out = json.loads(cap.out)
    assert out["paced"] and out["control_period_ms"] == pytest.approx(40.0)
    assert 1.9 <= out["wall_s"] <= 4.0
    assert "paced at 40 ms" in cap.err


def test_wilson_interval():
    assert robot.wilson_interval(0, 10)[0] == 0.0
    lo, hi = robot.wilson_interval(50, 100)
    assert lo == pytest.approx(0.4038, abs=1e-3) and hi == pytest.approx(0.5962, abs=1e-3)
