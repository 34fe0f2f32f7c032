"""Session-wide env rollouts shared by the env tests (one compile per engine)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

import mjx_envs

B, T = 8, 50
# Rows of the scripted batch.
ROW_LX, ROW_LY, ROW_LZ, ROW_ZERO, ROW_R10X, ROW_RX, ROW_COLLIDE, ROW_RANDOM = range(B)


def scripted_actions(seed: int = 0) -> np.ndarray:
    a = np.zeros((B, T, 8), np.float32)
    a[ROW_LX, 0, 0] = 1.0
    a[ROW_LY, 0, 1] = 1.0
    a[ROW_LZ, 0, 2] = 1.0
    a[ROW_R10X, 0, 4] = 10.0
    a[ROW_RX, 0, 4] = 1.0
    a[ROW_COLLIDE, :, 1] = -1.0  # left arm towards the right
    a[ROW_COLLIDE, :, 5] = 1.0  # right arm towards the left
    a[ROW_RANDOM] = np.random.default_rng(seed).uniform(-1, 1, (T, 8))
    return a


class Rollout:
    """Runs ``jax.jit(jax.vmap(env.step))`` step by step over the scripted batch."""

    def __init__(self, physics: str, task: str = "reach"):
        self.env = mjx_envs.make(task, physics=physics)
        self.trace_count = 0

        def counted_step(state, action):
            self.trace_count += 1
            return self.env.step(state, action)

        self.vreset = jax.jit(jax.vmap(self.env.reset))
        self.vstep = jax.jit(jax.vmap(counted_step))
        self.keys = jax.random.split(jax.random.PRNGKey(0), B)
        self.actions = scripted_actions()
        state = self.vreset(self.keys)
        self.states = [state]
        for t in range(T):
            state = self.vstep(state, jnp.asarray(self.actions[:, t]))
            self.states.append(state)
        self.obs = jax.tree.map(lambda *x: np.stack([np.asarray(v) for v in x], 1),
                                *[s.obs for s in self.states])  # [B, T+1, ...]
        self.metrics = jax.tree.map(lambda *x: np.stack([np.asarray(v) for v in x], 1),
                                    *[s.metrics for s in self.states[1:]])  # [B, T]
        # a second full episode with uniformly random actions in every env (same compiled step)
        rand = np.random.default_rng(1).uniform(-1, 1, (T, B, 8)).astype(np.float32)
        state = self.vreset(jax.random.split(jax.random.PRNGKey(1), B))
        random_states = [state]
        for t in range(T):
            state = self.vstep(state, jnp.asarray(rand[t]))
            random_states.append(state)
        self.random_states = random_states


@functools.cache
def rollout(physics: str, task: str = "reach") -> Rollout:
    return Rollout(physics, task)


# -- samplers for the task rules (mjx_envs.rules) ---------------------------------------------

class RecordingSampler:
    """Wraps a sampler and keeps every ``uniform`` draw (as NumPy), in order."""

    def __init__(self, inner):
        self.inner, self.draws = inner, []

    def split(self, key, num):
        return self.inner.split(key, num)

    def uniform(self, key, shape, low, high):
        v = self.inner.uniform(key, shape, low, high)
        self.draws.append(np.asarray(v))
        return v


class ReplaySampler:
    """Hands out recorded draws in order (as ``xp`` arrays); keys are ignored."""

    def __init__(self, draws, xp=np):
        self.draws, self.xp = list(draws), xp

    def split(self, key, num):
        return (key,) * num

    def uniform(self, key, shape, low, high):
        v = self.draws.pop(0)
        assert v.shape == tuple(shape), (v.shape, shape)
        return self.xp.asarray(v)
