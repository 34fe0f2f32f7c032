"""Physics randomization (mjx_envs/randomize.py): each field changes what it names and nothing
else, off by default with no code or carry, per-env values within one batch, the same model on
both engines, and evaluation over randomization fields."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjx_envs
from daddpg_jax.algo import acting
from mjx_envs import randomize, registry, rules, settings, wrappers
from mjx_envs.observation import obs_layout

L = obs_layout()
T, N = 6, 4
EXACT = dict(perturb_exact=True)
VALUE = dict(object_mass=0.5, object_size=0.004, object_friction=-0.4, table_height=0.01,
             grasp_timeconst=0.25, base_offset=0.01, base_yaw=4.0, finger_force=-0.5,
             action_scale=0.5)
"""one exact value per field (the test of each field)"""
CHANGES = {
    "object_mass": {"body_mass", "body_inertia", "body_subtreemass"},
    "object_size": {"geom_size", "geom_rbound"},
    "object_friction": {"pair_friction"},
    "table_height": {"geom_pos"},
    "grasp_timeconst": {"pair_solref"},
    "base_offset": {"body_pos"},
    "base_yaw": {"body_quat"},
    "finger_force": {"actuator_gainprm", "actuator_biasprm", "actuator_forcerange"},
    "action_scale": set(),
}
"""the model fields each randomization field may change"""

_RUNS: dict = {}


def _run(task="pickup", actions=None, physics="c", **over):
    """(reset states, per-step states) of N envs under `over` from fixed keys (compiled once)."""
    over = {"episode_length": T, **over}
    key = (task, physics, tuple(sorted(over.items())))
    if key not in _RUNS:
        env = mjx_envs.make(task, physics=physics, **over)
        _RUNS[key] = (env, jax.jit(lambda ks, xs: acting.rollout(env, lambda s, a: a, ks,
                                                                 xs=xs)))
    env, fn = _RUNS[key]
    if actions is None:
        actions = np.zeros((T, N, 8), np.float32)
    keys = jax.random.split(jax.random.PRNGKey(5), N)
    s0, tr = fn(keys, jnp.asarray(actions))
    return env, jax.device_get(s0), jax.device_get(tr)


def _pair_names(m, row):
    """The geom names of contact pair ``row`` of model ``m``."""
    return m.geom(int(m.pair_geom1[row])).name, m.geom(int(m.pair_geom2[row])).name


def _index(task, **over):
    cfg = registry.task_config(task, **over)
    env = mjx_envs.make(task, physics="c", **over)
    obj = registry.OBJECTS.get(task)
    return env, randomize.ModelIndex(env.mj_model, obj[1] if obj else None,
                                     randomize.Randomization.from_config(cfg))


def test_off_by_default_with_nothing_carried():
    for task in registry.TASKS:
        cfg = registry.default_config(task)
        r = randomize.Randomization.from_config(cfg)
        assert not r.active and not r.physical
        assert all(getattr(cfg, f, 0.0) == 0.0 for f in randomize.FIELDS)
        for name in randomize.FIELDS:
            if hasattr(cfg, name):
                assert registry.test_overrides(task)[name] == 0.0
    env = mjx_envs.make("pickup", physics="c")
    assert env.backend.rand is None and env.backend.n_rand_params == 0
    s = env.reset(jax.random.PRNGKey(0))
    assert "physics" not in s.info
    # reach has no object fields
    with pytest.raises(settings.ConfigError, match="unknown config field"):
        registry.task_config("reach", object_mass=0.1)


@pytest.mark.parametrize("name", randomize.FIELDS)
def test_each_field_changes_the_model_fields_it_names_and_nothing_else(name):
    task = "pickup"
    env, ix = _index(task, **{name: VALUE[name]}, **EXACT)
    r = randomize.Randomization.from_config(registry.task_config(task, **{name: VALUE[name]},
                                                                 **EXACT))
    values = randomize.draw(np, rules.NumpySampler(), np.random.default_rng(0), r)
    fields = randomize.model_fields(np, ix, values["params"])
    changed = {k for k, v in fields.items() if not np.allclose(v, ix.nominal[k])}
    assert changed == CHANGES[name] - ({"body_quat"} if name == "base_offset" else set())
    m = ix.nominal
    if name == "object_mass":
        assert fields["body_mass"][ix.body] == pytest.approx(1.5 * m["body_mass"][ix.body])
        assert np.count_nonzero(fields["body_mass"] != m["body_mass"]) == 1
    if name == "object_size":
        rows = np.flatnonzero(np.any(fields["geom_size"] != m["geom_size"], axis=1))
        assert set(rows) == set(ix.geoms)
        np.testing.assert_allclose(fields["geom_size"][rows], m["geom_size"][rows] + 0.004,
                                   atol=1e-7)
    if name == "object_friction":
        rows = np.flatnonzero(np.any(fields["pair_friction"] != m["pair_friction"], axis=1))
        assert set(rows) == set(ix.pairs) and len(rows) > 0
        np.testing.assert_allclose(fields["pair_friction"][rows, :2],
                                   0.6 * m["pair_friction"][rows, :2], rtol=1e-6)
        np.testing.assert_array_equal(fields["pair_friction"][rows, 2:],
                                      m["pair_friction"][rows, 2:])
    if name == "grasp_timeconst":
        rows = np.flatnonzero(np.any(fields["pair_solref"] != m["pair_solref"], axis=1))
        assert set(rows) == set(ix.grip_pairs) and len(rows) == 12   # 4 fingers x 3 parts
        names = {n for r in rows for n in _pair_names(env.mj_model, r)}
        assert "tabletop" not in names
        np.testing.assert_allclose(fields["pair_solref"][rows, 0],
                                   1.25 * m["pair_solref"][rows, 0], rtol=1e-6)
        np.testing.assert_array_equal(fields["pair_solref"][rows, 1], m["pair_solref"][rows, 1])
    if name == "table_height":
        diff = fields["geom_pos"] - m["geom_pos"]
        assert np.count_nonzero(diff) == 1 and diff[ix.table, 2] == pytest.approx(0.01)
    if name == "base_offset":
        diff = fields["body_pos"] - m["body_pos"]
        np.testing.assert_allclose(np.linalg.norm(diff[ix.mounts], axis=1), 0.01, rtol=1e-5)
        assert np.count_nonzero(np.abs(diff).sum(1)) == 2
    if name == "finger_force":
        np.testing.assert_allclose(fields["actuator_forcerange"][ix.fingers],
                                   0.5 * m["actuator_forcerange"][ix.fingers])
        np.testing.assert_allclose(fields["actuator_gainprm"][ix.fingers, 0], 150.0)


def test_rest_height_and_goals_move_with_table_and_size():
    over = dict(table_height=0.01, object_size=0.004, **EXACT)
    _, n0, ntr = _run()
    env, s0, tr = _run(**over)
    dz = 0.014
    # initial object height, goals and achieved goals at reset move by dz, x/y stay
    np.testing.assert_allclose(s0.obs["desired_goal"][..., 2], n0.obs["desired_goal"][..., 2]
                               + dz, atol=1e-6)
    np.testing.assert_array_equal(s0.obs["desired_goal"][..., :2], n0.obs["desired_goal"][..., :2])
    np.testing.assert_allclose(s0.obs["achieved_goal"][..., 2], n0.obs["achieved_goal"][..., 2]
                               + dz, atol=1e-6)
    # the object rests at the new height: after T still steps it has not moved more than 1 mm
    # from where it started (the nominal bar settles the same way)
    z0 = s0.obs["achieved_goal"][..., 2]
    zt = tr.obs["achieved_goal"][-1][..., 2]
    np.testing.assert_allclose(zt, z0, atol=1e-3)
    assert tr.metrics["physics_ok"].min() == 1.0


def test_action_scale_scales_the_step_and_nothing_else():
    a = np.zeros((T, N, 8), np.float32)
    a[..., 0] = 0.5  # both arms +x
    a[..., 4] = 0.5
    _, n0, ntr = _run(task="reach", actions=a)
    env, s0, tr = _run(task="reach", actions=a, action_scale=0.5, **EXACT)
    m_nom = ntr.data.mocap_pos[0, :, :2] - n0.data.mocap_pos[:, :2]
    m_new = tr.data.mocap_pos[0, :, :2] - s0.data.mocap_pos[:, :2]
    np.testing.assert_allclose(m_new, 1.5 * m_nom, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(m_nom[..., 0], 0.05 * 0.5, rtol=1e-5)
    np.testing.assert_array_equal(s0.obs["observation"], n0.obs["observation"])
    assert not env.randomization.physical and env.backend.rand is None  # action scale only


def test_base_offset_and_yaw_move_the_arm_not_what_it_believes():
    over = dict(base_offset=0.01, base_yaw=4.0, **EXACT)
    _, n0, ntr = _run(task="reach")
    env, s0, tr = _run(task="reach", **over)
    g = slice(*L["grip_pos"])
    # the arms believe they are where the nominal arms are (no jump at reset, same frame)
    np.testing.assert_allclose(s0.obs["observation"][..., g], n0.obs["observation"][..., g],
                               atol=2e-4)
    np.testing.assert_allclose(tr.obs["observation"][-1][..., g],
                               ntr.obs["observation"][-1][..., g], atol=2e-3)
    # but the true grippers (reach's achieved goal) are displaced by the calibration error
    shift = np.linalg.norm(s0.obs["achieved_goal"] - n0.obs["achieved_goal"], axis=-1)
    assert shift.min() > 0.005 and shift.max() < 0.03
    # reach has no object: its object terms stay zero
    for name in ("object_pos", "object_rel_pos", "object_velp"):
        assert not np.any(tr.obs["observation"][..., slice(*L[name])]), name
    # the transform and its inverse agree
    p = s0.info["physics"]["params"][0]
    ix = env.model_index
    x = np.asarray([[0.3, 0.1, 0.5], [0.2, -0.2, 0.45]], np.float32)
    np.testing.assert_allclose(randomize.to_nominal(np, ix, p, randomize.to_true(np, ix, p, x)),
                               x, atol=1e-6)


def test_training_draws_differ_between_envs_within_bounds_and_change_the_physics():
    env, s0, tr = _run(object_mass=0.5, object_friction=0.5, table_height=0.01,
                       finger_force=0.3)
    p = randomize.unpack(s0.info["physics"]["params"])
    for k, bound in (("mass", 0.5), ("friction", 0.5), ("finger", 0.3)):
        assert len(set(np.round(p[k], 6))) == N
        assert np.all(np.abs(p[k] - 1.0) <= bound)
    assert np.all(np.abs(p["table"]) <= 0.01) and len(set(np.round(p["table"], 6))) == N
    # the C engine's per-env models hold those values ...
    models = env.backend.models_for(s0.info["physics"]["params"])
    masses = [m.body_mass[env.model_index.body] for m in models]
    np.testing.assert_allclose(masses, 0.5 * p["mass"], rtol=1e-5)
    tables = [m.geom_pos[env.model_index.table, 2] for m in models]
    np.testing.assert_allclose(tables, 0.40 + p["table"], atol=1e-6)
    # ... and the objects come to rest at different heights
    z = tr.obs["achieved_goal"][-1][:, 0, 2]
    assert len(set(np.round(z, 4))) == N
    # the same keys give the same draws (deterministic per seed)
    _, s1, _ = _run(object_mass=0.5, object_friction=0.5, table_height=0.01, finger_force=0.3)
    np.testing.assert_array_equal(s1.info["physics"]["params"], s0.info["physics"]["params"])


def test_finger_force_changes_the_squeeze():
    """Commanded open from closed, a weaker finger servo lags further behind."""
    a = np.zeros((T, N, 8), np.float32)
    a[..., 3] = a[..., 7] = 1.0   # open
    _, n0, ntr = _run(actions=a)
    _, s0, tr = _run(actions=a, finger_force=-0.8, **EXACT)
    f = slice(*L["fingers"])
    nom = ntr.obs["observation"][0][..., f]
    weak = tr.obs["observation"][0][..., f]
    assert np.all(nom > 1e-3) and np.all(weak < nom - 1e-4)   # the weak fingers open less


@pytest.mark.mjx
def test_mjx_and_c_build_the_same_models_and_start_states():
    over = dict(object_mass=0.5, object_size=0.004, object_friction=0.5, table_height=0.01,
                grasp_timeconst=0.3, base_offset=0.01, base_yaw=4.0, finger_force=0.3,
                episode_length=T)
    c = mjx_envs.make("pickup", physics="c", **over)
    m = mjx_envs.make("pickup", physics="mjx", **over)
    keys = jax.random.split(jax.random.PRNGKey(2), 2)
    sc = jax.device_get(jax.jit(jax.vmap(c.reset))(keys))
    sm = jax.device_get(jax.jit(jax.vmap(m.reset))(keys))
    np.testing.assert_array_equal(sc.info["physics"]["params"], sm.info["physics"]["params"])
    np.testing.assert_allclose(sc.obs["observation"], sm.obs["observation"], atol=1e-5)
    np.testing.assert_allclose(sc.obs["desired_goal"], sm.obs["desired_goal"], atol=1e-6)
    params = sc.info["physics"]["params"]
    c_models = c.backend.models_for(params)
    for i in range(2):
        mx = jax.device_get(m.backend._model(jnp.asarray(params[i])))
        for name in c.model_index.fields():
            np.testing.assert_allclose(np.asarray(getattr(mx, name)),
                                       getattr(c_models[i], name), rtol=1e-5, atol=1e-6,
                                       err_msg=name)
    # both step their randomized models: two still steps leave the objects where they rest
    a = jnp.zeros((2, 8), jnp.float32)
    tc, tm = sc, sm
    for _ in range(2):
        tc = jax.jit(jax.vmap(c.step))(tc, a)
        tm = jax.jit(jax.vmap(m.step))(tm, a)
    tc, tm = jax.device_get((tc, tm))
    assert tm.metrics["physics_ok"].min() == 1.0 and tc.metrics["physics_ok"].min() == 1.0
    np.testing.assert_allclose(tm.obs["achieved_goal"], tc.obs["achieved_goal"], atol=3e-3)
    np.testing.assert_allclose(tm.obs["achieved_goal"], sm.obs["achieved_goal"], atol=3e-3)


def test_numpy_simulator_runs_the_nominal_physics():
    from mjx_envs.numpy_env import NumpyDualArmEnv

    cfg = registry.task_config("push", object_mass=0.3)
    with pytest.warns(UserWarning, match="nominal physics"):
        sim = NumpyDualArmEnv(cfg, task="push")
    assert sim.config.object_mass == 0.0


def test_evaluation_grid_accepts_randomization_fields():
    from daddpg_jax.analysis import perturbation
    from mjx_envs.schema import ConfigError

    grid = perturbation.parse_grid("push", ["object_mass=0,0.5", "latency=0,1"])
    assert grid == {"object_mass": [0.0, 0.5], "latency": [0, 1]}
    with pytest.raises(ConfigError, match="not a perturbation of reach"):
        perturbation.parse_grid("reach", ["object_mass=0,0.5"])
    with pytest.raises(ConfigError, match="object_size"):
        perturbation.parse_grid("push", ["object_size=0.5"])


def test_eval_env_drops_training_randomization():
    from daddpg_jax.algo.config import build_config
    from daddpg_jax.running.runner import make_eval_env

    cfg = build_config("push").replace(physics="c")
    ev = make_eval_env(cfg, {"object_mass": 0.3, "base_yaw": 3.0})
    assert wrappers.find(ev, wrappers.Randomize) is None



def test_believed_obs_moves_the_gripper_terms_consistently():
    _, ix = _index("pickup", base_yaw=5.0, base_offset=0.01, **EXACT)
    _, ix_reach = _index("reach", base_yaw=5.0, base_offset=0.01, **EXACT)
    rng = np.random.default_rng(1)
    obs = rng.normal(size=(2, 25)).astype(np.float32)
    params = randomize.nominal_params()
    params[5:11] = rng.uniform(-0.01, 0.01, 6)
    params[11:13] = np.radians([5.0, -3.0])
    seen = randomize.believed_obs(np, ix, params, obs)
    f = {k: slice(*v) for k, v in L.items()}
    rot = np.stack([[[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]]
                    for y in params[11:13]])
    np.testing.assert_allclose(seen[:, f["grip_velp"]],
                               np.einsum("aji,aj->ai", rot, obs[:, f["grip_velp"]]), atol=1e-6)
    # the object's velocity seen relative to the believed gripper still sums to its own
    np.testing.assert_allclose(seen[:, f["object_velp"]] + seen[:, f["grip_velp"]],
                               obs[:, f["object_velp"]] + obs[:, f["grip_velp"]], atol=1e-6)
    np.testing.assert_allclose(seen[:, f["object_rel_pos"]],
                               obs[:, f["object_pos"]] - seen[:, f["grip_pos"]], atol=1e-6)
    for name in ("object_pos", "fingers", "object_rot", "object_velr", "finger_vel"):
        np.testing.assert_array_equal(seen[:, f[name]], obs[:, f[name]])
    reach = randomize.believed_obs(np, ix_reach, params, obs)
    for name in ("object_rel_pos", "object_velp"):
        np.testing.assert_array_equal(reach[:, f[name]], obs[:, f[name]])


def test_yaw_turns_the_mounts_and_the_gripper_targets_about_world_z():
    import mujoco

    _, ix = _index("reach", base_yaw=6.0, **EXACT)
    params = randomize.nominal_params()
    params[11:13] = np.radians([6.0, -4.0])
    fields = randomize.model_fields(np, ix, params)
    for arm, yaw in enumerate(np.radians([6.0, -4.0])):
        q_yaw = np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])
        for body in (ix.mounts[arm], ix.targets[arm]):
            want = np.zeros(4)
            mujoco.mju_mulQuat(want, q_yaw, ix.nominal["body_quat"][body])   # world-frame yaw
            np.testing.assert_allclose(fields["body_quat"][body], want, atol=1e-12)
    untouched = np.setdiff1d(np.arange(len(fields["body_quat"])),
                             np.concatenate([ix.mounts, ix.targets]))
    np.testing.assert_array_equal(fields["body_quat"][untouched],
                                  ix.nominal["body_quat"][untouched])


def test_c_engine_models_follow_every_new_draw():
    over = dict(object_mass=0.5, object_size=0.004, table_height=0.01, base_yaw=3.0,
                finger_force=0.3, episode_length=T)
    env = mjx_envs.make("pickup", physics="c", **over)
    reset = jax.jit(jax.vmap(env.reset))
    for seed in (0, 1, 2):
        s = jax.device_get(reset(jax.random.split(jax.random.PRNGKey(seed), 3)))
        params = s.info["physics"]["params"]
        models = env.backend.models_for(params)
        for i in range(3):
            for name, want in randomize.model_fields(np, env.model_index, params[i]).items():
                np.testing.assert_array_equal(getattr(models[i], name), want, err_msg=name)
        # rows that are not randomized keep the model's own float64 values
        np.testing.assert_array_equal(models[0].body_pos[1:], env.mj_model.body_pos[1:])


@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_grasped_starts_keep_the_geometry_nominal():
    """A recorded grasp is exact under the nominal geometry only: episodes that start from one
    keep size, table and bases nominal (and their goals), the rest stays randomized."""
    over = dict(grasp_start_fraction=1.0, n_grasp_states=4, object_mass=0.5,
                object_size=0.004, table_height=0.01, base_offset=0.01, **EXACT)
    env, s0, tr = _run(**over)
    _, g0, gtr = _run(grasp_start_fraction=1.0, n_grasp_states=4)
    p = randomize.unpack(s0.info["physics"]["params"])
    np.testing.assert_allclose(p["mass"], 1.5)
    assert not np.any(p["size"]) and not np.any(p["table"]) and not np.any(p["offset"])
    np.testing.assert_allclose(s0.obs["desired_goal"], g0.obs["desired_goal"], atol=1e-6)
    np.testing.assert_array_equal(s0.data.qpos, g0.data.qpos)
    assert tr.metrics["physics_ok"].min() == 1.0
    # the heavier bar is still held above the table by the closed grippers after T steps
    z = tr.obs["achieved_goal"][-1][..., 2]
    np.testing.assert_allclose(z, gtr.obs["achieved_goal"][-1][..., 2], atol=0.01)
