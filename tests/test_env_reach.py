"""Env contract, action semantics, rewards, determinism and engine parity for Reach."""

from __future__ import annotations

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import mjx_envs
from daddpg_jax.deploy import ur3
from mjx_envs import model as model_lib
from mjx_envs import observation as obs_lib
from mjx_envs.physics.backends import import_mjx
from tests.env_fixtures import (
    ROW_COLLIDE,
    ROW_LX,
    ROW_LY,
    ROW_LZ,
    ROW_R10X,
    ROW_RANDOM,
    ROW_RX,
    ROW_ZERO,
    B,
    T,
    rollout,
)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENGINES = ["c", pytest.param("mjx", marks=pytest.mark.mjx)]
# Engine parity tolerance on every observation entry of a 50-step reach episode (measured max
# 3.8 mm on positions, 5.4 mm on velocities*dt; see
# docs/ENVIRONMENTS.md): positions agree to this many metres.
PARITY_TOL_M = 0.006


@pytest.fixture(scope="module")
def c_env():
    return mjx_envs.make("reach", physics="c")


# -- kinematics -----------------------------------------------------------------------------

def _set_arm_qpos(model, qpos, q_left, q_right):
    for p, q in (("l", q_left), ("r", q_right)):
        for i in range(6):
            qpos[model.jnt_qposadr[model.joint(f"{p}_j{i + 1}").id]] = q[i]


@pytest.mark.parametrize("physics", ENGINES)
def test_forward_kinematics_matches_dh(physics, c_env):
    m = c_env.mj_model
    rng = np.random.default_rng(1)
    qs = rng.uniform(-np.pi, np.pi, (12, 2, 6))
    qpos = np.tile(m.qpos0, (len(qs), 1))
    for k, q in enumerate(qs):
        _set_arm_qpos(m, qpos[k], q[0], q[1])
    if physics == "c":
        d = mujoco.MjData(m)
        sites = []
        for k in range(len(qs)):
            d.qpos[:] = qpos[k]
            mujoco.mj_kinematics(m, d)
            sites.append([d.site("l_grip").xpos.copy(), d.site("r_grip").xpos.copy()])
        sites = np.array(sites)
    else:
        mjx = import_mjx()
        mm = mjx.put_model(m)
        d0 = mjx.make_data(mm)

        def kin(q):
            return mjx.kinematics(mm, d0.replace(qpos=q)).site_xpos

        xpos = np.asarray(jax.jit(jax.vmap(kin))(jnp.asarray(qpos, jnp.float32)))
        sites = xpos[:, [m.site("l_grip").id, m.site("r_grip").id]]
    for k, q in enumerate(qs):
        for i, p in enumerate(("l", "r")):
            ref = ur3.forward_kinematics(q[i], ur3.base_transform(p))[:3, 3]
            assert np.linalg.norm(sites[k, i] - ref) < 1e-3, (k, p, sites[k, i], ref)


def test_joint_limits_are_ur3(c_env):
    m = c_env.mj_model
    for p in ("l", "r"):
        for i in range(6):
            j = m.joint(f"{p}_j{i + 1}")
            np.testing.assert_allclose(m.jnt_range[j.id], [-2 * np.pi, 2 * np.pi], atol=1e-5)


# -- contract -------------------------------------------------------------------------------

@pytest.mark.parametrize("physics", ENGINES)
def test_contract_shapes_nan_and_single_trace(physics):
    r = rollout(physics)
    env = r.env
    assert env.action_size == 8 and env.num_arms == 2 and env.episode_length == T
    assert r.obs["observation"].shape == (B, T + 1, 2, env.obs_size)
    assert r.obs["achieved_goal"].shape == (B, T + 1, 2, 3)
    assert r.obs["desired_goal"].shape == (B, T + 1, 2, 3)
    for v in r.obs.values():
        assert v.dtype == np.float32 and np.all(np.isfinite(v))
    final = r.states[-1]
    assert final.reward.shape == (B, 2) and final.reward.dtype == jnp.float32
    assert final.done.shape == (B,) and np.all(np.asarray(final.done) == 1.0)
    assert np.all(np.asarray(r.states[-2].done) == 0.0)
    for k in ("success", "arm_contact", "physics_ok", "reward_goal"):
        assert r.metrics[k].shape == (B, T)
    assert np.all(r.metrics["physics_ok"] == 1.0)
    for leaf in jax.tree.leaves(final):
        assert not getattr(leaf, "weak_type", False)
    # desired goal is constant through the episode; object terms are zero in reach
    assert np.all(r.obs["desired_goal"] == r.obs["desired_goal"][:, :1])
    lay = obs_lib.obs_layout()
    a, b = lay["object_pos"]
    assert np.all(r.obs["observation"][..., a:b] == 0)
    # the fully random episode: finite, shaped, done at the end
    for st in r.random_states:
        for v in jax.tree.leaves(st.obs) + [st.reward]:
            assert np.all(np.isfinite(np.asarray(v)))
        assert st.obs["observation"].shape == (B, 2, env.obs_size)
    assert np.all(np.asarray(r.random_states[-1].done) == 1.0)
    assert np.all(np.asarray(r.random_states[-1].metrics["physics_ok"]) == 1.0)
    assert r.trace_count == 1


