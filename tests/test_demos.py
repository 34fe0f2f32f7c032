"""Demonstrations (TrainConfig.n_demos): the demo buffer played at init, the behaviour-cloning
term with its Q filter, checkpoints, and the scripted pick-up demos on the C engine."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mjx_envs
from daddpg_jax import variants
from daddpg_jax.algo import losses as agent_lib
from daddpg_jax.algo import networks as nets
from daddpg_jax.algo.config import TrainConfig, preset
from daddpg_jax.algo.train import make_train_fns
from daddpg_jax.running import checkpoint as ckpt
from tests import toy_env
from tests.conftest import HIDDEN, OBS, TINY, T, random_batch, run_options, tree_equal

N_DEMOS = 6
DEMO = TINY.replace(n_demos=N_DEMOS, demo_batch=16)


def toy_demo_policy(obs):
    """Straight to the goal at full speed: solves the toy reach in a few steps."""
    grip = obs["observation"][..., :3]
    a = jnp.clip((obs["desired_goal"] - grip) / 0.05, -1.0, 1.0)
    a = jnp.concatenate([a, jnp.zeros(a.shape[:-1] + (1,))], -1)
    return a.reshape(a.shape[:-2] + (8,))


@pytest.fixture(scope="module")
def env():
    return toy_env.make(episode_length=T)


@pytest.fixture(scope="module")
def demo_fns(env):
    return make_train_fns(env, DEMO, demo_policy=toy_demo_policy)


@pytest.fixture(scope="module")
def demo_epoch(demo_fns):
    s0 = demo_fns.init()
    s0_copy = jax.tree.map(jnp.copy, s0)     # train_epoch donates its argument
    s1, m1 = demo_fns.train_epoch(s0)
    return s0_copy, s1, m1


# --- the loss ------------------------------------------------------------------------------

@pytest.mark.parametrize("algo", ["daddpg", "single"])
def test_bc_loss_matches_numpy(algo):
    n_agents = variants.get(algo).num_agents
    batch = random_batch(jax.random.PRNGKey(3), n_agents)
    demo = np.zeros(batch["a"].shape[0], bool)
    demo[5:] = True
    batch["demo"] = jnp.asarray(demo)
    for q_filter in (False, True):
        cfg = TrainConfig(algo=algo, hidden=HIDDEN, n_demos=1, bc_weight=2.5,
                          q_filter=q_filter)
        learner = agent_lib.make_learner(cfg, (-1.05, 0.0))
        st = agent_lib.init_agent_state(jax.random.PRNGKey(0), learner, HIDDEN, OBS)
        pi = np.asarray(agent_lib.policy_actions(learner, st.actor, batch["o"], batch["g"]))
        a = np.asarray(batch["a"])
        own = a[None] if algo == "single" else a.reshape(-1, 2, 4).transpose(1, 0, 2)
        err = ((pi - own) ** 2).sum(-1)                                   # [A, B]
        if q_filter:
            mask = np.asarray(nets.own_action_mask(algo))
            mixed = np.where(mask[:, None, :], np.tile(pi, (1, 1, 8 // pi.shape[-1])), a[None])
            q_pi = np.asarray(agent_lib.q_values(learner, st.critic, batch["o"], batch["g"],
                                                 mixed))
            q_demo = np.asarray(agent_lib.q_values(learner, st.critic, batch["o"], batch["g"],
                                                   np.broadcast_to(a, (n_agents,) + a.shape)))
            keep = (q_demo > q_pi).astype(np.float32)
        else:
            keep = np.ones_like(err)
        w = keep * demo[None]
        want_bc = (w * err).sum(1) / demo.sum()
        loss, aux = agent_lib.actor_loss(st.actor, st.critic, batch, learner)
        np.testing.assert_allclose(aux["bc_loss"], want_bc, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(aux["q_filter_pass"], w.sum(1) / demo.sum(), rtol=1e-6)
        # the actor loss is the plain DDPG loss + bc_weight * BC
        plain = {k: v for k, v in batch.items() if k != "demo"}
        _, aux0 = agent_lib.actor_loss(st.actor, st.critic, plain, learner)
        np.testing.assert_allclose(aux["actor_loss"],
                                   np.asarray(aux0["actor_loss"]) + 2.5 * want_bc,
                                   rtol=1e-5, atol=1e-5)
        assert "bc_loss" not in aux0


def test_bc_gradient_moves_actor_towards_demo_actions():
    cfg = TrainConfig(hidden=HIDDEN, n_demos=1, bc_weight=100.0, q_filter=False, action_l2=0.0,
                      lr_actor=1e-3)
    learner = agent_lib.make_learner(cfg, (-1.05, 0.0))
    st = agent_lib.init_agent_state(jax.random.PRNGKey(0), learner, HIDDEN, OBS)
    batch = random_batch(jax.random.PRNGKey(4), 2)
    batch["demo"] = jnp.ones(batch["a"].shape[0], bool)
    bc0 = agent_lib.actor_loss(st.actor, st.critic, batch, learner)[1]["bc_loss"]
    for _ in range(50):
        st, _ = agent_lib.update(st, batch, learner)
    bc1 = agent_lib.actor_loss(st.actor, st.critic, batch, learner)[1]["bc_loss"]
    assert np.all(np.asarray(bc1) < 0.5 * np.asarray(bc0))


# --- the trainer ---------------------------------------------------------------------------

def test_demos_played_at_init(demo_fns, demo_epoch, env):
    s0 = demo_epoch[0]
    d = s0.demos
    assert d.obs.shape == (N_DEMOS, T + 1, 2, env.obs_size)
    assert d.actions.shape == (N_DEMOS, T, 8) and d.g.shape == (N_DEMOS, T, 2, 3)
    # the demo controller reaches every goal; its actions are the controller's
    dist = np.linalg.norm(np.asarray(d.ag[:, -1] - d.g[:, -1]), axis=-1)
    assert np.all(dist < 0.05)
    obs0 = dict(observation=d.obs[:, 0], desired_goal=d.g[:, 0])
    np.testing.assert_allclose(d.actions[:, 0], toy_demo_policy(obs0), atol=1e-6)
    # normalizers have seen every demo transition; the replay is still empty
    assert float(s0.obs_norm.count) == N_DEMOS * T and int(s0.buffer.size) == 0
    # same seed -> same demos; demos have their own PRNG stream: agents equal those without demos
    again = demo_fns.init()
    assert tree_equal(again.demos, d)
    plain = make_train_fns(env, TINY).init()
    assert plain.demos.actions.shape[0] == 0 and float(plain.obs_norm.count) == 0
    assert tree_equal(plain.agent, s0.agent)


def test_epoch_with_demos_logs_bc_and_compiles_once(demo_fns, demo_epoch):
    _, s1, m1 = demo_epoch
    assert m1["bc_loss"].shape == (DEMO.n_cycles, 2)
    assert np.all(np.isfinite(m1["bc_loss"])) and np.all(m1["bc_loss"] >= 0)
    assert np.all((m1["q_filter_pass"] >= 0) & (m1["q_filter_pass"] <= 1))
    assert not np.any(m1["nonfinite"])
    # demo steps are not counted as env steps; the demo buffer is not changed by training
    assert demo_fns.env_steps(s1) == DEMO.n_cycles * DEMO.num_envs * T
    np.testing.assert_array_equal(s1.demos.actions, demo_epoch[0].demos.actions)
    assert demo_fns.train_epoch._cache_size() == 1


def test_checkpoint_keeps_demos_out_and_restores_them(demo_fns, demo_epoch, tmp_path):
    s1 = demo_epoch[1]
    ckpt.save(tmp_path, s1, step=1)
    template = demo_fns.init(jax.random.PRNGKey(0))
    restored, _ = ckpt.restore(tmp_path, template)
    assert tree_equal(restored.agent, s1.agent)
    assert tree_equal(restored.demos, s1.demos)


def test_demo_config_errors(env):
    with pytest.raises(ValueError, match="n_demos"):
        TrainConfig(n_demos=-1)
    with pytest.raises(ValueError, match="demo_batch"):
        TrainConfig(n_demos=2, demo_batch=0)
    with pytest.raises(ValueError, match="scripted controller"):
        make_train_fns(env, DEMO.replace(task="reach"))


def test_scripted_pickup_demos_succeed_on_c_engine():
    """Default demo controller: the pick-up script, whose demos lift the bar to the goals."""
    env = mjx_envs.make("pickup", physics="c")
    cfg = TrainConfig(**preset("pickup")).replace(n_demos=2, hidden=(16,), n_test_episodes=2)
    s = make_train_fns(env, cfg).init()
    d = s.demos
    dist = np.linalg.norm(np.asarray(d.ag[:, -1] - d.g[:, -1]), axis=-1)
    assert np.all(dist < env.config.distance_threshold)
    lift = np.asarray(d.ag[:, -1, :, 2] - d.ag[:, 0, :, 2])
    assert np.all(lift > 0.04)   # every test goal is >= 0.05 m above the resting height



def test_restore_into_abstract_or_demo_free_template(demo_fns, demo_epoch, env, tmp_path):
    """The exporter restores into jax.eval_shape(init) and evaluation into a template built with
    n_demos = 0: both get the trained agents and normalizers."""
    s1 = demo_epoch[1]
    ckpt.save(tmp_path, s1, step=1)
    abstract = jax.eval_shape(demo_fns.init, jax.random.PRNGKey(0))
    restored, _ = ckpt.restore(tmp_path, abstract)
    assert restored.demos.actions.shape == (N_DEMOS, T, 8)
    assert tree_equal(restored.agent, s1.agent)
    plain = make_train_fns(env, DEMO.replace(n_demos=0)).init()
    restored, _ = ckpt.restore(tmp_path, plain)
    assert restored.demos.actions.shape[0] == 0
    assert tree_equal(restored.obs_norm, s1.obs_norm)


@pytest.mark.e2e  # ~7-15 s: kept out of the default tier's 5 minutes
def test_runner_logs_bc_columns(env, tmp_path):
    import csv

    from daddpg_jax.running.runner import train

    train(DEMO.replace(n_epochs=1), run_options(str(tmp_path), env, demo_policy=toy_demo_policy))
    row = next(csv.DictReader(open(tmp_path / "metrics.csv")))
    assert float(row["bc_loss"]) >= 0 and 0 <= float(row["q_filter_pass"]) <= 1
