"""Training loop on the toy env: determinism, compile count, checkpoints, progress, learning."""

import os
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from daddpg_jax import variants
from daddpg_jax.algo import replay
from daddpg_jax.algo.train import (
    ROLLOUT_DONE,
    UPDATES_DONE,
    EpochHooks,
    StageClock,
    make_train_fns,
)
from daddpg_jax.running import checkpoint as ckpt
from tests import toy_env
from tests.conftest import LEARN, LEARN_ENV, TINY, T, tree_equal


@pytest.fixture(scope="module")
def env():
    return toy_env.make(episode_length=T)


@pytest.fixture(scope="module")
def fns(env):
    return make_train_fns(env, TINY)


@pytest.fixture(scope="module")
def two_epochs(fns):
    """(state after 1 epoch, metrics 1, state after 2 epochs, metrics 2) from seed 0."""
    s1, m1 = fns.train_epoch(fns.init())
    s1_copy = jax.tree.map(jnp.copy, s1)   # train_epoch donates its argument
    s2, m2 = fns.train_epoch(s1)
    return s1_copy, m1, s2, m2


def test_epoch_metrics_and_counters(fns, two_epochs):
    s1, m1, s2, m2 = two_epochs
    n = TINY.n_cycles
    for k in ("success", "arm_contact", "nonfinite", "cycle"):
        assert m1[k].shape == (n,), k
    for k in ("critic_loss", "actor_loss", "mean_q", "final_distance"):
        assert m1[k].shape == (n, 2), k
    assert not np.any(m1["nonfinite"]) and not np.any(m2["nonfinite"])
    np.testing.assert_array_equal(m2["cycle"], np.arange(n + 1, 2 * n + 1))
    assert int(s2.cycles) == 2 * n and int(s2.updates) == 2 * n * TINY.n_batches
    assert fns.env_steps(s2) == 2 * n * TINY.num_envs * T
    np.testing.assert_array_equal(m1["buffer_episodes"], TINY.num_envs * np.arange(1, n + 1))
    assert float(s2.obs_norm.count) == 2 * n * TINY.num_envs * T


def test_train_epoch_compiles_once(fns, two_epochs):
    s2 = two_epochs[2]
    s3, _ = fns.train_epoch(jax.tree.map(jnp.copy, s2))
    assert fns.train_epoch._cache_size() == 1


def test_same_seed_same_metrics(fns, two_epochs):
    _, m1, _, _ = two_epochs
    _, m1b = fns.train_epoch(fns.init())
    for k in m1:
        np.testing.assert_array_equal(m1[k], m1b[k], err_msg=k)
    _, m_other = fns.train_epoch(fns.init(jax.random.PRNGKey(1)))
    assert not np.array_equal(m1["critic_loss"], m_other["critic_loss"])


def test_evaluate_is_deterministic_and_shaped(fns, two_epochs):
    s1 = two_epochs[0]
    e1, e2 = fns.evaluate(s1), fns.evaluate(s1)
    assert tree_equal(e1, e2)
    assert e1["final_distance"].shape == (2,)
    assert 0.0 <= float(e1["success"]) <= 1.0 and 0.0 <= float(e1["arm_contact"]) <= 1.0
    # success is measured on n_test_episodes episodes (resolution 1/n)
    n_success = float(e1["success"]) * TINY.n_test_episodes
    assert n_success == pytest.approx(round(n_success))


def test_rollout_episode_layout(fns, two_epochs, env):
    s1 = two_epochs[0]
    eps, tr = fns.rollout(s1, jax.random.PRNGKey(0), 3, False)
    assert eps.obs.shape == (3, T + 1, 2, env.obs_size) and eps.ag.shape == (3, T + 1, 2, 3)
    assert eps.g.shape == (3, T, 2, 3) and eps.actions.shape == (3, T, 8)
    assert eps.info["arm_contact_penalty"].shape == (3, T, 2)
    # slot 0 is the reset observation; stored rewards recompute exactly
    s0 = jax.vmap(env.reset)(jax.random.split(jax.random.split(jax.random.PRNGKey(0))[0], 3))
    np.testing.assert_array_equal(eps.obs[:, 0], s0.obs["observation"])
    ep = jnp.repeat(jnp.arange(3), T)
    t = jnp.tile(jnp.arange(T), 3)
    out = replay.her_transitions(jax.random.PRNGKey(0), eps, ep, t, "none", 0.0,
                                 env.compute_reward)
    np.testing.assert_allclose(out["r"], jnp.swapaxes(tr["reward"], 0, 1).reshape(3 * T, 2),
                               atol=1e-6)
    # deterministic actions equal `act`
    a = fns.act(s1, eps.obs[:, 0], eps.g[:, 0])
    np.testing.assert_allclose(a, eps.actions[:, 0], atol=1e-6)


