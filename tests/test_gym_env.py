"""Gymnasium adapter (mjx_envs/gym_env.py): env checker, spaces, reward = compute_reward (also
batched, as HER calls it), 50-step truncation, seeding, registration, no JAX import, and the
same dynamics, rules and rewards as the trainer's C-engine env (the NumPy simulator it wraps,
mjx_envs.numpy_env, for every task)."""

import dataclasses
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
from gymnasium.utils.env_checker import check_env  # noqa: E402

import mjx_envs  # noqa: E402
import mjx_envs.gym_env as ge  # noqa: E402
from mjx_envs.numpy_env import NumpyDualArmEnv  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TASKS = ("reach", "push", "pickup", "pot")


@pytest.mark.parametrize("task", TASKS)
def test_env_checker_and_spaces(task):
    env = gym.make(ge.ENV_IDS[task])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded Box observations, as in the Fetch tasks
        check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=0)
    assert {k: v.shape for k, v in obs.items()} == {
        "observation": (50,), "achieved_goal": (6,), "desired_goal": (6,)}
    assert all(v.dtype == np.float32 for v in obs.values())
    assert env.action_space.shape == (8,)
    assert np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    assert "is_success" in info
    env.close()


@pytest.mark.parametrize("task", ["reach", "push"])
def test_reward_equals_compute_reward_and_truncation(task):
    # every reward term on: goal, team and the goal-independent arm-contact penalty
    env = ge.DualUR3GoalEnv(task, team_scale=0.5, arm_contact_penalty=0.25)
    obs, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    ags, dgs, infos, rewards = [], [], [], []
    for t in range(1, 51):
        obs, r, terminated, truncated, info = env.step(rng.uniform(-1, 1, 8).astype(np.float32))
        assert terminated is False
        assert truncated is (t == 50)
        assert r == float(env.compute_reward(obs["achieved_goal"], obs["desired_goal"], info))
        assert r == pytest.approx(float(np.sum(env.per_arm_reward(
            obs["achieved_goal"], obs["desired_goal"], info))))
        ags.append(obs["achieved_goal"]), dgs.append(obs["desired_goal"])
        infos.append(info), rewards.append(r)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(8, np.float32))
    ag, dg = np.stack(ags), np.stack(dgs)
    # HER tools: [batch, 6] goals and an array (or list) of info dicts
    batched = env.compute_reward(ag, dg, np.array(infos, dtype=object))
    assert batched.shape == (50,) and batched.dtype == np.float32
    np.testing.assert_array_equal(batched, np.asarray(rewards, np.float32))
    np.testing.assert_array_equal(env.compute_reward(ag, dg, infos), batched)
    # relabelled with the achieved goal: only the contact penalty remains
    pen = np.array([i["arm_contact_penalty"].sum() for i in infos], np.float32)
    np.testing.assert_array_equal(env.compute_reward(ag, ag, infos), pen)
    # SB3 passes empty dicts unless asked to copy infos: no penalty then
    no_info = env.compute_reward(ag, dg, [{} for _ in infos])
    np.testing.assert_array_equal(no_info, env.compute_reward(ag, dg, None))


def test_success_reward_zero_and_seeding():
    env = ge.DualUR3GoalEnv("reach")
    o1, _ = env.reset(seed=7)
    o2, _ = env.reset(seed=7)
    o3, _ = env.reset(seed=8)
    np.testing.assert_array_equal(o1["desired_goal"], o2["desired_goal"])
    assert not np.array_equal(o1["desired_goal"], o3["desired_goal"])
    # goal at the grippers' home positions: a zero action holds them there -> success, reward 0
    o, _ = env.reset(options={"goal": o1["achieved_goal"].reshape(2, 3)})
    o, r, _, _, info = env.step(np.zeros(8, np.float32))
    assert info["is_success"] == 1.0 and r == 0.0
    o, r, _, _, info = env.step(np.array([1, 0, 0, 0, 1, 0, 0, 0], np.float32))
    assert info["is_success"] == 0.0 and r == -2.0


def test_registered_ids_and_overrides():
    ids = mjx_envs.register_gymnasium_envs()
    assert ids == ["DualUR3Reach-v0", "DualUR3Push-v0", "DualUR3Pickup-v0", "DualUR3Pot-v0",
                   "DualUR3ReachDense-v0", "DualUR3PushDense-v0", "DualUR3PickupDense-v0",
                   "DualUR3PotDense-v0"]
    env = gym.make("DualUR3Reach-v0", arm_contact_penalty=0.1)
    assert env.unwrapped.arm_contact_penalty == np.float32(0.1)
    with pytest.raises(ValueError, match="unknown setting"):
        ge.DualUR3GoalEnv("reach", not_a_field=1)


