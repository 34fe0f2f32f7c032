"""The safety invariant as a property (Hypothesis): whatever the service answers (valid, NaN,
garbage, missing, late), whatever valid limits file the robot holds (boxes that do not hold
the start pose, tiny boxes, low speed caps, narrow finger ranges, a calibration within the
accepted range) and whatever the arms' readings and drivers do (frozen clocks, slow reads,
servoL returning False or raising, a gripper raising), the client's loop sends no command
outside the box, no step over the cap, no start move faster than the cap or from or to outside
the box, no finger command outside its range (checked by the independent recorder,
tests/arm_recorder.py, with its own arithmetic); no exception escapes; every run ends in
bounded time (a fake clock: the episode length bounds the periods).

Default tier: >= 500 generated control periods (~5 s); slow tier: >= 20,000 (~3 min). The
count and the seed are printed (docs/RELIABILITY.md quotes them)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from daddpg_jax.deploy import robot
from daddpg_jax.deploy.arm_frames import base_transform
from daddpg_jax.deploy.limits import RobotLimits
from daddpg_jax.deploy.robot_session import ENDS_RUN
from daddpg_jax.deploy.safety import SafetyFilter
from daddpg_jax.deploy.ursim import SimGripper, SimRTDEControl, sim_env, sim_ur_env
from mjx_envs.numpy_env import NumpyDualArmEnv
from tests.arm_recorder import ArmRecorder, Expected, install

SEED = 20261205
SIM_LOW = np.array([[0.12, -0.14, 0.41], [0.12, -0.36, 0.41]])
SIM_HIGH = np.array([[0.40, 0.36, 0.65], [0.40, 0.14, 0.65]])
START = np.array([[0.25, 0.15, 0.55], [0.25, -0.15, 0.55]])
"""the reach task's start pose (its tool centres, world), for boxes that hold it"""
NOMINAL = {0: ((0.0, 0.25, 0.40), math.pi), 1: ((0.0, -0.25, 0.40), math.pi)}
ANSWERS = ("valid", "valid", "valid", "valid", "nan", "garbage", "missing", "late", "short",
           "huge")
FAULTS = ("none", "frozen", "slow", "false", "raise", "grip")


