"""Gymnasium adapter (mjx_envs/gym_env.py): env checker, spaces, reward = compute_reward (also
batched, as HER calls it), 50-step truncation, seeding, registration, no JAX import, and the
same dynamics as the trainer's C-engine env."""

import dataclasses
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
from gymnasium.utils.env_checker import check_env  # noqa: E402

import mjx_envs.gym_env as ge  # noqa: E402

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
    ids = ge.register_envs()
    assert ids == ["DualUR3Reach-v0", "DualUR3Push-v0", "DualUR3Pickup-v0", "DualUR3Pot-v0"]
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
def test_settings_equal_the_jax_tasks(task):
    import mjx_envs

    cfg = dataclasses.asdict(mjx_envs.default_config(task))
    s = ge.TASK_SETTINGS[task]
    for k, v in cfg.items():
        if isinstance(v, (str, bool)):
            assert s[k] == v, k
        else:
            np.testing.assert_allclose(np.asarray(s[k], float), np.asarray(v, float), err_msg=k)


@pytest.mark.parametrize("task", ["push", "pickup"])
def test_same_trajectory_as_the_trainers_c_engine_env(task):
    """From the JAX env's initial state and goal, 8 random actions give the same observations
    (float32 rounding) and per-step rewards as the trainer's C-engine env."""
    import jax

    import mjx_envs

    jenv = mjx_envs.make(task, physics="c")
    st = jenv.reset(jax.random.PRNGKey(1))
    env = ge.DualUR3GoalEnv(task)
    o, _ = env.reset(options=dict(qpos=np.asarray(st.data.qpos),
                                  goal=np.asarray(st.obs["desired_goal"])))
    np.testing.assert_allclose(o["observation"], np.asarray(st.obs["observation"]).ravel(), atol=1e-5)
    step = jax.jit(jenv.step)
    rng = np.random.default_rng(2)
    for _ in range(8):
        a = rng.uniform(-1, 1, 8).astype(np.float32)
        st = step(st, a)
        o, r, _, _, _ = env.step(a)
        np.testing.assert_allclose(o["observation"], np.asarray(st.obs["observation"]).ravel(),
                                   atol=1e-5)
        np.testing.assert_allclose(o["achieved_goal"], np.asarray(st.obs["achieved_goal"]).ravel(),
                                   atol=1e-5)
        assert r == float(np.sum(st.reward))