def test_imports_no_jax():
    code = ("import sys, numpy as np, gymnasium as gym, mjx_envs.gym_env\n"
            "e = gym.make('DualUR3Pot-v0'); e.reset(seed=0); e.step(np.zeros(8, np.float32))\n"
            "assert 'jax' not in sys.modules, 'jax imported'\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]


@pytest.mark.parametrize("task", TASKS)
def test_numpy_sim_agrees_with_the_jax_c_engine_env(task):
    """The NumPy simulator (what the adapter wraps) and the trainer's C-engine env: the same
    reset for the same draws (rules), then the same observations (float32 rounding), achieved
    goals, success and per-arm rewards (every term on) over a few random actions."""
    import jax
    import jax.numpy as jnp

    import mjx_envs
    from mjx_envs.core import SAMPLER
    from tests.env_fixtures import RecordingSampler, ReplaySampler

    terms = dict(team_scale=0.5, arm_contact_penalty=0.25)
    jenv = mjx_envs.make(task, physics="c", **terms)
    sim = NumpyDualArmEnv(terms, task=task)
    assert sim.config == jenv.config
    key = jax.random.PRNGKey(4)
    st = jax.jit(jenv.reset)(key)
    rec = RecordingSampler(SAMPLER)
    jenv.rules.reset(jnp, rec, key)
    goal, qpos = sim.rules.reset(np, ReplaySampler(rec.draws), None)
    np.testing.assert_allclose(goal, np.asarray(st.obs["desired_goal"]), rtol=0, atol=1e-6)
    np.testing.assert_allclose(qpos, np.asarray(st.data.qpos), rtol=0, atol=1e-6)
    res = sim.reset(goal=np.asarray(st.obs["desired_goal"]), qpos=np.asarray(st.data.qpos))
    np.testing.assert_allclose(res.observation, np.asarray(st.obs["observation"]), atol=1e-5)
    step = jax.jit(jenv.step)
    rng = np.random.default_rng(2)
    for _ in range(5):
        a = rng.uniform(-1.2, 1.2, 8).astype(np.float32)
        st, res = step(st, a), sim.step(a)
        np.testing.assert_allclose(res.observation, np.asarray(st.obs["observation"]), atol=1e-5)
        np.testing.assert_allclose(res.achieved_goal, np.asarray(st.obs["achieved_goal"]),
                                   atol=1e-5)
        assert res.success == bool(st.metrics["success"])
        contact, info = sim.info_terms(res.arm_clearance)
        assert contact == float(st.metrics["arm_contact"])
        np.testing.assert_array_equal(
            sim.compute_reward(res.achieved_goal, res.desired_goal, info), np.asarray(st.reward))


def test_compute_reward_with_empty_or_partial_info():
    env = ge.DualUR3GoalEnv("reach", arm_contact_penalty=0.5)
    ag = np.zeros((3, 6), np.float32)
    dg = ag.copy()
    dg[0, 0] = 1.0  # left arm of transition 0 misses its goal
    pen = {"arm_contact_penalty": np.full(2, -0.5, np.float32)}
    base = env.compute_reward(ag, dg, None)
    np.testing.assert_array_equal(base, [-1.0, 0.0, 0.0])
    np.testing.assert_array_equal(env.compute_reward(ag, dg, {}), base)
    np.testing.assert_array_equal(env.compute_reward(ag[0], dg[0], {}), -1.0)
    np.testing.assert_array_equal(env.compute_reward(ag[0], dg[0], {"step": 3}), -1.0)
    # a term missing from some of the dicts counts as 0 for those transitions
    np.testing.assert_array_equal(env.compute_reward(ag, dg, [pen, {}, {"step": 1}]),
                                  [-2.0, 0.0, 0.0])
    np.testing.assert_array_equal(env.compute_reward(ag, dg, pen), [-2.0, -1.0, -1.0])


def test_settings_come_from_mjx_envs_settings():
    from mjx_envs import registry

    for task in TASKS:
        assert ge.task_config(task) == registry.default_config(task)
        assert ge.task_settings(task) == dataclasses.asdict(registry.default_config(task))
    s = ge.task_settings("push", max_delta=0.03)
    assert s["max_delta"] == 0.03 and s["target_radius"] == (0.06, 0.08)
    env = ge.DualUR3GoalEnv("pot", episode_length=20)
    assert env.episode_length == 20 and env.sim.config.scene == "scene_pot.xml"
    # the NumPy simulator: a dict (e.g. a policy export's env settings: lists, derived keys such
    # as dt) or a config overrides the task's settings
    sim = NumpyDualArmEnv({"max_delta": 0.02, "dt": 0.04,
                           "goal_low": [[0.2, -0.08, 0.43], [0.2, -0.3, 0.43]]})
    assert sim.config.max_delta == 0.02 and sim.config.goal_low[0] == (0.2, -0.08, 0.43)
    assert NumpyDualArmEnv(registry.task_config("pickup"), task="pickup").rules.has_object
    with pytest.raises(ValueError, match="object joint"):
        NumpyDualArmEnv({"scene": "scene_reach.xml"}, task="push")
    with pytest.raises(ValueError, match="unknown task"):
        NumpyDualArmEnv(task="juggle")


@pytest.mark.parametrize("task, over", [("push", {}), ("pickup", {}),
                                        ("push", {"action_history": 2})])
def test_same_trajectory_as_the_trainers_c_engine_env(task, over):
    """From the JAX env's initial state and goal, 8 random actions give the same observations
    (float32 rounding; with an action history, the same remembered actions) and per-step
    rewards as the trainer's C-engine env."""
    import jax

    import mjx_envs

    jenv = mjx_envs.make(task, physics="c", **over)
    st = jenv.reset(jax.random.PRNGKey(1))
    env = ge.DualUR3GoalEnv(task, **over)
    assert env.observation_space["observation"].shape == (2 * jenv.obs_size,)
    o, _ = env.reset(options=dict(qpos=np.asarray(st.data.qpos),
                                  goal=np.asarray(st.obs["desired_goal"])))
    np.testing.assert_allclose(o["observation"], np.asarray(st.obs["observation"]).ravel(),
                               atol=1e-5)
    step = jax.jit(jenv.step)
    rng = np.random.default_rng(2)
    for _ in range(8):
        a = rng.uniform(-1.2, 1.2, 8).astype(np.float32)   # out-of-range values are clipped
        st = step(st, a)
        o, r, _, _, _ = env.step(a)
        np.testing.assert_allclose(o["observation"], np.asarray(st.obs["observation"]).ravel(),
                                   atol=1e-5)
        np.testing.assert_allclose(o["achieved_goal"], np.asarray(st.obs["achieved_goal"]).ravel(),
                                   atol=1e-5)
        assert r == float(np.sum(st.reward))


@pytest.mark.parametrize("env_id", list(ge.DENSE_ENV_IDS.values()))
def test_dense_ids_pass_the_env_checker_and_reward_minus_the_distance(env_id):
    """~1 s each: the ...Dense-v0 ids (the sparse ones: test_env_checker_and_spaces)."""
    env = gym.make(env_id)
    assert env.spec.max_episode_steps == 50
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded Box observations, as in the Fetch tasks
        check_env(env.unwrapped, skip_render_check=True)
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    for t in range(1, 51):
        obs, r, terminated, truncated, info = env.step(rng.uniform(-1, 1, 8).astype(np.float32))
        d = np.linalg.norm(obs["achieved_goal"].reshape(2, 3) - obs["desired_goal"].reshape(2, 3),
                           axis=-1)
        assert r == pytest.approx(-float(d.sum()), abs=1e-6)      # defaults: -(d_left + d_right)
        assert r == float(env.unwrapped.compute_reward(obs["achieved_goal"],
                                                       obs["desired_goal"], info))
        assert truncated is (t == 50) and terminated is False
    assert env.unwrapped.reward_type == "dense"


@pytest.mark.parametrize("env_id", list(ge.ENV_IDS.values()))
def test_sparse_ids_have_max_episode_steps(env_id):
    assert gym.spec(env_id).max_episode_steps == 50
    assert gym.spec(env_id).kwargs["reward_type"] == "sparse"


@pytest.mark.e2e
def test_gymnasium_make_the_standard_way_in_a_fresh_interpreter():
    """~2 s: gymnasium.make("mjx_envs:...") and gymnasium.register_envs(mjx_envs) with nothing
    imported before, as users of gymnasium_robotics write them."""
    code = ("import gymnasium as gym, numpy as np\n"
            "e = gym.make('mjx_envs:DualUR3Push-v0')\n"
            "assert e.spec.max_episode_steps == 50, e.spec\n"
            "e.reset(seed=0); e.step(np.zeros(8, np.float32))\n"
            "import mjx_envs\n"
            "gym.register_envs(mjx_envs)\n"
            "d = gym.make('DualUR3PotDense-v0'); d.reset(seed=0)\n"
            "import sys; assert 'jax' not in sys.modules\n")
    for snippet in (code, code.replace("e = gym.make('mjx_envs:DualUR3Push-v0')",
                                       "import mjx_envs; gym.register_envs(mjx_envs)\n"
                                       "e = gym.make('DualUR3Push-v0')")):
        out = subprocess.run([sys.executable, "-c", snippet], capture_output=True, text=True,
                             cwd="/", timeout=120,
                             env=dict(os.environ, PYTHONPATH=ROOT))
        assert out.returncode == 0, out.stderr[-2000:]
