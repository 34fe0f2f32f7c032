"""The training-only task options of pickup and pot (`mjx_envs.settings.TRAINING_ONLY_FIELDS`):
goals at the object's resting height (``goal_rest_fraction``) and starts from recorded grasped
states (``grasp_start_fraction``). Off by default with unchanged outputs; on the C engine the
options do what they say; one MJX smoke check; test episodes switch them off.

Budget (2-core CPU): C-engine programs compile in seconds and each grasp recording takes a few
seconds (small ``n_grasp_states``); the MJX check compiles one reset + step at batch 2 (~35 s
cold, faster from the persistent compilation cache of tests/conftest.py).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjx_envs
from mjx_envs import registry, schema, settings
from mjx_envs.core import SAMPLER
from mjx_envs.numpy_env import NumpyDualArmEnv
from mjx_envs.schema import ConfigError
from mjx_envs.tasks import grasp_start, scripted
from tests.conftest import tree_equal
from tests.env_fixtures import RecordingSampler, ReplaySampler

LIFT_TASKS = ("pickup", "pot")
OFF = {"goal_rest_fraction": 0.0, "grasp_start_fraction": 0.0}
N_STATES = 8  # grasped states recorded in these tests (the default is 64)
B = 8


@functools.cache
def _env(task, physics="c", **overrides):
    return mjx_envs.make(task, physics=physics, **overrides)


def _grasp_env(task, fraction=1.0):
    return _env(task, grasp_start_fraction=fraction, n_grasp_states=N_STATES)


def _keys(n, seed=0):
    return jax.random.split(jax.random.PRNGKey(seed), n)


def _episode(env, keys, actions):
    """jit(vmap(reset)) then the steps of ``actions`` [T, B, 8]: (first state, states [T])."""

    @jax.jit
    def run(keys, actions):
        s0 = jax.vmap(env.reset)(keys)

        def body(s, a):
            s = jax.vmap(env.step)(s, a)
            return s, s

        return s0, jax.lax.scan(body, s0, actions)[1]

    return jax.device_get(run(keys, jnp.asarray(actions)))


def _still_closed(t, n, up=0.0):
    """[t, n, 8] actions: fingers closed (-1), each gripper moving up by ``up`` (else still)."""
    return np.tile(np.array([0, 0, up, -1.0] * 2, np.float32), (t, n, 1))


def _holding(obs):
    return np.asarray(scripted.holding(jax.tree.map(jnp.asarray, obs)))


def _rest_goal_height(env):
    """Height of each arm's goal when the object lies at its resting height: [2]."""
    return np.float32(env._rest_z) + env.point_offsets[:, 2]


# -- off by default: the standard task, unchanged ----------------------------------------------

@pytest.mark.parametrize("task", LIFT_TASKS)
def test_off_by_default_and_outputs_unchanged(task):
    cfg = registry.default_config(task)
    assert cfg.goal_rest_fraction == 0.0 and cfg.grasp_start_fraction == 0.0
    assert registry.task_config(task, **OFF) == cfg
    default = _env(task)
    explicit = _env(task, **OFF, n_grasp_states=N_STATES)  # differs in an unused field only
    assert default.grasp_states is None and explicit.grasp_states is None
    keys = _keys(4, 1)
    actions = np.random.default_rng(0).uniform(-1, 1, (3, 4, 8)).astype(np.float32)
    assert tree_equal(_episode(default, keys, actions), _episode(explicit, keys, actions))


@pytest.mark.parametrize("task", LIFT_TASKS)
def test_default_reset_draws_are_the_standard_ones(task):
    """With the options off, reset makes exactly the standard task's jax.random draws."""
    r = _env(task).rules
    key = jax.random.PRNGKey(3)
    rec = RecordingSampler(SAMPLER)
    r.reset(jnp, rec, key)
    k_goal, k_init = jax.random.split(key, 2)
    k_pose, k_r, k_phi = jax.random.split(k_goal, 3)
    cfg = r.config
    f32 = jnp.float32
    want = [jax.random.uniform(k_pose, (4,), f32, np.float32(cfg.target_low),
                               np.float32(cfg.target_high)),
            jax.random.uniform(k_r, (), f32, *cfg.target_radius),
            jax.random.uniform(k_phi, (), f32, 0.0, 2 * np.pi),
            jax.random.uniform(k_init, (3,), f32, np.float32(cfg.init_low),
                               np.float32(cfg.init_high))]
    assert len(rec.draws) == len(want)
    for got, w in zip(rec.draws, want, strict=True):
        np.testing.assert_array_equal(got, np.asarray(w))