# -- action semantics -----------------------------------------------------------------------

def _disp(r, row, t=5):
    ag = r.obs["achieved_goal"]
    return ag[row, t] - ag[row, 0]


@pytest.mark.parametrize("physics", ENGINES)
def test_action_moves_one_gripper_by_max_delta(physics):
    r = rollout(physics)
    md = r.env.config.max_delta
    for row, arm, axis in ((ROW_LX, 0, 0), (ROW_LY, 0, 1), (ROW_LZ, 0, 2), (ROW_RX, 1, 0)):
        d = _disp(r, row)
        assert 0.85 * md < d[arm, axis] < 1.05 * md, (row, d)
        off = np.delete(d[arm], axis)
        assert np.all(np.abs(off) < 0.005), (row, d)
        assert np.linalg.norm(d[1 - arm]) < 0.005, (row, d)


@pytest.mark.parametrize("physics", ENGINES)
def test_zero_action_holds_and_clipping(physics):
    r = rollout(physics)
    ag = r.obs["achieved_goal"]
    drift = np.linalg.norm(ag[ROW_ZERO] - ag[ROW_ZERO, :1], axis=-1)
    assert drift.max() < 0.005
    np.testing.assert_allclose(r.obs["observation"][ROW_R10X], r.obs["observation"][ROW_RX],
                               atol=1e-6)


@pytest.mark.parametrize("physics", ENGINES)
def test_arm_contact_when_driven_together_only(physics):
    r = rollout(physics)
    assert r.metrics["arm_contact"][ROW_COLLIDE].max() == 1.0
    for row in (ROW_LX, ROW_LY, ROW_LZ, ROW_ZERO, ROW_RX):
        assert r.metrics["arm_contact"][row].max() == 0.0, row


# -- rewards --------------------------------------------------------------------------------

def test_compute_reward_shapes_threshold_and_both(c_env):
    env = c_env
    th = env.config.distance_threshold
    g = jnp.zeros((2, 3))
    for shape in [(2, 3), (5, 2, 3), (4, 6, 2, 3)]:
        ag = jnp.zeros(shape)
        r = env.compute_reward(ag, jnp.broadcast_to(g, shape), None)
        assert r.shape == shape[:-1] and np.all(np.asarray(r) == 0.0)
    inside = jnp.array([[th * 0.999, 0, 0], [0, 0, 0]])
    edge = jnp.array([[th * 1.001, 0, 0], [0, 0, 0]])
    np.testing.assert_array_equal(env.compute_reward(inside, g), [0.0, 0.0])
    np.testing.assert_array_equal(env.compute_reward(edge, g), [-1.0, 0.0])
    assert float(env.success(inside, g)) == 1.0
    assert float(env.success(edge, g)) == 0.0  # one arm in is not success
    info = {"arm_contact_penalty": jnp.array([-0.5, -0.5])}
    np.testing.assert_array_equal(env.compute_reward(inside, g, info), [-0.5, -0.5])
    # the Gymnasium/HER convention: an empty info, or one without a term, adds nothing
    for no_pen in (None, {}, {"step": jnp.int32(3)}):
        np.testing.assert_array_equal(env.compute_reward(edge, g, no_pen), [-1.0, 0.0])
    batch = jnp.broadcast_to(edge, (4, 2, 3))
    np.testing.assert_array_equal(env.compute_reward(batch, jnp.zeros((4, 2, 3)), {}),
                                  np.tile([-1.0, 0.0], (4, 1)))
    team = mjx_envs.make("reach", physics="c", team_scale=0.5)
    np.testing.assert_array_equal(team.compute_reward(edge, g), [-1.5, -0.5])
    assert team.reward_range == (-1.5, 0.0)


