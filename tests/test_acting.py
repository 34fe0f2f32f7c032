"""daddpg_jax/algo/acting.py against plain Python loops of env.reset / env.step (toy env)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from daddpg_jax.algo import acting
from tests import toy_env
from tests.conftest import T, tree_equal

N = 3


@pytest.fixture(scope="module")
def env():
    return toy_env.make(episode_length=T, clearance=0.5)


def _python_loop(env, reset_keys, actions):
    """One env at a time, one step at a time: states[i][t] (t = 0 the reset state)."""
    states = []
    for i, k in enumerate(reset_keys):
        traj = [env.reset(k)]
        for t in range(T):
            traj.append(env.step(traj[-1], actions[t, i]))
        states.append(traj)
    return states


def test_rollout_of_given_actions_equals_python_loop(env):
    key = jax.random.PRNGKey(0)
    reset_keys = jax.random.split(key, N)
    xs = jax.random.uniform(jax.random.PRNGKey(1), (T, N, 8), minval=-1, maxval=1)
    s0, states = jax.jit(lambda k, x: acting.rollout(env, lambda s, a: a, k, xs=x))(
        reset_keys, xs)
    ref = _python_loop(env, reset_keys, xs)
    for i in range(N):
        assert tree_equal(jax.tree.map(lambda x, i=i: x[i], s0), ref[i][0])
        for t in range(T):
            got = jax.tree.map(lambda x, i=i, t=t: x[t, i], states)
            want = ref[i][t + 1]
            np.testing.assert_allclose(got.obs["observation"], want.obs["observation"],
                                       atol=1e-6)
            np.testing.assert_allclose(got.reward, want.reward, atol=1e-6)
            np.testing.assert_array_equal(got.metrics["success"], want.metrics["success"])


def test_play_episodes_equals_python_loop(env):
    """The training rollout: reset keys split(split(key)[0], N), 3 policy keys per step from a
    key carried through the scan, episodes stacked as replay Episodes."""
    key = jax.random.PRNGKey(7)

    def policy(s, keys):   # depends on the state and on every per-step key
        noise = sum(jax.random.normal(k, (s.obs["observation"].shape[0], 8)) for k in keys)
        return jnp.tanh(0.3 * noise + jnp.tile(s.obs["desired_goal"][:, 0], (1, 3))[:, :8])

    eps, tr = jax.jit(lambda k: acting.play_episodes(env, policy, k, N))(key)
    assert eps.obs.shape == (N, T + 1, 2, env.obs_size) and eps.actions.shape == (N, T, 8)
    np.testing.assert_array_equal(acting.episode_keys(key, N),
                                  jax.random.split(jax.random.split(key)[0], N))

    # the same key chain by hand; each env stepped alone (the policy sees the whole batch)
    k = jax.random.split(key)[1]
    ref = [[env.reset(rk)] for rk in acting.episode_keys(key, N)]
    actions = []
    for t in range(T):
        k, *ks = jax.random.split(k, 4)
        a = policy(jax.tree.map(lambda *x: jnp.stack(x), *[r[t] for r in ref]), ks)
        actions.append(a)
        for i in range(N):
            ref[i].append(env.step(ref[i][t], a[i]))
    for i in range(N):
        for t in range(T + 1):
            np.testing.assert_allclose(eps.obs[i, t], ref[i][t].obs["observation"], atol=1e-6)
            np.testing.assert_allclose(eps.ag[i, t], ref[i][t].obs["achieved_goal"], atol=1e-6)
        for t in range(T):
            np.testing.assert_allclose(eps.actions[i, t], actions[t][i], atol=1e-6)
            np.testing.assert_allclose(eps.g[i, t], ref[i][t].obs["desired_goal"])
            np.testing.assert_allclose(tr["reward"][t, i], ref[i][t + 1].reward, atol=1e-6)
            np.testing.assert_allclose(eps.info["arm_contact_penalty"][i, t],
                                       ref[i][t + 1].info["arm_contact_penalty"])


def test_unroll_rejects_keys_and_xs_together(env):
    s0 = acting.reset(env, jax.random.split(jax.random.PRNGKey(0), 2))
    with pytest.raises(ValueError, match="not both"):
        acting.unroll(env, s0, lambda s, x: x, 2, key=jax.random.PRNGKey(1), step_keys=1,
                      xs=jnp.zeros((2, 2, 8)))
