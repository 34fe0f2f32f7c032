"""Losses, targets, normalizer, variants and the actor-gradient isolation between arms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from daddpg_jax import variants
from daddpg_jax.algo import losses as agent_lib
from daddpg_jax.algo import networks as nets
from daddpg_jax.algo import normalizer as norm
from daddpg_jax.algo.config import REPLAY_RATIO, TrainConfig, preset, replay_ratio
from tests.conftest import HIDDEN, OBS, B, random_batch, tree_equal


def make(algo, **kw):
    cfg = TrainConfig(algo=algo, hidden=HIDDEN, **kw)
    learner = agent_lib.make_learner(cfg, (-1.05, 0.0))
    state = agent_lib.init_agent_state(jax.random.PRNGKey(0), learner, HIDDEN, OBS)
    return cfg, learner, state


# --- TD target, bounds, polyak --------------------------------------------------------------

def test_td_target_matches_numpy():
    rng = np.random.default_rng(0)
    r = -rng.integers(0, 2, (2, 100)).astype(np.float32)
    q = rng.uniform(-80, 10, (2, 100)).astype(np.float32)
    lo, hi = agent_lib.target_bounds("daddpg", (-1.05, 0.0), 0.98)
    assert lo == pytest.approx(-1.05 / 0.02) and hi == 0.0
    y = agent_lib.td_target(jnp.asarray(r), jnp.asarray(q), 0.98, lo, hi)
    np.testing.assert_allclose(y, np.clip(r + 0.98 * q, -52.5, 0.0), rtol=1e-6, atol=1e-5)
    y_raw = agent_lib.td_target(jnp.asarray(r), jnp.asarray(q), 0.98, lo, hi, clip=False)
    np.testing.assert_allclose(y_raw, r + 0.98 * q, rtol=1e-6, atol=1e-5)
    lo1, hi1 = agent_lib.target_bounds("single", (-1.05, 0.0), 0.98)
    assert lo1 == pytest.approx(2 * lo) and hi1 == 0.0


def test_critic_loss_uses_clipped_target_of_target_networks():
    cfg, learner, st = make("daddpg")
    # make target networks differ from the online ones
    st = st.replace(target_critic=jax.tree.map(lambda x: x * 3.0 + 0.5, st.target_critic))
    batch = random_batch(jax.random.PRNGKey(1), 2)
    _, aux = agent_lib.critic_loss(st.critic, st.target_actor, st.target_critic, batch, learner)
    a2 = nets.joint_action(
        agent_lib.policy_actions(learner, st.target_actor, batch["o2"], batch["g"]))
    q2 = np.asarray(agent_lib.q_values(learner, st.target_critic, batch["o2"], batch["g"],
                                       jnp.stack([a2, a2])))
    q = np.asarray(agent_lib.q_values(learner, st.critic, batch["o"], batch["g"],
                                      jnp.stack([batch["a"]] * 2)))
    y = np.clip(np.asarray(batch["r"]) + 0.98 * q2, learner.target_lo, learner.target_hi)
    np.testing.assert_allclose(aux["mean_target"], y.mean(1), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(aux["critic_loss"], ((y - q) ** 2).mean(1), rtol=1e-5, atol=1e-5)


def test_critic_loss_n_step_discount_per_row():
    cfg, learner, st = make("daddpg")
    batch = random_batch(jax.random.PRNGKey(2), 2)
    disc = jnp.asarray(np.random.default_rng(0).choice([0.98, 0.98 ** 2, 0.98 ** 3], B),
                       jnp.float32)
    _, aux = agent_lib.critic_loss(st.critic, st.target_actor, st.target_critic,
                                   dict(batch, discount=disc), learner)
    a2 = nets.joint_action(
        agent_lib.policy_actions(learner, st.target_actor, batch["o2"], batch["g"]))
    q2 = np.asarray(agent_lib.q_values(learner, st.target_critic, batch["o2"], batch["g"],
                                       jnp.stack([a2, a2])))
    y = np.clip(np.asarray(batch["r"]) + np.asarray(disc)[None] * q2, learner.target_lo,
                learner.target_hi)
    np.testing.assert_allclose(aux["mean_target"], y.mean(1), rtol=1e-5, atol=1e-5)


def test_polyak_matches_numpy():
    rng = np.random.default_rng(0)
    tgt = {"w": rng.normal(size=(2, 3, 4)).astype(np.float32),
           "b": rng.normal(size=(2, 4)).astype(np.float32)}
    onl = {"w": rng.normal(size=(2, 3, 4)).astype(np.float32),
           "b": rng.normal(size=(2, 4)).astype(np.float32)}
    out = agent_lib.polyak_update(jax.tree.map(jnp.asarray, tgt), jax.tree.map(jnp.asarray, onl),
                                  0.95)
    for k in tgt:
        np.testing.assert_allclose(out[k], 0.95 * tgt[k] + 0.05 * onl[k], rtol=1e-6)


def test_update_changes_online_not_targets_and_targets_move_by_polyak():
    cfg, learner, st = make("daddpg")
    batch = random_batch(jax.random.PRNGKey(2), 2)
    new, metrics = jax.jit(agent_lib.update, static_argnums=2)(st, batch, learner)
    assert metrics["critic_loss"].shape == (2,) and metrics["actor_loss"].shape == (2,)
    assert tree_equal(st.target_actor, new.target_actor)
    assert any(not np.allclose(a, b) for a, b in zip(jax.tree.leaves(st.actor),
                                                     jax.tree.leaves(new.actor), strict=True))
    moved = agent_lib.update_targets(new, 0.95)
    for t, o, m in zip(jax.tree.leaves(new.target_critic), jax.tree.leaves(new.critic),
                       jax.tree.leaves(moved.target_critic), strict=True):
        np.testing.assert_allclose(m, 0.95 * np.asarray(t) + 0.05 * np.asarray(o),
                                   rtol=1e-5, atol=1e-7)


# --- normalizer --------------------------------------------------------------------------

def test_normalizer_matches_numpy():
    rng = np.random.default_rng(0)
    chunks = [rng.normal(loc=[1.3, -0.2, 0.0], scale=[0.1, 2.0, 0.001], size=(n, 2, 3))
              .astype(np.float32) for n in (7, 300, 1000)]
    st = norm.init((2, 3))
    for c in chunks:
        st = jax.jit(norm.update)(st, jnp.asarray(c))
    allx = np.concatenate(chunks).astype(np.float64)
    assert float(st.count) == len(allx)
    np.testing.assert_allclose(st.mean, allx.mean(0), rtol=1e-5, atol=1e-6)
    std_ref = np.sqrt(np.maximum(0.01 ** 2, allx.var(0)))
    np.testing.assert_allclose(norm.std(st, 0.01), std_ref, rtol=1e-4)
    x = rng.normal(loc=1.3, scale=1.0, size=(50, 2, 3)).astype(np.float32)
    ref = np.clip((x - allx.mean(0)) / std_ref, -5, 5)
    np.testing.assert_allclose(norm.normalize(st, jnp.asarray(x), 0.01, 5.0), ref,
                               rtol=1e-4, atol=1e-4)
    assert np.abs(np.asarray(norm.normalize(st, jnp.asarray(x), 0.01, 5.0))).max() <= 5.0


# --- variants ----------------------------------------------------------------------------

@pytest.mark.parametrize("algo,n_agents,act_dim,actor_in,critic_in", [
    ("daddpg", 2, 4, 2 * (OBS + 3), 2 * (OBS + 3) + 8),
    ("maddpg", 2, 4, OBS + 3, 2 * (OBS + 3) + 8),
    ("ddpg", 2, 4, OBS + 3, OBS + 3 + 4),
    ("single", 1, 8, 2 * (OBS + 3), 2 * (OBS + 3) + 8),
])
def test_variant_shapes(algo, n_agents, act_dim, actor_in, critic_in):
    cfg, learner, st = make(algo)
    v = variants.get(algo)
    assert v.num_agents == n_agents and v.agent_action_dim == act_dim
    assert nets.input_dims(algo, OBS) == (actor_in, critic_in) == v.input_dims(OBS)
    assert learner.variant is v
    assert st.actor["params"]["Dense_0"]["kernel"].shape == (n_agents, actor_in, HIDDEN[0])
    assert st.critic["params"]["Dense_0"]["kernel"].shape == (n_agents, critic_in, HIDDEN[0])
    assert st.actor["params"]["Dense_2"]["kernel"].shape == (n_agents, HIDDEN[1], act_dim)
    batch = random_batch(jax.random.PRNGKey(0), n_agents)
    pi = agent_lib.policy_actions(learner, st.actor, batch["o"], batch["g"])
    assert pi.shape == (n_agents, B, act_dim)
    assert np.abs(np.asarray(pi)).max() <= 1.0
    assert nets.joint_action(pi).shape == (B, 8)
    q = agent_lib.q_values(learner, st.critic, batch["o"], batch["g"],
                           jnp.stack([batch["a"]] * n_agents))
    assert q.shape == (n_agents, B)
    # the two arms' networks are different (independent initialisations)
    if n_agents == 2:
        k = st.actor["params"]["Dense_0"]["kernel"]
        assert not np.allclose(k[0], k[1])


def test_variant_inputs_see_what_they_should():
    """maddpg/ddpg actors ignore the other arm; ddpg critics ignore the other arm entirely."""
    b = random_batch(jax.random.PRNGKey(0), 2)
    o_mod = b["o"].at[:, 1].add(10.0)   # change arm 1's observation only
    for algo in ("maddpg", "ddpg"):
        x0 = nets.actor_inputs(algo, b["o"], b["g"])
        x1 = nets.actor_inputs(algo, o_mod, b["g"])
        np.testing.assert_array_equal(x0[0], x1[0])
        assert not np.allclose(x0[1], x1[1])
    a = jnp.stack([b["a"]] * 2)
    a_mod = a.at[:, :, 4:].add(1.0)     # change arm 1's action only
    c0 = nets.critic_inputs("ddpg", b["o"], b["g"], a)
    c1 = nets.critic_inputs("ddpg", o_mod, b["g"], a_mod)
    np.testing.assert_array_equal(c0[0], c1[0])
    for algo in ("daddpg", "maddpg"):
        c0 = nets.critic_inputs(algo, b["o"], b["g"], a)
        c1 = nets.critic_inputs(algo, b["o"], b["g"], a_mod)
        assert not np.allclose(c0[0], c1[0])
    x0 = nets.actor_inputs("daddpg", b["o"], b["g"])
    x1 = nets.actor_inputs("daddpg", o_mod, b["g"])
    assert not np.allclose(x0[0], x1[0])


@pytest.mark.parametrize("algo", variants.ALGOS)
def test_joint_action_own_slots_and_mask(algo):
    """The joint action is the agents' outputs concatenated in agent order; agent j owns the
    columns [j * d, (j + 1) * d)."""
    v = variants.get(algo)
    n, d = v.num_agents, v.agent_action_dim
    a = jax.random.uniform(jax.random.PRNGKey(0), (B, 8), minval=-1, maxval=1)
    own = nets.own_actions(v, a)
    assert own.shape == (n, B, d)
    for j in range(n):
        np.testing.assert_array_equal(own[j], a[:, j * d:(j + 1) * d])
    np.testing.assert_array_equal(nets.joint_action(own), a)
    mask = np.asarray(nets.own_action_mask(algo))
    want = np.zeros((n, 8), bool)
    for j in range(n):
        want[j, j * d:(j + 1) * d] = True
    np.testing.assert_array_equal(mask, want)
    assert nets.input_dims(v, OBS) == nets.input_dims(algo, OBS)


def test_single_rewards_sum_over_arms():
    r = jnp.array([[-1.0, 0.0], [-1.0, -1.05]])
    np.testing.assert_allclose(agent_lib.agent_rewards("single", r), [[-1.0, -2.05]])
    np.testing.assert_allclose(agent_lib.agent_rewards("daddpg", r), [[-1.0, -1.0], [0.0, -1.05]])


# --- gradient isolation ------------------------------------------------------------------

@pytest.mark.parametrize("algo", ["daddpg", "maddpg", "ddpg"])
@pytest.mark.parametrize("other_action", ["buffer", "policy"])
def test_actor_gradient_isolation(algo, other_action):
    cfg, learner, st = make(algo, other_action=other_action)
    batch = random_batch(jax.random.PRNGKey(5), 2)
    def loss(p, i):
        return agent_lib.actor_loss(p, st.critic, batch, learner)[1]["actor_loss"][i]

    for i in (0, 1):
        grads = jax.grad(loss)(st.actor, i)
        for leaf in jax.tree.leaves(grads):
            assert np.all(np.asarray(leaf[1 - i]) == 0.0), (algo, i)
        assert any(np.abs(np.asarray(leaf[i])).max() > 0 for leaf in jax.tree.leaves(grads))
    # the summed loss gives each arm exactly its own loss's gradient
    g_sum = jax.grad(lambda p: agent_lib.actor_loss(p, st.critic, batch, learner)[0])(st.actor)
    g0 = jax.grad(loss)(st.actor, 0)
    for a, b in zip(jax.tree.leaves(g_sum), jax.tree.leaves(g0), strict=True):
        np.testing.assert_allclose(a[0], b[0], rtol=1e-5, atol=1e-7)


def test_critic_gradient_isolation():
    cfg, learner, st = make("daddpg")
    batch = random_batch(jax.random.PRNGKey(6), 2)
    def loss0(p):
        return agent_lib.critic_loss(p, st.target_actor, st.target_critic, batch,
                                     learner)[1]["critic_loss"][0]

    for leaf in jax.tree.leaves(jax.grad(loss0)(st.critic)):
        assert np.all(np.asarray(leaf[1]) == 0.0)


# --- presets -----------------------------------------------------------------------------

def test_cpu_preset_caps_the_updates_of_many_envs():
    p = preset("reach", 2048, device="cpu")
    assert (p["batch_size"], p["n_batches"], p["n_cycles"]) == (1024, 100, 3)
    assert p["buffer_size"] == 20 * 2048 * 50
    p = preset("push", 32, device="cpu")
    assert (p["batch_size"], p["n_batches"], p["n_cycles"]) == (1024, 100, 50)
    # the default sizes keep the HER baselines' schedule
    assert preset("push", device="cpu")["n_batches"] == 40
    assert preset("reach", 2048, device="gpu")["batch_size"] == 8192


def test_preset_keeps_replay_ratio():
    p = preset("reach")
    assert p["num_envs"] == 2 and p["batch_size"] == 256
    assert p["n_batches"] == 40 and p["n_cycles"] == 20
    assert preset("push", 2)["n_cycles"] == 50
    for device, sizes in (("gpu", (1, 2, 8, 64, 512, 4096)), ("cpu", (1, 2, 8, 16))):
        for n in sizes:
            p = preset("push", n, device=device)
            assert p["batch_size"] <= 8192
            rr = replay_ratio(p["n_batches"], p["batch_size"], n)
            assert REPLAY_RATIO <= rr < REPLAY_RATIO * 1.1 + 1, (n, p, rr)
            cfg = TrainConfig(**p)
            assert cfg.num_envs == n
    with pytest.raises(ValueError):
        preset("nope", 2)
    with pytest.raises(ValueError):
        TrainConfig(algo="nope")
