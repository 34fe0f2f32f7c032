"""Export -> NumPy policy: round trip, parity with the JAX actors, errors, JAX-free imports."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjx_envs
from daddpg_jax.running import checkpoint as ckpt
from daddpg_jax.algo.config import TrainConfig
from daddpg_jax.deploy import FORMAT_VERSION, NumpyPolicy, PolicyFormatError
from daddpg_jax.running.export import ExportError, export_run, export_state
from daddpg_jax.algo.train import make_train_fns
from mjx_envs import observation as obs_lib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ALGOS = ("daddpg", "maddpg", "ddpg", "single")
N_INPUTS = 1000


def tiny_config(algo: str) -> TrainConfig:
    return TrainConfig(algo=algo, hidden=(32, 24), num_envs=2, n_cycles=1, n_batches=1,
                       batch_size=8, buffer_size=200, n_test_episodes=2, seed=7)


def with_random_normalizers(state, seed: int):
    """Non-trivial normalizer statistics (fresh ones are mean 0, std = eps)."""
    rng = np.random.default_rng(seed)

    def rnd(ns):
        shape = ns.mean.shape
        return ns.replace(count=jnp.float32(500.0),
                          mean=jnp.asarray(rng.normal(0, 0.3, shape), jnp.float32),
                          m2=jnp.asarray(rng.uniform(0.01, 40.0, shape), jnp.float32))

    return state.replace(obs_norm=rnd(state.obs_norm), goal_norm=rnd(state.goal_norm))


@pytest.fixture(scope="module")
def env():
    return mjx_envs.make("reach", physics="c")


@pytest.fixture(scope="module")
def exported(env, tmp_path_factory):
    """algo -> (fns, state, path of the export)."""
    out = {}
    d = tmp_path_factory.mktemp("export")
    for i, algo in enumerate(ALGOS):
        cfg = tiny_config(algo)
        fns = make_train_fns(env, cfg)
        state = with_random_normalizers(fns.init(jax.random.PRNGKey(i)), seed=i)
        path = export_state(state, cfg, env, str(d / f"{algo}.npz"))
        out[algo] = (fns, state, path)
    return out


def random_inputs(n: int, seed: int):
    rng = np.random.default_rng(seed)
    o = rng.normal(0.0, 1.0, (n, 2, 25)).astype(np.float32)
    o[: n // 10] *= 300.0  # some beyond clip_obs and the normalizer clip
    g = rng.uniform(-0.5, 0.8, (n, 2, 3)).astype(np.float32)
    return o, g


@pytest.mark.parametrize("algo", ALGOS)
def test_numpy_policy_matches_jax_actors(exported, algo):
    fns, state, path = exported[algo]
    policy = NumpyPolicy.load(path)
    o, g = random_inputs(N_INPUTS, seed=11)
    expected = np.asarray(fns.act(state, jnp.asarray(o), jnp.asarray(g)))
    got = policy.act(o, g)
    assert got.shape == (N_INPUTS, 8) and got.dtype == np.float32
    np.testing.assert_allclose(got, expected, atol=1e-5, rtol=0)
    # unbatched, extra leading axes, per arm
    np.testing.assert_allclose(policy.act(o[3], g[3]), expected[3], atol=1e-5, rtol=0)
    batched = policy.act(o[:60].reshape(3, 20, 2, 25), g[:60].reshape(3, 20, 2, 3))
    np.testing.assert_allclose(batched.reshape(60, 8), expected[:60], atol=1e-5, rtol=0)
    per_arm = policy.act_per_arm(o[:5], g[:5])
    assert per_arm.shape == (5, 2, 4)
    # BLAS may block a 5-row product differently from a 1000-row one: equal to float rounding
    np.testing.assert_allclose(per_arm[:, 0], got[:5, :4], atol=1e-6, rtol=0)
    np.testing.assert_allclose(per_arm[:, 1], got[:5, 4:], atol=1e-6, rtol=0)
    assert np.all(np.abs(got) <= 1.0)


def test_export_round_trip(exported, env):
    fns, state, path = exported["daddpg"]
    with np.load(path, allow_pickle=False) as f:
        files = set(f.files)
        meta = json.loads(str(f["meta"]))
        w0 = f["actor/W0"]
        mean = f["obs_norm/mean"]
    assert {"actor/W0", "actor/b0", "actor/W2", "actor/b2", "obs_norm/mean", "obs_norm/std",
            "goal_norm/mean", "goal_norm/std", "meta"} <= files
    np.testing.assert_array_equal(w0, np.asarray(state.agent.actor["params"]["Dense_0"]["kernel"]))
    assert w0.shape == (2, 2 * (25 + 3), 32)
    np.testing.assert_array_equal(mean, np.asarray(state.obs_norm.mean))
    assert meta["format_version"] == FORMAT_VERSION
    assert meta["task"] == "reach" and meta["algo"] == "daddpg"
    assert meta["layer_sizes"] == [[56, 32], [32, 24], [24, 4]]
    assert meta["obs_layout"] == {k: list(v) for k, v in obs_lib.obs_layout().items()}
    assert meta["normalizer"] == {"clip_obs": 200.0, "norm_clip": 5.0, "norm_eps": 0.01}
    e = meta["env"]
    assert e["dt"] == pytest.approx(env.dt) and e["max_delta"] == env.config.max_delta
    assert np.allclose(e["workspace_low"], env.config.workspace_low)
    assert e["distance_threshold"] == 0.02 and e["lock_fingers"] is True
    assert meta["action"]["max_delta"] == env.config.max_delta
    policy = NumpyPolicy.load(path)
    info = policy.info()
    assert info["format_version"] == FORMAT_VERSION and info["obs_layout"]["grip_pos"] == [0, 3]
    assert policy.obs_layout["finger_vel"] == (23, 25)


def test_bad_inputs_raise_value_error(exported):
    policy = NumpyPolicy.load(exported["maddpg"][2])
    o, g = random_inputs(4, seed=0)
    bad = [
        (o[0, :, :24], g[0]),           # wrong obs size
        (o[0, :1], g[0]),                # one arm
        (o[0], g[0, :, :2]),             # wrong goal size
        (o[0].ravel(), g[0]),            # flat
        (o[:2], g[:3]),                  # batch mismatch
        ([["a"] * 25] * 2, g[0]),        # not numbers
    ]
    for obs, goal in bad:
        with pytest.raises(ValueError):
            policy.act(obs, goal)
    for value in (np.nan, np.inf, -np.inf):
        o2 = o[0].copy()
        o2[1, 5] = value
        with pytest.raises(ValueError, match="NaN or infinite"):
            policy.act(o2, g[0])
        g2 = g[0].copy()
        g2[0, 0] = value
        with pytest.raises(ValueError, match="NaN or infinite"):
            policy.act(o[0], g2)


def test_policy_file_errors(exported, tmp_path):
    with pytest.raises(FileNotFoundError):
        NumpyPolicy.load(tmp_path / "missing.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(PolicyFormatError):
        NumpyPolicy.load(junk)
    with np.load(exported["ddpg"][2], allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files}
    meta = json.loads(str(arrays["meta"]))
    meta["format_version"] = 99
    np.savez(tmp_path / "v99.npz", **{**arrays, "meta": np.array(json.dumps(meta))})
    with pytest.raises(PolicyFormatError, match="format version 99"):
        NumpyPolicy.load(tmp_path / "v99.npz")
    cut = {k: v for k, v in arrays.items() if k != "actor/b1"}
    np.savez(tmp_path / "cut.npz", **cut)
    with pytest.raises(PolicyFormatError, match="actor/b1"):
        NumpyPolicy.load(tmp_path / "cut.npz")


@pytest.fixture(scope="module")
def run_with_checkpoint(env, exported, tmp_path_factory):
    """A run directory holding config.json and checkpoints 1 and 2 (no training)."""
    fns, state, _ = exported["daddpg"]
    cfg = tiny_config("daddpg").replace(physics="c")
    run = str(tmp_path_factory.mktemp("run") / "reach_tiny")
    ckpt.save_config(run, cfg, env_overrides={})
    ckpt.save(run, fns.init(jax.random.PRNGKey(99)), 1)
    ckpt.save(run, state, 2)
    return run, state


def test_export_run_restores_checkpoint(run_with_checkpoint, exported, tmp_path):
    run, state = run_with_checkpoint
    latest = NumpyPolicy.load(export_run(run, str(tmp_path / "latest.npz")))
    first = NumpyPolicy.load(export_run(run, str(tmp_path / "first.npz"), step=1))
    assert latest.meta["source"]["checkpoint_step"] == 2
    assert first.meta["source"]["checkpoint_step"] == 1
    direct = NumpyPolicy.load(exported["daddpg"][2])
    for a, b in zip(latest.weights + latest.biases, direct.weights + direct.biases):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(latest.obs_std, direct.obs_std)
    assert not np.array_equal(first.weights[0], latest.weights[0])
    with pytest.raises(ExportError, match="no checkpoint 5"):
        export_run(run, str(tmp_path / "x.npz"), step=5)


def test_export_cli(run_with_checkpoint, tmp_path):
    run, _ = run_with_checkpoint
    script = os.path.join(ROOT, "experiments", "export.py")
    out = tmp_path / "cli.npz"
    r = subprocess.run([sys.executable, script, run, "--step", "2", "--out", str(out)],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stdout and out.exists()
    assert NumpyPolicy.load(out).meta["source"]["checkpoint_step"] == 2
    # a run without a checkpoint: clear message, non-zero exit, no traceback
    empty = tmp_path / "empty_run"
    ckpt.save_config(str(empty), tiny_config("daddpg"), env_overrides={})
    r = subprocess.run([sys.executable, script, str(empty), "--out", str(tmp_path / "e.npz")],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode != 0
    assert "has no checkpoint" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, script, str(tmp_path / "nowhere"), "--out",
                        str(tmp_path / "e.npz")], capture_output=True, text=True, timeout=300,
                       cwd=ROOT)
    assert r.returncode != 0 and "does not exist" in r.stderr and "Traceback" not in r.stderr


JAX_FREE_SCRIPT = textwrap.dedent("""
    import importlib.abc, sys

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("jax", "jaxlib", "flax", "optax", "orbax", "chex"):
                raise ImportError(f"blocked import of {name}")
            return None

    sys.meta_path.insert(0, Block())
    import numpy as np
    import daddpg_jax.deploy, daddpg_jax.deploy.safety, daddpg_jax.deploy.robot, daddpg_jax.deploy.server
    import mjx_envs.observation, mjx_envs.numpy_env, daddpg_jax.deploy.ur3
    policy = daddpg_jax.deploy.NumpyPolicy.load(sys.argv[1])
    env = mjx_envs.numpy_env.NumpyDualArmEnv(policy.env)
    res = env.reset(np.random.default_rng(0))
    a = policy.act(res.observation, res.desired_goal)
    res = env.step(a)
    bad = [m for m in sys.modules if m.split(".")[0] in ("jax", "jaxlib", "flax", "optax")]
    assert not bad, bad
    try:
        import jax
    except ImportError:
        print("JAX-FREE OK", a.shape)
""")


def test_robot_side_imports_without_jax(exported, tmp_path):
    script = tmp_path / "jax_free.py"
    script.write_text(JAX_FREE_SCRIPT)
    env = dict(os.environ, PYTHONPATH=ROOT)
    r = subprocess.run([sys.executable, str(script), exported["single"][2]], capture_output=True,
                       text=True, timeout=120, cwd=str(tmp_path), env=env)
    assert r.returncode == 0, r.stderr
    assert "JAX-FREE OK (8,)" in r.stdout