def test_checkpoint_round_trip_and_resume(fns, two_epochs, tmp_path):
    s1, _, s2, m2 = two_epochs
    run = tmp_path / "run"
    ckpt.save(run, s1, step=1, save_buffer=True)
    restored, step = ckpt.restore(run, fns.init(jax.random.PRNGKey(99)))
    assert step == 1 and tree_equal(restored, s1)
    # 1 epoch + resume + 1 epoch == 2 epochs (buffer saved)
    r2, rm2 = fns.train_epoch(restored)
    assert fns.train_epoch._cache_size() == 1   # a restored state does not trigger a recompile
    assert tree_equal(r2, s2)
    for k in m2:
        np.testing.assert_array_equal(m2[k], rm2[k], err_msg=k)


def test_checkpoint_without_buffer_and_keep_last(fns, two_epochs, tmp_path):
    s1 = two_epochs[0]
    run = tmp_path / "run"
    for step in range(1, 6):
        ckpt.save(run, s1, step=step, save_buffer=False, keep=2)
    assert ckpt.all_steps(run) == [4, 5]
    template = fns.init(jax.random.PRNGKey(7))
    restored, step = ckpt.restore(run, template)
    assert step == 5
    assert tree_equal(restored.agent, s1.agent) and tree_equal(restored.obs_norm, s1.obs_norm)
    assert tree_equal(restored.buffer, template.buffer)   # fresh buffer kept
    assert int(restored.cycles) == int(s1.cycles)
    with pytest.raises(FileNotFoundError):
        ckpt.restore(run, template, restore_buffer=True)
    ckpt.save_config(run, TINY, env_overrides={"episode_length": T})
    cfg, payload = ckpt.load_config(run)
    assert cfg == TINY and payload["env_overrides"] == {"episode_length": T}
    assert "jax" in payload["versions"]
    # the host is recorded: the same seed may round differently on another CPU model
    assert payload["host"]["cpu"] and payload["host"]["cores"] == os.cpu_count()


class _Hooks(EpochHooks):
    """Records every hook call."""

    def __init__(self):
        self.cycles, self.stages = [], []

    def cycle(self, m):
        self.cycles.append(int(m["cycle"]))

    def stage(self, stage):
        self.stages.append(int(stage))


@pytest.mark.e2e  # ~7-15 s: kept out of the default tier's 5 minutes
def test_hooks_per_cycle_and_stage_marks_leave_the_numbers_unchanged(env):
    """The hooks' callbacks (per cycle; rollout/updates stage marks) run at their places, in
    program order, and change no number. ~3 s."""
    cfg = TINY.replace(n_cycles=2)
    hooks = _Hooks()
    f, plain = make_train_fns(env, cfg, hooks=hooks), make_train_fns(env, cfg)
    s, m = f.train_epoch(f.init())
    s0, m0 = plain.train_epoch(plain.init())
    jax.block_until_ready(s)
    jax.effects_barrier()
    assert sorted(hooks.cycles) == [1, 2]
    assert hooks.stages == [ROLLOUT_DONE, UPDATES_DONE] * 2
    assert tree_equal(s, s0) and tree_equal(m, m0)