# -- goal_rest_fraction ------------------------------------------------------------------------

@pytest.mark.parametrize("task", LIFT_TASKS)
def test_goal_rest_fraction_one_puts_every_goal_at_rest_height(task):
    env = _env(task, goal_rest_fraction=1.0)
    g = np.asarray(jax.jit(jax.vmap(env.reset))(_keys(64)).obs["desired_goal"])
    np.testing.assert_allclose(g[..., 2], np.broadcast_to(_rest_goal_height(env), (64, 2)),
                               atol=1e-6)
    centre = g.mean(axis=1)  # x, y still spread over the goal range
    lo, hi = env.config.target_low, env.config.target_high
    assert np.all(centre[:, 0] >= lo[0] - 1e-5) and np.all(centre[:, 0] <= hi[0] + 1e-5)
    assert np.ptp(centre[:, 0]) > 0.5 * (hi[0] - lo[0])


def test_goal_rest_fraction_half_about_half():
    env = _env("pickup", goal_rest_fraction=0.5)
    g = np.asarray(jax.vmap(lambda k: env.rules.goal(jnp, SAMPLER, k))(_keys(64, 5)))
    at_rest = np.all(np.abs(g[..., 2] - _rest_goal_height(env)) < 1e-6, axis=-1)
    assert 20 <= at_rest.sum() <= 44, at_rest.sum()
    h = g[~at_rest, :, 2] - _rest_goal_height(env)  # the others lifted as usual
    assert np.all(h >= env.config.target_low[2] - 1e-5)


def test_goal_rest_fraction_numpy_and_jax_agree():
    """The NumPy simulator supports goal_rest_fraction: same draws -> same goals."""
    cfg = registry.task_config("pot", goal_rest_fraction=0.5)
    r = _env("pot", goal_rest_fraction=0.5).rules
    for seed in range(4):
        rec = RecordingSampler(SAMPLER)
        g_jax, q_jax = r.reset(jnp, rec, jax.random.PRNGKey(seed))
        assert len(rec.draws) == 5  # pose, radius, direction, rest choice; initial pose
        g_np, q_np = r.reset(np, ReplaySampler(rec.draws), None)
        np.testing.assert_allclose(g_np, np.asarray(g_jax), rtol=0, atol=1e-6)
        np.testing.assert_allclose(q_np, np.asarray(q_jax), rtol=0, atol=1e-6)
    sim = NumpyDualArmEnv(schema.replace_config(cfg, goal_rest_fraction=1.0), task="pot")
    g = sim.reset(np.random.default_rng(0)).desired_goal
    np.testing.assert_allclose(g[:, 2], _rest_goal_height(_env("pot")), atol=1e-6)


# -- grasp_start_fraction (C engine) -----------------------------------------------------------

