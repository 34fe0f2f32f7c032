"""Running mean/std normalizer for observations and goals, kept on device.

Statistics are per feature over a fixed trailing shape (here [2 arms, dim], so each arm has its
own statistics). They are accumulated as (count, mean, M2) and merged batch by batch with Chan's
parallel formula: the same numbers as running sum/sumsq/count, without the float32 cancellation
of sumsq/n - mean^2 after millions of samples.

    std = sqrt(max(norm_eps^2, M2 / count))          (HER baselines' definition)
    normalize(x) = clip((clip(x, +-clip_obs) - mean) / std, -norm_clip, norm_clip)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class NormState:
    count: jax.Array  # float32 scalar
    mean: jax.Array   # float32 [*shape]
    m2: jax.Array     # float32 [*shape], sum of squared deviations from the mean


def init(shape) -> NormState:
    shape = tuple(shape)
    return NormState(count=jnp.zeros((), jnp.float32),
                     mean=jnp.zeros(shape, jnp.float32),
                     m2=jnp.zeros(shape, jnp.float32))


def update(state: NormState, x: jax.Array, clip_obs: float = 200.0, axis_name=None) -> NormState:
    """Merges a batch x [..., *shape] (all leading axes are samples) into the statistics.

    axis_name: inside ``shard_map``, x is this device's part of the batch; the batch moments of
    all devices are merged first (psum of counts, Chan's formula), so every device ends with the
    statistics of the whole batch."""
    feat = state.mean.shape
    x = jnp.clip(x.astype(jnp.float32), -clip_obs, clip_obs).reshape((-1,) + feat)
    n_b = jnp.asarray(x.shape[0], jnp.float32)
    mean_b = jnp.mean(x, axis=0)
    m2_b = jnp.sum(jnp.square(x - mean_b), axis=0)
    if axis_name is not None:
        n_l, mean_l = n_b, mean_b
        n_b = jax.lax.psum(n_l, axis_name)
        mean_b = jax.lax.psum(mean_l * n_l, axis_name) / n_b
        m2_b = jax.lax.psum(m2_b + jnp.square(mean_l - mean_b) * n_l, axis_name)
    n = state.count + n_b
    delta = mean_b - state.mean
    mean = state.mean + delta * (n_b / n)
    m2 = state.m2 + m2_b + jnp.square(delta) * (state.count * n_b / n)
    return NormState(count=n, mean=mean, m2=m2)


def std(state: NormState, eps: float = 0.01) -> jax.Array:
    var = state.m2 / jnp.maximum(state.count, 1.0)
    return jnp.sqrt(jnp.maximum(jnp.float32(eps) ** 2, var))


def normalize(state: NormState, x: jax.Array, eps: float = 0.01, clip: float = 5.0,
              clip_obs: float = 200.0) -> jax.Array:
    """x [..., *shape] -> clipped standardized values of the same shape."""
    x = jnp.clip(x, -clip_obs, clip_obs)
    return jnp.clip((x - state.mean) / std(state, eps), -clip, clip)
