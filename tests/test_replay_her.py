"""Replay ring buffer and HER relabelling against plain-Python references."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from daddpg_jax.algo import acting, replay
from tests import toy_env
from tests.conftest import tree_equal

T, OBS = 6, 5


def make_episodes(n, first_id=0, info_keys=("arm_contact_penalty",), seed=0):
    """Episodes whose entries identify (episode id, step, arm) so a sample can be traced back."""
    rng = np.random.default_rng(seed)
    ids = np.arange(first_id, first_id + n, dtype=np.float32)
    t1 = np.arange(T + 1, dtype=np.float32)
    ag = np.zeros((n, T + 1, 2, 3), np.float32)
    ag[..., 0] = ids[:, None, None]
    ag[..., 1] = t1[None, :, None]
    ag[..., 2] = (np.array([0.0, 1.0], np.float32)[None, None, :]
                  + rng.uniform(0, 0.5, (n, T + 1, 2)))
    obs = np.zeros((n, T + 1, 2, OBS), np.float32)
    obs[..., 0] = ids[:, None, None] + 1.0
    obs[..., 1] = t1[None, :, None]
    g = rng.uniform(-1, 1, (n, T, 2, 3)).astype(np.float32)
    actions = np.zeros((n, T, 8), np.float32)
    actions[..., 0] = ids[:, None] + 1.0
    actions[..., 1] = np.arange(T, dtype=np.float32)
    info = {k: -0.05 * rng.integers(0, 2, (n, T, 2)).astype(np.float32) for k in info_keys}
    return replay.Episodes(obs=jnp.asarray(obs), ag=jnp.asarray(ag), g=jnp.asarray(g),
                           actions=jnp.asarray(actions),
                           info={k: jnp.asarray(v) for k, v in info.items()})


def empty(cap):
    return replay.init(cap, T, OBS, 3, 8, ("arm_contact_penalty",))


ENV = toy_env.make(episode_length=T, threshold=0.3)


def test_capacity_in_episodes():
    assert replay.capacity_episodes(1_000_000, 50, 2) == 20_000
    assert replay.capacity_episodes(100, 50, 8) == 8  # at least one cycle's worth


def test_insert_and_wraparound():
    buf = empty(5)
    assert int(buf.size) == 0 and buf.capacity == 5
    ep_a = make_episodes(3, first_id=0)
    buf = replay.insert(buf, ep_a)
    assert int(buf.size) == 3 and int(buf.insert_idx) == 3
    np.testing.assert_array_equal(buf.data.actions[:3], ep_a.actions)
    np.testing.assert_array_equal(buf.data.actions[3:], 0.0)
    ep_b = make_episodes(3, first_id=3, seed=1)
    buf = replay.insert(buf, ep_b)
    # slots 3, 4 then 0 (wraps): the oldest episode is overwritten
    assert int(buf.size) == 5 and int(buf.insert_idx) == 1
    np.testing.assert_array_equal(buf.data.obs[np.array([3, 4, 0])], ep_b.obs)
    np.testing.assert_array_equal(buf.data.info["arm_contact_penalty"][np.array([3, 4, 0])],
                                  ep_b.info["arm_contact_penalty"])
    np.testing.assert_array_equal(buf.data.ag[1:3], ep_a.ag[1:3])
    buf = replay.insert(buf, make_episodes(5, first_id=6, seed=2))
    assert int(buf.size) == 5 and int(buf.insert_idx) == 1
    np.testing.assert_array_equal(np.sort(np.asarray(buf.data.actions[:, 0, 0])), np.arange(7, 12))
    with pytest.raises(ValueError):
        replay.insert(buf, make_episodes(6))


def test_insert_under_jit_matches_eager():
    buf = replay.insert(empty(4), make_episodes(3))
    eps = make_episodes(3, first_id=3, seed=1)
    eager = replay.insert(buf, eps)
    jitted = jax.jit(replay.insert)(buf, eps)
    assert tree_equal(eager, jitted)


def test_never_samples_unwritten_slots():
    buf = replay.insert(empty(50), make_episodes(3))
    out = jax.jit(lambda k: replay.sample(k, buf, 4096, "future", 0.8, ENV.compute_reward))(
        jax.random.PRNGKey(0))
    ep = np.asarray(out["ep"])
    assert ep.min() >= 0 and ep.max() <= 2
    assert set(np.unique(ep)) == {0, 1, 2}
    assert np.all(np.asarray(out["a"])[:, 0] > 0)   # unwritten slots hold zeros
    t = np.asarray(out["t"])
    assert t.min() == 0 and t.max() == T - 1


def _reference_reward(ag2, g, info):
    d = np.linalg.norm(ag2 - g, axis=-1)
    return -(d >= ENV.config.threshold).astype(np.float32) + info


@pytest.mark.parametrize("mode", ["future", "final", "none"])
def test_her_against_python_reference(mode):
    eps = make_episodes(4)
    buf = replay.insert(empty(4), eps)
    n = 20000
    out = jax.jit(lambda k: replay.sample(k, buf, n, mode, 0.8, ENV.compute_reward))(
        jax.random.PRNGKey(1))
    out = jax.tree.map(np.asarray, out)
    ag, g_stored = np.asarray(eps.ag), np.asarray(eps.g)
    info = np.asarray(eps.info["arm_contact_penalty"])
    n_relabel, offsets = 0, []
    for i in range(n):
        e, t, g = out["ep"][i], out["t"][i], out["g"][i]
        # transition fields come from (e, t) / (e, t+1)
        np.testing.assert_array_equal(out["o"][i], np.asarray(eps.obs)[e, t])
        np.testing.assert_array_equal(out["o2"][i], np.asarray(eps.obs)[e, t + 1])
        np.testing.assert_array_equal(out["a"][i], np.asarray(eps.actions)[e, t])
        np.testing.assert_array_equal(out["ag2"][i], ag[e, t + 1])
        if np.array_equal(g, g_stored[e, t]):
            assert not out["relabel"][i]
        else:
            assert out["relabel"][i]
            n_relabel += 1
            # both arms' goals come from ONE step t' of the same episode, strictly later than t
            matches = [tp for tp in range(T + 1) if np.array_equal(g, ag[e, tp])]
            assert len(matches) == 1, (i, e, t)
            tp = matches[0]
            assert t < tp <= T
            assert tp == out["goal_t"][i]
            if mode == "final":
                assert tp == T
            if T - t > 1:
                offsets.append((tp - t - 1) / (T - t - 1))
        r_ref = _reference_reward(ag[e, t + 1], g, info[e, t])
        np.testing.assert_allclose(out["r"][i], r_ref, atol=1e-6)
    frac = n_relabel / n
    if mode == "none":
        assert n_relabel == 0
    else:
        assert abs(frac - 0.8) < 0.02, frac    # 0.8 +- 7 sigma
    if mode == "future":
        # t' uniform on {t+1, ..., T}: normalized offsets average 0.5 and cover both ends
        assert abs(np.mean(offsets) - 0.5) < 0.02
        assert min(offsets) == 0.0 and max(offsets) == 1.0


def test_relabel_probability_from_k():
    from daddpg_jax.algo.config import TrainConfig
    assert TrainConfig(replay_k=4).future_p == pytest.approx(0.8)
    assert TrainConfig(replay_k=4, her="none").future_p == 0.0


def test_rewards_include_info_terms_and_match_env():
    """With her='none', recomputed rewards equal the rewards the env returned while stepping."""
    env = toy_env.make(episode_length=T, clearance=0.5, contact_penalty=0.3)
    n = 8

    def random_actions(s, keys):
        return jax.random.uniform(keys[0], (n, 8), minval=-1, maxval=1)

    eps, tr = jax.jit(lambda k: acting.play_episodes(env, random_actions, k, n))(
        jax.random.PRNGKey(3))
    ep = jnp.repeat(jnp.arange(n), T)
    t = jnp.tile(jnp.arange(T), n)
    out = replay.her_transitions(jax.random.PRNGKey(0), eps, ep, t, "none", 0.8,
                                 env.compute_reward)
    np.testing.assert_allclose(out["r"], jnp.swapaxes(tr["reward"], 0, 1).reshape(n * T, 2),
                               atol=1e-6)
    assert np.any(np.asarray(eps.info["arm_contact_penalty"]) < 0)  # the info term contributed


def _n_step_reference(eps, ep, t, g, goal_t, n, gamma, compute_reward):
    """Plain-Python n-step transitions: loop over rows and steps."""
    np_eps = jax.tree.map(np.asarray, eps)
    rs, o2s, discs = [], [], []
    for b in range(len(ep)):
        e, tt = int(ep[b]), int(t[b])
        m = min(n, T - tt)
        r = np.zeros(2, np.float32)
        for k in range(m):
            info = {name: v[e, tt + k] for name, v in np_eps.info.items()}
            r_k = np.asarray(compute_reward(np_eps.ag[e, tt + k + 1], g[b], info))
            r = r + np.float32(gamma) ** k * r_k
        rs.append(r)
        o2s.append(np_eps.obs[e, tt + m])
        discs.append(np.float32(gamma) ** m)
    return np.stack(rs), np.stack(o2s), np.asarray(discs)


@pytest.mark.parametrize("her", ["future", "none"])
def test_n_step_returns_match_a_python_loop(her):
    eps = make_episodes(4, seed=3)
    key = jax.random.PRNGKey(7)
    ep = jnp.asarray(np.repeat(np.arange(4), T), jnp.int32)
    t = jnp.asarray(np.tile(np.arange(T), 4), jnp.int32)
    gamma = 0.9
    for n in (2, 3, T + 2):
        out = replay.her_transitions(key, eps, ep, t, her, 0.8, ENV.compute_reward,
                                     n_step=n, gamma=gamma)
        one = replay.her_transitions(key, eps, ep, t, her, 0.8, ENV.compute_reward)
        # same relabelling draws as the one-step transition: n-step consumes no randomness
        np.testing.assert_array_equal(out["g"], one["g"])
        np.testing.assert_array_equal(out["goal_t"], one["goal_t"])
        r, o2, disc = _n_step_reference(eps, np.asarray(ep), np.asarray(t), np.asarray(out["g"]),
                                        np.asarray(out["goal_t"]), n, gamma,
                                        ENV.compute_reward)
        np.testing.assert_allclose(out["r"], r, rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(out["o2"], o2)
        np.testing.assert_allclose(out["discount"], disc, rtol=1e-6)
        # truncated at the episode end: the last step bootstraps from slot T with gamma^1
        last = np.asarray(t) == T - 1
        np.testing.assert_allclose(np.asarray(out["discount"])[last], gamma, rtol=1e-6)
        np.testing.assert_array_equal(np.asarray(out["o2"])[last], np.asarray(one["o2"])[last])
        np.testing.assert_array_equal(np.asarray(out["r"])[last], np.asarray(one["r"])[last])


def test_one_step_keeps_the_one_step_batch():
    eps = make_episodes(3, seed=4)
    ep = jnp.asarray([0, 1, 2, 2], jnp.int32)
    t = jnp.asarray([0, 3, 5, 1], jnp.int32)
    key = jax.random.PRNGKey(1)
    a = replay.her_transitions(key, eps, ep, t, "future", 0.8, ENV.compute_reward)
    b = replay.her_transitions(key, eps, ep, t, "future", 0.8, ENV.compute_reward,
                               n_step=1, gamma=0.5)
    assert "discount" not in a and tree_equal(a, b)