@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
@pytest.mark.parametrize("task", LIFT_TASKS)
def test_grasp_start_every_episode_starts_grasped_and_holds(task):
    env = _grasp_env(task)
    gs = env.grasp_states
    assert gs.qpos.shape == (N_STATES, env.mj_model.nq) and gs.mocap.shape == (N_STATES, 2, 3)
    assert set(gs._fields) == {"qpos", "qvel", "mocap", "tries", "seconds"}  # no actions
    assert len({q.tobytes() for q in gs.qpos}) == N_STATES  # distinct states
    keys = _keys(B, 2)
    s0, still = _episode(env, keys, _still_closed(5, B))
    # starts: one of the recorded states, both grippers closed on the object
    match = np.all(np.asarray(s0.data.qpos)[:, None] == gs.qpos[None], axis=-1)
    assert np.all(match.sum(1) == 1)
    assert _holding(s0.obs).all()
    contacts = grasp_start.FingerContacts(env.mj_model, env.rules.object_body)
    for q, v, m in zip(s0.data.qpos, s0.data.qvel, s0.data.mocap_pos, strict=True):
        assert min(contacts.forces(q, v, m).values()) >= grasp_start.MIN_FINGER_FORCE
    # the goal is drawn as usual (the same goals as the standard task's for the same keys)
    standard = jax.jit(jax.vmap(_env(task).reset))(keys)
    np.testing.assert_array_equal(s0.obs["desired_goal"], standard.obs["desired_goal"])
    # closed and still: the object stays in the grippers (it does not drop)
    z0 = s0.obs["achieved_goal"][..., 2]
    assert np.all(np.abs(still.obs["achieved_goal"][-1, ..., 2] - z0) < 0.005)
    assert _holding(jax.tree.map(lambda x: x[-1], still.obs)).all()
    assert np.all(still.metrics["physics_ok"] == 1.0)
    # closed and rising 0.02 m per step: both object points rise with the grippers
    _, lift = _episode(env, keys, _still_closed(6, B, up=0.4))
    assert np.all(lift.obs["achieved_goal"][-1, ..., 2] - z0 > 0.09)


def test_grasp_start_fraction_half_about_half():
    env = _grasp_env("pickup", 0.5)
    s0 = jax.jit(jax.vmap(env.reset))(_keys(64, 4))
    qpos = np.asarray(s0.data.qpos)
    grasped = np.any(np.all(qpos[:, None] == env.grasp_states.qpos[None], axis=-1), axis=1)
    assert 20 <= grasped.sum() <= 44, grasped.sum()
    # the others start from the standard initial state: the home arm pose
    np.testing.assert_array_equal(qpos[~grasped, :16], np.broadcast_to(
        env.rules.home_qpos[:16], (int((~grasped).sum()), 16)))


def test_grasp_states_recorded_once_per_config_and_errors(monkeypatch):
    a = _grasp_env("pickup")
    b = _env("pickup", grasp_start_fraction=0.3, goal_rest_fraction=0.2, n_grasp_states=N_STATES)
    assert b.grasp_states is a.grasp_states  # cached: the options do not change the recording
    assert a.grasp_states.tries >= N_STATES
    # too few successful grasps: a clear error when the states are first needed (the first
    # reset traced), not when the env is built
    monkeypatch.setattr(grasp_start, "_CACHE", {})
    monkeypatch.setattr(grasp_start, "MIN_FINGER_FORCE", 1e6)
    env = mjx_envs.make("pickup", physics="c", grasp_start_fraction=1.0, n_grasp_states=2)
    with pytest.raises(grasp_start.GraspRecordError, match=r"only 0 of \d+ scripted grasps"):
        jax.eval_shape(env.reset, jax.random.PRNGKey(0))


# -- MJX (one reset + step at batch 2) ---------------------------------------------------------

@pytest.mark.mjx
def test_grasp_start_mjx_smoke():
    env = mjx_envs.make("pickup", physics="mjx", grasp_start_fraction=1.0, goal_rest_fraction=1.0,
                        n_grasp_states=N_STATES)
    s0, s1 = _episode(env, _keys(2, 6), _still_closed(1, 2))
    s1 = jax.tree.map(lambda x: x[0], s1)
    # a recorded state (MJX's forward normalizes the object's quaternion: float32 rounding)
    diff = np.abs(np.asarray(s0.data.qpos)[:, None] - env.grasp_states.qpos[None]).max(-1)
    assert np.all(diff.min(1) < 1e-6), diff.min(1)
    assert _holding(s0.obs).all() and _holding(s1.obs).all()
    assert np.all(s1.metrics["physics_ok"] == 1.0)
    np.testing.assert_allclose(s0.obs["desired_goal"][..., 2],
                               np.broadcast_to(_rest_goal_height(env), (2, 2)), atol=1e-6)
    dz = s1.obs["achieved_goal"][..., 2] - s0.obs["achieved_goal"][..., 2]
    assert np.all(np.abs(dz) < 0.005)


# -- test episodes: the standard task ----------------------------------------------------------