@pytest.mark.e2e  # ~7-15 s: kept out of the default tier's 5 minutes
def test_stage_clock_splits_the_epoch_between_rollouts_and_updates(env):
    """StageClock as the stage hook: both sums positive and within the epoch's seconds. ~2 s."""
    clock = StageClock()
    f = make_train_fns(env, TINY.replace(n_cycles=2), hooks=clock)
    s = f.init()
    s, _ = f.train_epoch(s)       # compiles
    jax.block_until_ready(s)
    t0 = time.perf_counter()
    clock.start()
    s, _ = f.train_epoch(s)
    jax.block_until_ready(s)
    epoch_s = time.perf_counter() - t0
    assert 0 < clock.rollout_s and 0 < clock.update_s
    assert clock.rollout_s + clock.update_s <= epoch_s


def test_nonfinite_flag(fns):
    s = fns.init()
    nan_critic = jax.tree.map(lambda x: x * jnp.nan, s.agent.critic)
    bad = s.replace(agent=s.agent.replace(critic=nan_critic))
    _, m = fns.train_epoch(bad)
    assert np.all(m["nonfinite"])


@pytest.mark.parametrize("algo", ["maddpg", "ddpg", "single"])
def test_variants_run(env, algo):
    cfg = TINY.replace(algo=algo, n_cycles=1, n_batches=2, n_test_episodes=4)
    f = make_train_fns(env, cfg)
    s, m = f.train_epoch(f.init())
    assert not np.any(m["nonfinite"])
    n_agents = variants.get(algo).num_agents
    assert n_agents == (1 if algo == "single" else 2)
    assert m["critic_loss"].shape == (1, n_agents)
    assert f.act(s, jnp.zeros((5, 2, env.obs_size)), jnp.zeros((5, 2, 3))).shape == (5, 8)


def test_n_step_training_runs_and_differs(env):
    base = TINY.replace(n_cycles=2, n_batches=2, n_test_episodes=4)
    f1, f0 = make_train_fns(env, base.replace(n_step=3)), make_train_fns(env, base)
    _, m1 = f1.train_epoch(f1.init())
    _, m0 = f0.train_epoch(f0.init())
    assert np.all(np.isfinite(np.asarray(m1["critic_loss"])))
    # the first cycle collects the same data (n-step draws no extra randomness); the targets
    # and so the losses differ
    np.testing.assert_array_equal(m1["episode_return"][0], m0["episode_return"][0])
    assert not np.allclose(np.asarray(m1["critic_loss"]), np.asarray(m0["critic_loss"]))


def test_learns_toy_reach():
    f = make_train_fns(toy_env.make(**LEARN_ENV), LEARN)
    s = f.init()
    before = float(f.evaluate(s)["success"])
    rates = []
    for _ in range(6):
        s, m = f.train_epoch(s)
        assert not np.any(m["nonfinite"])
        rates.append(float(f.evaluate(s)["success"]))
    print("toy reach eval success", before, rates)
    assert max(rates[-2:]) >= before + 0.5, (before, rates)


def test_evaluation_runs_on_the_eval_env():
    """make_train_fns(eval_env=...): test episodes are played in that env (the runner passes
    the task without its training-only options), training episodes in `env`."""
    env = toy_env.make(episode_length=T, threshold=1e-6)          # nothing ever succeeds
    easy = toy_env.make(episode_length=T, threshold=10.0)         # everything succeeds
    f = make_train_fns(env, TINY)
    g = make_train_fns(env, TINY, eval_env=easy)
    s = f.init()
    assert float(f.evaluate(s)["success"]) == 0.0
    assert float(g.evaluate(s)["success"]) == 1.0
    _, m = g.train_epoch(g.init())
    assert float(np.max(m["success"])) == 0.0


def test_eval_env_is_the_standard_task():
    """The runner's evaluation env switches the training-only task options off, and is not
    built when none is on."""
    from daddpg_jax.algo.config import build_config
    from daddpg_jax.running.runner import make_eval_env
    from mjx_envs import settings

    cfg = build_config("pickup").replace(physics="c")
    assert make_eval_env(cfg, {}) is None
    assert make_eval_env(cfg.replace(task="reach"), {}) is None
    ev = make_eval_env(cfg, {"goal_rest_fraction": 0.5, "team_scale": 0.5})
    for name in settings.TRAINING_ONLY_FIELDS:
        assert getattr(ev.config, name) == 0.0
    assert ev.config.team_scale == 0.5