@pytest.mark.parametrize("physics", ENGINES)
def test_success_metric_is_reward_zero(physics):
    r = rollout(physics)
    env = r.env
    ag, g = r.obs["achieved_goal"][:, 1:], r.obs["desired_goal"][:, 1:]
    rew = np.asarray(env.compute_reward(ag, g))
    np.testing.assert_array_equal(r.metrics["success"], np.all(rew == 0.0, axis=-1))


# -- determinism ----------------------------------------------------------------------------

@pytest.mark.parametrize("physics", ENGINES)
def test_reset_determinism(physics):
    r = rollout(physics)
    s1 = r.vreset(r.keys)
    s2 = r.vreset(r.keys)
    for a, b in zip(jax.tree.leaves(s1), jax.tree.leaves(s2), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    goals = np.asarray(s1.obs["desired_goal"])
    assert len({g.tobytes() for g in goals}) == B
    env = r.env
    lo, hi = np.asarray(env.config.goal_low), np.asarray(env.config.goal_high)
    assert np.all(goals >= lo - 1e-6) and np.all(goals <= hi + 1e-6)


# -- parity ---------------------------------------------------------------------------------

@pytest.mark.mjx
def test_engine_parity_reach():
    c, m = rollout("c"), rollout("mjx")
    np.testing.assert_array_equal(c.obs["desired_goal"], m.obs["desired_goal"])
    diff = np.abs(c.obs["observation"] - m.obs["observation"])
    assert diff.max() < PARITY_TOL_M, diff.max()
    np.testing.assert_array_equal(c.metrics["arm_contact"][ROW_RANDOM],
                                  m.metrics["arm_contact"][ROW_RANDOM])


def test_bad_inputs_raise_clear_errors():
    with pytest.raises(ValueError, match="unknown task"):
        mjx_envs.make("juggle")
    with pytest.raises(ValueError, match="unknown physics"):
        mjx_envs.make("reach", physics="gpu")
    with pytest.raises(ValueError, match="unknown config field"):
        mjx_envs.make("reach", max_detla=0.1)


def test_segment_distance_reference():
    rng = np.random.default_rng(0)
    for _ in range(200):
        p1, q1, p2, q2 = rng.normal(size=(4, 3))
        s = np.linspace(0, 1, 401)
        a = p1 + s[:, None] * (q1 - p1)
        b = p2 + s[:, None] * (q2 - p2)
        brute = np.min(np.linalg.norm(a[:, None] - b[None], axis=-1))
        got = float(obs_lib.segment_distance(np, p1, q1, p2, q2))
        assert got <= brute + 1e-9 and brute - got < 5e-3


# -- scenes and imports -------------------------------------------------------------------------

def test_scenes_load_from_the_package_assets():
    assert {"scene_reach.xml", "scene_push.xml", "scene_pickup.xml",
            "scene_pot.xml"} <= set(model_lib.scenes())
    with model_lib.scene_path("scene_reach.xml") as p:
        assert p.is_file() and p.parent.name == "assets"
    m = model_lib.load_model("scene_push.xml", timestep=0.005, cone="elliptic")
    assert m.opt.timestep == 0.005 and m.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC
    with pytest.raises(FileNotFoundError, match="no_such_scene.xml"):
        model_lib.load_model("no_such_scene.xml")
    with pytest.raises(ValueError, match="cone"):
        model_lib.load_model("scene_reach.xml", cone="round")


@pytest.mark.mjx
def test_mjx_backend_import_prints_no_warp_noise():
    code = ("import mjx_envs\n"
            "env = mjx_envs.make('reach', physics='mjx')\n"
            "assert env.backend.name == 'mjx'\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         timeout=120, env=dict(os.environ, JAX_PLATFORMS="cpu"))
    assert out.returncode == 0, out.stderr[-2000:]
    assert "warp" not in (out.stdout + out.stderr).lower(), out.stdout + out.stderr


def test_render_a_frame_of_a_state(c_env):
    """mjx_envs.render in this process (~1 s): the camera's settings, and a small frame of the
    reset state that shows the scene (skipped where no headless OpenGL can be created)."""
    from mjx_envs import render

    cam = render.make_camera(distance=2.0)
    assert cam.distance == 2.0 and cam.azimuth == render.DEFAULT_CAMERA["azimuth"]
    np.testing.assert_allclose(cam.lookat, render.DEFAULT_CAMERA["lookat"])
    state = c_env.reset(jax.random.PRNGKey(0))
    try:
        img = render.render_state(c_env, state, width=64, height=48)
    except Exception as e:  # noqa: BLE001 (no EGL/OSMesa context on this machine)
        pytest.skip(f"no headless OpenGL here: {e}")
    assert img.shape == (48, 64, 3) and img.dtype == np.uint8 and img.std() > 5
