"""Observation and action perturbations (mjx_envs/perturb.py): each field changes what it names
and nothing else, off by default, the same code on NumPy and JAX (robot client = trainer), and
evaluation over a perturbation grid."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjx_envs
from daddpg_jax.algo import acting
from mjx_envs import perturb, registry, rules, wrappers
from mjx_envs.observation import obs_layout

L = obs_layout()
T, N = 12, 4
POSITIONS = ("grip_pos", "object_pos", "object_rel_pos")


def _cols(*names):
    return np.concatenate([np.arange(*L[n]) for n in names])


OTHER = np.setdiff1d(np.arange(perturb.OBS_SIZE), _cols(*POSITIONS))


def _actions(seed=0):
    return np.asarray(np.random.default_rng(seed).uniform(-1, 1, (T, N, 8)), np.float32)


_RUNS: dict = {}


def _run(actions=None, task="push", **over):
    """(reset states, per-step states) of N C-engine envs of `task` under `over`, fixed keys;
    compiled once per config."""
    over = {"episode_length": T, **over}
    key = (task, tuple(sorted(over.items())))
    if key not in _RUNS:
        env = mjx_envs.make(task, physics="c", **over)
        _RUNS[key] = jax.jit(lambda ks, xs: acting.rollout(env, lambda s, a: a, ks, xs=xs))
    keys = jax.random.split(jax.random.PRNGKey(3), N)
    s0, tr = _RUNS[key](keys, jnp.asarray(_actions() if actions is None else actions))
    return jax.device_get(s0), jax.device_get(tr)


def _obs(s0, tr):
    """[T + 1, N, 2, OBS] observations the policy saw."""
    return np.concatenate([s0.obs["observation"][None], tr.obs["observation"]], 0)


@pytest.fixture(scope="module")
def nominal():
    return _run()


def test_off_by_default_and_nothing_carried():
    for task in registry.TASKS:
        cfg = registry.default_config(task)
        assert not perturb.Perturbation.from_config(cfg).active
        assert all(getattr(cfg, f) == 0 for f in perturb.FIELDS) and not cfg.perturb_exact
        assert cfg.action_history == 0
    env = mjx_envs.make("reach", physics="c")
    s = env.reset(jax.random.PRNGKey(0))
    assert "perturb" not in s.info and "action_history" not in s.info
    assert env.obs_size == perturb.OBS_SIZE == 25
    assert registry.test_overrides("reach")["latency"] == 0
    assert isinstance(registry.test_overrides("reach")["obs_period"], int)


def test_reach_object_terms_stay_zero_under_every_perturbation():
    s0, tr = _run(task="reach", obs_noise=0.02, obs_bias=0.02, obs_dropout=0.5)
    obs = _obs(s0, tr)
    for name in ("object_pos", "object_rel_pos", "object_velp"):
        assert not np.any(obs[..., slice(*L[name])]), name
    assert np.any(obs[..., slice(*L["grip_pos"])] != _obs(*_run(task="reach"))[
        ..., slice(*L["grip_pos"])])


def _same_truth(a, b):
    """The true state (achieved goals, rewards, qpos) of two runs is the same."""
    (a0, at), (b0, bt) = a, b
    np.testing.assert_array_equal(at.obs["achieved_goal"], bt.obs["achieved_goal"])
    np.testing.assert_array_equal(at.reward, bt.reward)
    np.testing.assert_array_equal(at.obs["desired_goal"], bt.obs["desired_goal"])
    np.testing.assert_array_equal(a0.obs["achieved_goal"], b0.obs["achieved_goal"])


def test_noise_moves_the_positions_only(nominal):
    run = _run(obs_noise=0.01, perturb_exact=True)
    _same_truth(run, nominal)
    o, o_nom = _obs(*run), _obs(*nominal)
    np.testing.assert_array_equal(o[..., OTHER], o_nom[..., OTHER])
    d = o[..., _cols("grip_pos", "object_pos")] - o_nom[..., _cols("grip_pos", "object_pos")]
    assert 0.008 < d.std() < 0.012 and abs(d.mean()) < 0.002
    rel = o[..., slice(*L["object_pos"])] - o[..., slice(*L["grip_pos"])]
    np.testing.assert_allclose(o[..., slice(*L["object_rel_pos"])], rel, atol=1e-6)


def test_bias_is_one_offset_of_the_object_per_episode(nominal):
    run = _run(obs_bias=0.03, perturb_exact=True)
    _same_truth(run, nominal)
    o, o_nom = _obs(*run), _obs(*nominal)
    np.testing.assert_array_equal(o[..., slice(*L["grip_pos"])], o_nom[..., slice(*L["grip_pos"])])
    off = o[..., slice(*L["object_pos"])] - o_nom[..., slice(*L["object_pos"])]   # [T+1, N, 2, 3]
    np.testing.assert_allclose(off, np.broadcast_to(off[:1, :, :1], off.shape), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(off, axis=-1), 0.03, atol=1e-5)
    assert len({tuple(np.round(off[0, i, 0], 5)) for i in range(N)}) == N   # per episode


def test_dropout_holds_the_object_observation(nominal):
    run = _run(obs_dropout=1.0, perturb_exact=True)
    _same_truth(run, nominal)
    o, o_nom = _obs(*run), _obs(*nominal)
    obj = _cols(*perturb.OBJECT_FIELDS)
    first = np.broadcast_to(o_nom[:1][..., obj], o[..., obj].shape)
    np.testing.assert_array_equal(o[..., obj], first)
    np.testing.assert_array_equal(o[..., slice(*L["grip_pos"])], o_nom[..., slice(*L["grip_pos"])])
    held = o[..., slice(*L["object_pos"])] - o[..., slice(*L["grip_pos"])]
    np.testing.assert_allclose(o[..., slice(*L["object_rel_pos"])], held, atol=1e-6)
    assert np.abs(o_nom[..., obj] - o_nom[:1][..., obj]).max() > 0   # the truth moved
    # dropout 0.5: some steps hold, some do not
    o_half = _obs(*_run(obs_dropout=0.5, perturb_exact=True))
    fresh = np.all(o_half[1:][..., obj] == o_nom[1:][..., obj], axis=(-1, -2))
    assert 0.2 < fresh.mean() < 0.8


def test_period_holds_the_whole_observation(nominal):
    run = _run(obs_period=3, perturb_exact=True)
    _same_truth(run, nominal)
    o, o_nom = _obs(*run), _obs(*nominal)
    for t in range(T + 1):
        np.testing.assert_array_equal(o[t], o_nom[t - t % 3])


def test_latency_applies_actions_late(nominal):
    a = _actions()
    late = _run(latency=2, perturb_exact=True)
    shifted = np.concatenate([np.zeros((2, N, 8), np.float32), a[:-2]], 0)
    ref = _run(actions=shifted)
    _same_truth(late, ref)
    np.testing.assert_array_equal(_obs(*late), _obs(*ref))


def test_action_history_appends_the_chosen_actions_and_changes_nothing_else():
    """action_history = 2 under one step of latency: each arm's observation ends with its own
    last two actions as chosen (clipped, not yet applied; zeros before the first), and the
    first 25 values and the true state are those of the env without the history."""
    k, n = 2, perturb.OBS_SIZE
    a = 1.2 * _actions()                                      # some values out of range
    ref = _run(actions=a, latency=1, perturb_exact=True)
    hist = _run(actions=a, latency=1, perturb_exact=True, action_history=k)
    _same_truth(hist, ref)
    o = _obs(*hist)
    assert o.shape == (T + 1, N, 2, n + 4 * k)
    np.testing.assert_array_equal(o[..., :n], _obs(*ref))
    past = o[..., n:].reshape(T + 1, N, 2, k, 4)
    chosen = np.clip(a, -1, 1).reshape(T, N, 2, 4)
    np.testing.assert_array_equal(past[0], 0.0)
    np.testing.assert_array_equal(past[1:, :, :, 0], chosen)
    np.testing.assert_array_equal(past[1, :, :, 1], 0.0)
    np.testing.assert_array_equal(past[2:, :, :, 1], chosen[:-1])
    env = mjx_envs.make("push", physics="c", action_history=k)
    assert env.obs_size == n + 4 * k
    assert obs_layout(k)["action_history"] == (n, n + 4 * k)
    assert registry.test_overrides("push").get("action_history") is None   # kept in tests


def test_training_draws_differ_between_envs_within_the_bounds():
    env = mjx_envs.make("push", physics="c", obs_noise=0.02, obs_dropout=0.5, obs_bias=0.05,
                        obs_period=4, latency=3)
    s = jax.device_get(jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 64)))
    p = s.info["perturb"]
    for name, hi in (("noise", 0.02), ("dropout", 0.5)):
        assert np.all((p[name] >= 0) & (p[name] <= hi)) and len(np.unique(p[name])) == 64
    assert np.all(np.linalg.norm(p["bias"], axis=-1) <= 0.05 + 1e-6)
    assert set(np.unique(p["latency"])) == {0, 1, 2, 3}
    assert set(np.unique(p["period"])) == {1, 2, 3, 4}
    # the task's own draws are unchanged: goals equal the unperturbed env's
    s0 = jax.jit(jax.vmap(mjx_envs.make("push", physics="c").reset))(
        jax.random.split(jax.random.PRNGKey(0), 64))
    np.testing.assert_array_equal(s.obs["desired_goal"], np.asarray(s0.obs["desired_goal"]))


class _FixedSampler:
    """The same 'random' numbers for NumPy and JAX: a function of the shape and the call."""

    def __init__(self, xp):
        self.xp, self.calls = xp, 0

    def split(self, key, num):
        return (key,) * num

    def _base(self, shape):
        self.calls += 1
        n = int(np.prod(shape)) if shape else 1
        v = np.sin(np.arange(n, dtype=np.float32) * 1.7 + self.calls).reshape(shape)
        return self.xp.asarray(v, self.xp.float32)

    def uniform(self, key, shape, low, high):
        return low + (high - low) * (self._base(shape) + 1) / 2

    def normal(self, key, shape):
        return 2 * self._base(shape)


@pytest.mark.parametrize("exact", [False, True])
def test_numpy_and_jax_give_the_same_perturbations(exact):
    """The robot client (NumPy) and the trainer (jax.numpy) run the same functions."""
    p = perturb.Perturbation(obs_noise=0.01, obs_dropout=0.6, obs_bias=0.02, obs_period=2,
                             latency=2, exact=exact)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(6, 2, perturb.OBS_SIZE)).astype(np.float32)
    acts = rng.uniform(-1, 1, (6, 8)).astype(np.float32)
    out = {}
    for xp in (np, jnp):
        smp = _FixedSampler(xp)
        seen, carry = perturb.start(xp, smp, None, p, xp.asarray(obs[0]))
        seq = [np.asarray(seen)]
        for t in range(1, 6):
            a, carry = perturb.delay(xp, p, carry, xp.asarray(acts[t]))
            seen, carry = perturb.observe(xp, smp, None, p, carry, xp.asarray(obs[t]))
            seq += [np.asarray(a), np.asarray(seen)]
        out[xp.__name__] = seq
    for a, b in zip(out["numpy"], out["jax.numpy"], strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6)


@pytest.mark.parametrize("history", [0, 2])
def test_robot_client_perturbations_match_the_trainer(tmp_path, history):
    """Sim-to-sim end to end: the client loop (NumPy env, served policy, --perturb latency and
    period) reproduces the trainer env's rollout with the same perturbations; with an action
    history it sends the same remembered actions."""
    from daddpg_jax.algo.config import TrainConfig
    from daddpg_jax.algo.train import make_train_fns
    from daddpg_jax.deploy import NumpyPolicy, robot
    from daddpg_jax.deploy.safety import SafetyFilter, SafetyLimits
    from daddpg_jax.deploy.server import PolicyClient, PolicyServer
    from daddpg_jax.running.export import _env_settings, export_state
    from mjx_envs.numpy_env import NumpyDualArmEnv

    pert = dict(latency=2, obs_period=3)
    env = mjx_envs.make("reach", physics="c", **pert, perturb_exact=True, action_history=history)
    cfg = TrainConfig(hidden=(16, 16), num_envs=2, n_cycles=1, n_batches=1, batch_size=8,
                      buffer_size=200, n_test_episodes=2, seed=5)
    fns = make_train_fns(env, cfg)
    state = fns.init(jax.random.PRNGKey(5))
    s = jax.jit(env.reset)(jax.random.PRNGKey(42))
    step = jax.jit(env.step)
    for _ in range(env.episode_length):
        s = step(s, fns.act(state, s.obs["observation"], s.obs["desired_goal"]))
    path = export_state(state, cfg, env, str(tmp_path / "p.npz"))
    settings_ = _env_settings(env)
    policy = NumpyPolicy.load(path)
    assert policy.obs_size == env.obs_size == 25 + 4 * history
    assert ("action_history" in policy.obs_layout) == bool(history)
    srv = PolicyServer(policy, port=0).start()
    try:
        client = PolicyClient(srv.url, timeout=5.0)
        safety = SafetyFilter(SafetyLimits.from_env(settings_, min_clearance=-1e9,
                                                    deadline_s=5.0))
        with pytest.warns(UserWarning, match="simulates true observations"):
            np_env = NumpyDualArmEnv(settings_)
        p = perturb.Perturbation(**pert, exact=True, has_object=False)   # reach
        out = robot.run_episode(np_env, client, safety, goal=np.asarray(s.obs["desired_goal"]),
                                perturbation=p)
        client.close()
    finally:
        srv.stop()
    assert out["stops"] == 0
    np.testing.assert_allclose(np_env._result().achieved_goal, np.asarray(s.obs["achieved_goal"]),
                               atol=1e-4)
    # and without the perturbation the episode ends elsewhere
    assert wrappers.find(env, wrappers.Perturb).perturbation.active


LEGACY = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "legacy_reach", "run")


@pytest.mark.e2e
def test_evaluation_grid_is_deterministic_and_written(tmp_path):
    from daddpg_jax.analysis import evaluation, perturbation
    from daddpg_jax.cli import evaluate as cli

    run = tmp_path / "run"
    shutil.copytree(LEGACY, run)
    policy = evaluation.load_policy(str(run))
    grid = perturbation.parse_grid("reach", ["obs_noise=0,0.02", "latency=0,1"])
    assert grid == {"obs_noise": [0.0, 0.02], "latency": [0, 1]}
    rows = perturbation.evaluate_grid(policy, grid, episodes=6, seed=1)
    again = perturbation.evaluate_grid(policy, grid, episodes=6, seed=1)
    assert rows == [dict(r, eval_seconds=a["eval_seconds"]) for r, a in zip(again, rows,
                                                                          strict=True)]
    assert [(r["obs_noise"], r["latency"]) for r in rows] == [(0, 0), (0, 1), (0.02, 0),
                                                               (0.02, 1)]
    plain, _ = evaluation.evaluate(policy, 6, 1)
    assert rows[0]["success_rate"] == plain["success_rate"]
    assert rows[0]["final_distance_left"] == pytest.approx(plain["final_distance_mean"]["left"])
    assert rows[1]["final_distance_left"] != rows[0]["final_distance_left"]

    out = tmp_path / "grid"
    rc = cli.main([str(run), "--episodes", "4", "--perturb", "obs_dropout=0,0.5", "--out",
                   str(out)])
    assert rc == 0
    data = json.loads((out / "perturbation.json").read_text())
    assert len(data["rows"]) == 2 and data["grid"] == {"obs_dropout": [0.0, 0.5]}
    assert (out / "perturbation.png").stat().st_size > 1000
    assert (out / "perturbation.csv").read_text().startswith("obs_dropout,success_rate,")
    assert cli.main([str(run), "--perturb", "gravity=1"]) == 2   # needs --out
    assert cli.main([str(run), "--perturb", "gravity=1", "--out", str(out)]) == 2


@pytest.mark.parametrize("items, match", [
    (["gravity=0,1"], "not a perturbation"),
    (["obs_noise=-1"], "obs_noise"),
    (["obs_dropout=0,2"], "obs_dropout"),
    (["latency=0.5"], "latency"),
    (["latency"], "KEY=V1,V2"),
    (["latency=0", "latency=1"], "twice"),
])
def test_grid_errors(items, match):
    from daddpg_jax.analysis import perturbation
    from mjx_envs.schema import ConfigError

    with pytest.raises(ConfigError, match=match):
        perturbation.parse_grid("push", items)


def test_eval_env_drops_training_perturbations():
    from daddpg_jax.algo.config import build_config
    from daddpg_jax.running.runner import make_eval_env

    cfg = build_config("push").replace(physics="c")
    ev = make_eval_env(cfg, {"obs_noise": 0.01, "latency": 2})
    assert wrappers.find(ev, wrappers.Perturb) is None
    assert make_eval_env(cfg, {}) is None
    # rules' samplers both draw normals
    assert rules.NumpySampler.normal(np.random.default_rng(0), (3,)).dtype == np.float32
    assert dataclasses.asdict(perturb.Perturbation())["latency"] == 0


def test_rollout_cache_never_serves_a_dead_env_s_program(monkeypatch):
    """Default tier, < 0.1 s. The compiled-rollout cache is keyed per live object: a grid builds
    one env per point and drops it, and CPython hands a dropped object's id() to the next one;
    keyed on bare ids, a grid point got an earlier point's rollout (its rows then depended on
    allocation order). Whether CPython reuses a given address depends on the allocator's state,
    so the cache's ``id`` is replaced here by a tag that the test hands out again on purpose."""
    import builtins

    from daddpg_jax.analysis import evaluation
    from daddpg_jax.analysis.evaluation import IdentityCache

    class Env:
        def __init__(self, tag):
            self.tag = tag

    monkeypatch.setattr(evaluation, "id", lambda o: getattr(o, "tag", builtins.id(o)),
                        raising=False)
    cache, built = IdentityCache(), []

    def build(tag):
        return lambda: built.append(tag) or tag

    act = Env(1)
    first = Env(7)
    assert cache.get((first, act), 8, build("first")) == "first"
    assert cache.get((first, act), 8, build("again")) == "first"    # same objects: a hit
    assert cache.get((first, act), 4, build("n=4")) == "n=4"        # other key: a miss
    del first                                                       # freed by its refcount
    assert len(cache) == 0                                          # dropped with its env
    second = Env(7)                                                 # the dead one's "id"
    assert cache.get((second, act), 8, build("second")) == "second"  # not "first"
    third = Env(7)   # the same "id" while `second` lives: its entry is not served either
    assert cache.get((third, act), 8, build("third")) == "third"
    assert cache.get((third, act), 8, build("again")) == "third"
    assert built == ["first", "n=4", "second", "third"]
