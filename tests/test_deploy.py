"""Export -> NumPy policy: round trip, parity with the JAX actors, errors, older files,
imports without JAX or MuJoCo."""

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
from daddpg_jax import variants
from daddpg_jax.algo.config import TrainConfig
from daddpg_jax.algo.train import make_train_fns
from daddpg_jax.cli import export as export_cli
from daddpg_jax.deploy import FORMAT_VERSION, NumpyPolicy, PolicyFormatError
from daddpg_jax.deploy.policy import env_settings, task_settings
from daddpg_jax.running import checkpoint as ckpt
from daddpg_jax.running.export import ExportError, export_run, export_state
from mjx_envs import observation as obs_lib
from mjx_envs import registry, schema, settings
from tests.conftest import call_main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ALGOS = variants.ALGOS
# the env settings that exports written before every task field was saved hold
FORMAT_1_ENV_KEYS = ("scene", "episode_length", "n_substeps", "timestep", "dt", "cone",
                     "max_delta", "lock_fingers", "locked_opening", "finger_stroke",
                     "distance_threshold", "arm_clearance", "workspace_low", "workspace_high",
                     "goal_low", "goal_high")
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


def _rewrite(path, out, **meta_changes):
    """A copy of the export at ``path`` with ``meta`` entries replaced."""
    with np.load(path, allow_pickle=False) as f:
        arrays = {k: f[k] for k in f.files}
    meta = {**json.loads(str(arrays["meta"])), **meta_changes}
    np.savez(out, **{**arrays, "meta": np.array(json.dumps(meta))})
    return out


def test_policy_reads_its_variant_row(exported, tmp_path):
    for algo in ALGOS:
        policy = NumpyPolicy.load(exported[algo][2])
        row = variants.get(algo)
        assert policy.variant == row and policy.num_agents == row.num_agents
        assert policy.meta["actor_input_dim"] == row.input_dims(25, 3)[0]
        assert policy.weights[-1].shape[-1] == row.agent_action_dim
    # a file whose actors do not fit its algo's row, or an algo without a row
    path = exported["maddpg"][2]
    with pytest.raises(PolicyFormatError, match="actor input size 28, expected 56"):
        NumpyPolicy.load(_rewrite(path, tmp_path / "a.npz", algo="daddpg"))
    with pytest.raises(PolicyFormatError, match="2 agents for algo single"):
        NumpyPolicy.load(_rewrite(path, tmp_path / "b.npz", algo="single"))
    with pytest.raises(PolicyFormatError, match="unknown algo 'td3'"):
        NumpyPolicy.load(_rewrite(path, tmp_path / "c.npz", algo="td3"))


def test_export_saves_every_task_setting(exported, env):
    policy = NumpyPolicy.load(exported["daddpg"][2])
    saved = policy.meta["env"]
    assert set(saved) == set(schema.fields(registry.default_config("reach"))) | {"dt"}
    assert saved == {**schema.to_dict(env.config), "dt": pytest.approx(env.dt)}
    assert policy.env == saved and policy.info()["env"] == saved
    assert task_settings("reach", saved) == env.config


def test_older_export_loads_with_task_defaults(exported, tmp_path):
    """An export written before every task field was saved (format 1, env settings
    FORMAT_1_ENV_KEYS) loads; the fields it lacks come from mjx_envs.settings."""
    path = exported["ddpg"][2]
    full = NumpyPolicy.load(path)
    old_env = {k: full.meta["env"][k] for k in FORMAT_1_ENV_KEYS}
    old_env["max_delta"] = 0.03  # the run's own value wins over the task default
    old = NumpyPolicy.load(_rewrite(path, tmp_path / "old.npz", env=old_env))
    defaults = schema.to_dict(registry.default_config("reach"))
    assert old.meta["env"] == old_env  # the file's own record is left as it is
    assert old.env == {**defaults, **old_env}
    assert old.env["goal_scale"] == defaults["goal_scale"] and old.env["max_delta"] == 0.03
    assert old.info()["env"] == old.env
    o, g = random_inputs(20, seed=3)
    np.testing.assert_array_equal(old.act(o, g), full.act(o, g))
    # a policy file the flat-layout version of the package wrote (tests/data/legacy_reach)
    legacy = NumpyPolicy.load(os.path.join(ROOT, "tests", "data", "legacy_reach", "policy.npz"))
    assert set(legacy.meta["env"]) == set(FORMAT_1_ENV_KEYS)
    # ... with the physics it was trained on (no record: version 1)
    assert legacy.env == {**defaults, "physics_version": 1, **legacy.meta["env"]}
    # no env settings at all: the task's defaults, dt from timestep * n_substeps
    bare = NumpyPolicy.load(_rewrite(path, tmp_path / "bare.npz", env={}))
    assert bare.env == {**defaults, "dt": pytest.approx(0.04)}