class FakeClock:
    """Monotonic seconds that advance 20 µs per reading, plus what a fault or a late answer
    adds (a read of both UR arms takes some 30 readings)."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        self.now += 2e-5
        return self.now


@st.composite
def limits_files(draw):
    """A valid limits file (as a dict): per arm a box anywhere around the simulator's (tiny to
    full, holding the start pose or not), a speed cap from 1 cm/s, a clearance, a finger range,
    a calibration within a few mm and a fraction of a degree of the nominal bases."""
    d = {"control_period": 0.04, "deadline": 0.03, "max_observation_age": 0.08,
         "max_speed": draw(st.floats(0.01, 2.17)), "min_clearance": draw(st.floats(0.0, 0.1))}
    fmin = draw(st.floats(0.0, 0.03))
    d["finger_min"], d["finger_max"] = fmin, draw(st.floats(fmin, 0.04))
    holds_start = draw(st.integers(0, 9)) > 0  # mostly boxes that hold the start pose
    for i, arm in enumerate(("left", "right")):
        if holds_start:
            low = START[i] - [draw(st.floats(0.003, 0.2)) for _ in range(3)]
            high = START[i] + [draw(st.floats(0.003, 0.2)) for _ in range(3)]
        else:
            centre = np.array([draw(st.floats(SIM_LOW[i, k], SIM_HIGH[i, k]))
                               for k in range(3)])
            half = np.array([draw(st.floats(0.003, 0.2)) for _ in range(3)])
            low, high = centre - half, centre + half
        d[arm] = {"workspace_low": low.round(4).tolist(), "workspace_high": high.round(4).tolist()}
    d["calibration"] = {}
    for i, arm in enumerate(("left", "right")):
        pos, yaw = NOMINAL[i]
        off = [draw(st.floats(-0.003, 0.003)) for _ in range(3)]
        dyaw = draw(st.floats(-0.005, 0.005))
        T = base_transform(np.add(pos, off), yaw + dyaw)
        from daddpg_jax.deploy.robot import matrix_to_rotvec

        d["calibration"][arm] = {"base_pos": T[:3, 3].tolist(),
                                 "base_rotvec": matrix_to_rotvec(T[:3, :3]).tolist(),
                                 "residuals_mm": [0.5] * 6, "rms_mm": 0.5}
    return d


@st.composite
def runs(draw):
    return dict(limits=draw(limits_files()), kind=draw(st.sampled_from(("sim", "ur-sim"))),
                speed_scale=draw(st.floats(0.05, 1.0)),
                answers=draw(st.lists(st.sampled_from(ANSWERS), min_size=50, max_size=50)),
                fault=draw(st.sampled_from(FAULTS)), fault_step=draw(st.integers(0, 49)),
                fault_steps=draw(st.integers(1, 30)),
                actions=np.random.default_rng(draw(st.integers(0, 2**31))).uniform(
                    -1.5, 1.5, (50, 8)).round(4).tolist(),
                goal_seed=draw(st.integers(0, 2**31)))


class _Service:
    """Answers of the generated kinds; ``late`` advances the fake clock past the deadline."""

    def __init__(self, run, clock):
        self.run, self.clock, self.n = run, clock, 0

    def act(self, obs, goal):
        k = self.n % 50
        self.n += 1
        kind, a = self.run["answers"][k], self.run["actions"][k]
        if kind == "late":
            self.clock.now += 0.05
            return a, {}
        return {"valid": (a, {}), "nan": ([float("nan")] * 8, {}),
                "garbage": ("garbage", {}), "missing": (None, {"error": "no answer"}),
                "short": (a[:7], {}), "huge": ([10**400] * 8, {})}[kind]


class _Faults:
    """Driver faults of the generated kinds on the simulated UR controllers, at period k."""

    def __init__(self, run, clock, env):
        self.run, self.clock, self.k = run, clock, 0
        ur = env.arms.arms
        self.stamps = [0.0, 0.0]
        for i, r in enumerate(ur.receives):
            r.getTimestamp = self._stamp(i)
            pose = r.getActualTCPPose
            r.getActualTCPPose = (lambda pose=pose: self._slow() or pose())

    def fault(self):
        """The fault of the current period: frozen and slow last ``fault_steps`` periods from
        ``fault_step``; False, raise and a gripper error come once, at ``fault_step``."""
        run, k = self.run, self.k
        lasting = run["fault"] in ("frozen", "slow")
        if k == run["fault_step"] or (lasting and 0 <= k - run["fault_step"] < run["fault_steps"]):
            return run["fault"]
        return "none"

    def _stamp(self, i):
        def stamp():
            if self.fault() != "frozen":
                self.stamps[i] = self.clock.now
            return self.stamps[i]
        return stamp

    def _slow(self):
        if self.fault() == "slow":
            self.clock.now += 0.05


def _make_env(run, clock, safety, bases):
    spec = NumpyDualArmEnv(task="reach")
    if run["kind"] == "sim":
        env = sim_env(spec, NumpyDualArmEnv(task="reach"), bases=bases, safety=safety)
        env.arms.arms.clock = env.arms.arms.wall = clock
    else:
        env = sim_ur_env(spec, NumpyDualArmEnv(task="reach"), 0.04, bases=bases, safety=safety,
                         watchdog=1e9)
        ur = env.arms.arms
        ur.clock = ur.guard.clock = clock
        for c in ur.controls:
            c.wall = clock
    env.clock = clock
    return env


PERIODS = [0]


def _check(run, monkeypatch_cls, recorder):
    clock = FakeClock()
    limits = RobotLimits.from_dict(run["limits"], source="generated")
    safety = limits.safety_limits(run["speed_scale"])
    recorder.expected = Expected(run["limits"], speed_scale=run["speed_scale"])
    recorder.violations.clear()
    recorder.commands = 0
    env = _make_env(run, clock, safety, limits.base_transforms())
    faults = _Faults(run, clock, env) if run["kind"] == "ur-sim" else None
    state = {"k": 0}
    if faults is not None:
        def servo(self, *a, _orig=monkeypatch_cls["servoL"]):
            f = faults.fault()
            if f == "false" and self.arm == 0:
                return False
            if f == "raise" and self.arm == 1:
                raise RuntimeError("RTDE: connection reset")
            faults.k = state["k"] = state["k"] + (self.arm == 1)
            return _orig(self, *a)

        def grip(self, opening, _orig=monkeypatch_cls["move"]):
            if faults.fault() == "grip":
                raise OSError("gripper socket closed")
            return _orig(self, opening)

        monkeypatch_cls["set"](SimRTDEControl, "servoL", servo)
        monkeypatch_cls["set"](SimGripper, "move", grip)
    service = _Service(run, clock)
    monitor = robot.OutageMonitor(max_missed=20, max_outage_s=2.0, clock=clock)
    out = robot.run_episodes(env, service, SafetyFilter(safety), 1, seed=run["goal_seed"],
                             monitor=monitor, max_observation_age=limits.max_observation_age,
                             max_reading_gap=limits.max_reading_gap, ends_run=ENDS_RUN)
    env.close()
    assert not recorder.violations, recorder.violations[:3]
    assert service.n <= 50 and clock.now < 60.0
    if out["aborted"] and out["aborted"]["kind"] == "GateRefusal":
        assert recorder.commands == 0  # nothing moved
    PERIODS[0] += service.n + out["stops"]
    return out


def _seed_alone_decides(monkeypatch) -> bool:
    """Hypothesis draws some 5-15 % of its integers and floats from a pool of constants that
    it reads out of the source of every local module in sys.modules at that moment
    (hypothesis/internal/conjecture/providers.py, ``_get_local_constants``): with the same
    seed, what the process imported before changed the generated runs (12 runs of SEED made
    597 periods alone, 639 after mjx_envs.tasks.scripted, 494 in a CI worker). For the
    property tests here the pool is empty and its cache fresh, so the seed alone decides (624
    periods with Hypothesis 6.170). False, and nothing patched, where a Hypothesis version
    lacks those internals (the default tier's seed loop then still reaches its count)."""
    try:
        from hypothesis.internal.cache import LRUCache
        from hypothesis.internal.conjecture import providers
        from hypothesis.internal.constants_ast import Constants
    except ImportError:
        return False
    if not all(hasattr(providers, k) for k in ("_get_local_constants", "CONSTANTS_CACHE")):
        return False
    none = Constants()
    monkeypatch.setattr(providers, "_get_local_constants", lambda: none)
    monkeypatch.setattr(providers, "CONSTANTS_CACHE", LRUCache(1024))
    return True


def _property(monkeypatch, examples: int, at: int = SEED):
    _seed_alone_decides(monkeypatch)
    recorder = ArmRecorder()
    install(monkeypatch, recorder)
    originals = {"servoL": SimRTDEControl.servoL, "move": SimGripper.move,
                 "set": monkeypatch.setattr}

    @seed(at)
    @settings(max_examples=examples, deadline=None, derandomize=False, database=None,
              suppress_health_check=list(HealthCheck))
    @given(runs())
    def prop(run):
        monkeypatch.setattr(SimRTDEControl, "servoL", originals["servoL"])
        monkeypatch.setattr(SimGripper, "move", originals["move"])
        _check(run, originals, recorder)

    PERIODS[0] = 0
    prop()
    return PERIODS[0]


def test_no_command_leaves_the_limits_whatever_the_service_files_and_arms_do(monkeypatch):
    """~5 s: >= 500 generated control periods: 12 runs of seed SEED (624 periods whatever the
    process imported before: `_seed_alone_decides`), and 12 more of the next seed while fewer
    (a Hypothesis version that draws other runs from the same seed)."""
    periods, seeds = 0, []
    for at in range(SEED, SEED + 4):
        periods += _property(monkeypatch, 12, at)
        seeds.append(at)
        if periods >= 500:
            break
    print(f"generated control periods: {periods} (seeds {seeds})")
    assert periods >= 500


@pytest.mark.slow
def test_no_command_leaves_the_limits_long(monkeypatch):
    """~3 min: >= 20,000 generated control periods (seed SEED)."""
    periods = _property(monkeypatch, 400)
    print(f"generated control periods: {periods} (seed {SEED})")
    assert periods >= 20_000