def test_test_overrides_switch_the_options_off():
    assert settings.TRAINING_ONLY_FIELDS[:2] == ("goal_rest_fraction", "grasp_start_fraction")
    perturbations = {"obs_noise": 0.0, "obs_dropout": 0.0, "obs_bias": 0.0, "obs_period": 0,
                     "latency": 0,   # mjx_envs/perturb.py: training only as well
                     "base_offset": 0.0, "base_yaw": 0.0, "finger_force": 0.0,
                     "action_scale": 0.0}   # mjx_envs/randomize.py, every task
    objects = {"object_mass": 0.0, "object_size": 0.0, "object_friction": 0.0,
               "table_height": 0.0, "grasp_timeconst": 0.0}   # randomize.py, object tasks
    for task in LIFT_TASKS:
        assert registry.test_overrides(task) == {**OFF, **perturbations, **objects}
        on = {"goal_rest_fraction": 0.5, "grasp_start_fraction": 0.5, "latency": 2}
        cfg = registry.task_config(task, **{**on, **registry.test_overrides(task)})
        assert cfg == registry.default_config(task)
    assert registry.test_overrides("reach") == perturbations
    assert registry.test_overrides("push") == {**perturbations, **objects}
    assert registry.test_overrides("toy") == {}
    from daddpg_jax.analysis.evaluation import standard_env_overrides

    assert standard_env_overrides("pot", {"grasp_start_fraction": 1.0, "max_delta": 0.04}) == {
        **OFF, **perturbations, **objects, "max_delta": 0.04}
    assert standard_env_overrides("reach", None) == perturbations


def test_robot_client_runs_the_standard_task(monkeypatch):
    from daddpg_jax.deploy import robot_session, server
    from daddpg_jax.deploy.limits import RobotLimits

    env = {**schema.to_dict(registry.default_config("pickup")), "goal_rest_fraction": 0.5,
           "grasp_start_fraction": 1.0, "dt": 0.04}

    class FakeClient:
        def __init__(self, *a, **k):
            pass

        def info(self):
            return {"task": "pickup", "env": env, "action_size": 8}

        def close(self):
            pass

    monkeypatch.setattr(server, "PolicyClient", FakeClient)
    limits = RobotLimits(control_period=0.04)
    _, task_cfg = robot_session.served_policy("http://x", limits, None, None, None)
    assert task_cfg == registry.default_config("pickup")  # the robot's own, standard task
    assert task_cfg.grasp_start_fraction == 0.0


def test_numpy_env_accepts_the_fields_and_disables_grasp_starts():
    with pytest.warns(UserWarning, match="grasp_start_fraction"):
        sim = NumpyDualArmEnv({"grasp_start_fraction": 0.5, "goal_rest_fraction": 0.5},
                              task="pickup")
    assert sim.config.grasp_start_fraction == 0.0 and sim.config.goal_rest_fraction == 0.5
    res = sim.reset(np.random.default_rng(0))
    np.testing.assert_array_equal(res.observation[:, :3], sim.reset(
        np.random.default_rng(1)).observation[:, :3])  # home gripper pose: a standard start


# -- validation --------------------------------------------------------------------------------

@pytest.mark.parametrize("overrides, message", [
    ({"goal_rest_fraction": 1.5}, "goal_rest_fraction must be <= 1.0, got 1.5"),
    ({"goal_rest_fraction": -0.1}, "goal_rest_fraction must be >= 0.0, got -0.1"),
    ({"grasp_start_fraction": 2}, "grasp_start_fraction must be <= 1.0, got 2.0"),
    ({"grasp_start_fraction": "half"}, "grasp_start_fraction must be a number"),
    ({"n_grasp_states": 0}, "n_grasp_states must be >= 1, got 0"),
    ({"n_grasp_states": 2.5}, "n_grasp_states must be an integer"),
])
def test_range_validation(overrides, message):
    with pytest.raises(ConfigError, match=message):
        registry.task_config("pickup", **overrides)


def test_tasks_without_the_options_reject_them():
    for task in ("reach", "push"):
        with pytest.raises(ConfigError, match="unknown config field.*goal_rest_fraction"):
            registry.task_config(task, goal_rest_fraction=0.5)