def test_env_settings_fill_from_task_defaults(exported, tmp_path):
    push = env_settings("push", {"max_delta": 0.03, "dt": 0.04})
    assert push["scene"] == "scene_push.xml" and push["max_delta"] == 0.03
    assert push["target_radius"] == list(registry.default_config("push").target_radius)
    assert push["dt"] == 0.04  # saved: kept
    assert env_settings("pot", {})["dt"] == pytest.approx(0.005 * 8)
    cfg = task_settings("pickup", {"workspace_low": [[0.1, -0.1, 0.4], [0.1, -0.3, 0.4]]})
    assert isinstance(cfg, settings.ObjectTaskConfig) and cfg.workspace_low[0] == (0.1, -0.1, 0.4)
    assert env_settings("custom", {"dt": 0.1, "x": 1}) == {"dt": 0.1, "x": 1}  # unknown task
    with pytest.raises(ValueError, match="max_delta"):
        env_settings("reach", {"max_delta": -1.0})
    path = exported["daddpg"][2]
    bad = dict(NumpyPolicy.load(path).meta["env"], cone="square")
    with pytest.raises(PolicyFormatError, match="cone"):
        NumpyPolicy.load(_rewrite(path, tmp_path / "bad.npz", env=bad))


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
    # the physics version: the run's record (export_run), this install's (a live state)
    from mjx_envs.settings import PHYSICS_VERSION

    assert latest.meta["physics_version"] == direct.meta["physics_version"] == PHYSICS_VERSION
    assert latest.info()["physics_version"] == PHYSICS_VERSION
    for a, b in zip(latest.weights + latest.biases, direct.weights + direct.biases,
                    strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(latest.obs_std, direct.obs_std)
    assert not np.array_equal(first.weights[0], latest.weights[0])
    with pytest.raises(ExportError, match="no checkpoint 5"):
        export_run(run, str(tmp_path / "x.npz"), step=5)


def test_export_cli(run_with_checkpoint, tmp_path, capsys):
    """daddpg-export's main in this process (~1 s)."""
    run, _ = run_with_checkpoint
    out = tmp_path / "cli.npz"
    assert call_main(export_cli.main, [run, "--step", "2", "--out", out]) == 0
    assert "wrote" in capsys.readouterr().out and out.exists()
    assert NumpyPolicy.load(out).meta["source"]["checkpoint_step"] == 2
    # a run without a checkpoint: clear message, non-zero exit, no traceback
    empty = tmp_path / "empty_run"
    ckpt.save_config(str(empty), tiny_config("daddpg"), env_overrides={})
    assert call_main(export_cli.main, [empty, "--out", tmp_path / "e.npz"]) != 0
    err = capsys.readouterr().err
    assert "has no checkpoint" in err and "Traceback" not in err
    assert call_main(export_cli.main, [tmp_path / "nowhere", "--out", tmp_path / "e.npz"]) != 0
    err = capsys.readouterr().err
    assert "does not exist" in err and "Traceback" not in err


DEPLOY_FREE_SCRIPT = textwrap.dedent("""
    # argv: policy file, "numpy" (block JAX and MuJoCo) or "sim" (block JAX only)
    import importlib, importlib.abc, pkgutil, sys

    mode = sys.argv[2]
    BLOCKED = ("jax", "jaxlib", "flax", "optax", "orbax", "chex")
    BLOCKED += ("mujoco", "mujoco_mjx") if mode == "numpy" else ()

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"blocked import of {name}")
            return None

    sys.meta_path.insert(0, Block())
    import numpy as np
    import daddpg_jax.deploy
    mods = [m.name for m in pkgutil.iter_modules(daddpg_jax.deploy.__path__,
                                                 "daddpg_jax.deploy.")]
    for m in mods + ["mjx_envs.observation", "mjx_envs.settings"]:
        importlib.import_module(m)
    from daddpg_jax.deploy.safety import SafetyLimits
    policy = daddpg_jax.deploy.NumpyPolicy.load(sys.argv[1])
    SafetyLimits.from_env(policy.env)
    rng = np.random.default_rng(0)
    o, g = rng.normal(0, 0.2, (2, 25)), rng.uniform(0.1, 0.5, (2, 3))
    if mode == "sim":
        import mjx_envs.numpy_env
        env = mjx_envs.numpy_env.NumpyDualArmEnv(policy.env, task=policy.task)
        res = env.reset(rng)
        o, g = res.observation, res.desired_goal
    a = policy.act(o, g)
    if mode == "sim":
        env.step(a)
    bad = [m for m in sys.modules if m.split(".")[0] in BLOCKED
           or m.startswith(("daddpg_jax.algo", "daddpg_jax.running"))]
    assert not bad, bad  # the robot side loads nothing of the trainer
    print("OK", mode, ",".join(sorted(mods)), a.shape)
""")


@pytest.mark.parametrize("mode", ["numpy", "sim"])
def test_robot_side_imports_without_jax(exported, tmp_path, mode):
    """Every module of daddpg_jax.deploy imports and the policy acts with NumPy only (neither
    JAX nor MuJoCo importable) and loads nothing of daddpg_jax.algo or daddpg_jax.running;
    with MuJoCo but no JAX, the NumPy simulator steps too."""
    script = tmp_path / "deploy_free.py"
    script.write_text(DEPLOY_FREE_SCRIPT)
    env = dict(os.environ, PYTHONPATH=ROOT)
    r = subprocess.run([sys.executable, str(script), exported["single"][2], mode],
                       capture_output=True, text=True, timeout=120, cwd=str(tmp_path), env=env)
    assert r.returncode == 0, r.stderr
    folder = os.path.join(ROOT, "daddpg_jax", "deploy")
    files = sorted(f[:-3] if f.endswith(".py") else f for f in os.listdir(folder)
                   if (f.endswith(".py") and f != "__init__.py")
                   or os.path.isfile(os.path.join(folder, f, "__init__.py")))
    assert f"OK {mode} {','.join('daddpg_jax.deploy.' + f for f in files)} (8,)" in r.stdout


def test_the_physics_version_is_recorded_and_an_older_run_acts_with_its_own(tmp_path, capsys):
    """config.json, the exported policy and GET /info carry the physics version; a run or a
    policy file of an older version is simulated with that version (an env override), silently;
    simulating it with another version that acts unlike it prints one warning line, reach none
    (~0 s)."""
    from mjx_envs.model import physics_version_note
    from mjx_envs.settings import PHYSICS_VERSION

    run = tmp_path / "run"
    ckpt.save_config(str(run), tiny_config("daddpg"), env_overrides={})
    _, payload = ckpt.load_config(str(run))
    assert payload["physics_version"] == PHYSICS_VERSION
    assert "physics_version" not in payload["env_overrides"]
    assert physics_version_note(PHYSICS_VERSION, "pickup") is None
    assert physics_version_note(None, "reach") is None      # version 2 changed no reach physics
    assert physics_version_note(None, "pickup", simulated=1) is None
    # version 3 changed MJX, and on the C engine only pot: a version-2 pick-up run simulated with
    # version 3 on the C engine acts alike; on MJX (or an engine not named) it may not
    assert physics_version_note(2, "pickup", simulated=3, engine="c") is None
    assert physics_version_note(2, "pot", simulated=3, engine="c") is not None
    assert physics_version_note(2, "pickup", simulated=3, engine="mjx") is not None
    assert physics_version_note(2, "pickup", simulated=3) is not None
    note = physics_version_note(None, "pickup")
    assert note.startswith(f"trained with physics version 1, simulated here with version "
                           f"{PHYSICS_VERSION}")
    old = tmp_path / "old"
    ckpt.save_config(str(old), tiny_config("daddpg").replace(task="pickup"), env_overrides={})
    path = old / "config.json"
    payload = json.loads(path.read_text())
    del payload["physics_version"]
    path.write_text(json.dumps(payload))
    for _ in range(2):
        _, payload = ckpt.load_config(str(old))
        assert payload["env_overrides"] == {"physics_version": 1}
        ckpt.physics_note(str(old), payload, "pickup")     # its own version: nothing to say
    assert capsys.readouterr().err == ""
    for _ in range(2):
        ckpt.physics_note(str(old), payload, "pickup", simulated=PHYSICS_VERSION)
    err = capsys.readouterr().err
    assert err.count("warning:") == 1 and note in err
    # resumed, it keeps its version: the override and the record say 1
    ckpt.save_config(str(old), tiny_config("daddpg").replace(task="pickup"),
                     env_overrides=payload["env_overrides"])
    assert json.loads(path.read_text())["physics_version"] == 1
    legacy = NumpyPolicy.load(os.path.join(ROOT, "tests", "data", "legacy_reach", "policy.npz"))
    assert legacy.info()["physics_version"] == 1
    assert legacy.env["physics_version"] == 1       # its simulator builds version 1's scene
