"""Episode replay buffer (preallocated ring of whole episodes) and HER relabelling.

Storage, for capacity C episodes of length T and 2 arms:
    obs     [C, T+1, 2, obs_size]   observations, slot T is the episode's last observation
    ag      [C, T+1, 2, 3]          achieved goals
    g       [C, T, 2, 3]            desired goals seen at each step
    actions [C, T, 8]               actions taken (both arms)
    info    {key: [C, T, 2]}        goal-independent reward terms of transition t (from the
                                    state reached by step t), kept so relabelling keeps them
A batch of episodes is written at the ring index (modulo C); `size` counts written episodes and
sampling draws episode indices in [0, size) only, so no unwritten slot is ever returned.
Rewards are not stored: they are recomputed from (ag[t+1], goal, info[t]) at sampling time.

The sampling functions take any pytree with this layout (the buffer's storage, or a fresh batch
of episodes), so the normalizer update can sample from the newest episodes with the same code.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Episodes:
    obs: jax.Array
    ag: jax.Array
    g: jax.Array
    actions: jax.Array
    info: dict[str, jax.Array]

    @property
    def num_episodes(self) -> int:
        return self.actions.shape[0]

    @property
    def horizon(self) -> int:
        return self.actions.shape[1]


@struct.dataclass
class ReplayBuffer:
    data: Episodes
    insert_idx: jax.Array  # int32 scalar: next slot to write
    size: jax.Array        # int32 scalar: number of written episodes (<= capacity)

    @property
    def capacity(self) -> int:
        return self.data.num_episodes


def capacity_episodes(buffer_size: int, horizon: int, num_envs: int) -> int:
    """buffer_size transitions as whole episodes, at least one cycle's worth of episodes."""
    return max(int(buffer_size) // int(horizon), int(num_envs))


def init(capacity: int, horizon: int, obs_size: int, goal_size: int, action_size: int,
         info_keys, num_arms: int = 2) -> ReplayBuffer:
    def z(*shape):
        return jnp.zeros(shape, jnp.float32)

    data = Episodes(
        obs=z(capacity, horizon + 1, num_arms, obs_size),
        ag=z(capacity, horizon + 1, num_arms, goal_size),
        g=z(capacity, horizon, num_arms, goal_size),
        actions=z(capacity, horizon, action_size),
        info={k: z(capacity, horizon, num_arms) for k in info_keys},
    )
    return ReplayBuffer(data=data, insert_idx=jnp.zeros((), jnp.int32),
                        size=jnp.zeros((), jnp.int32))


def insert(buf: ReplayBuffer, episodes: Episodes) -> ReplayBuffer:
    """Writes n episodes at slots (insert_idx + arange(n)) % capacity (n <= capacity)."""
    n, cap = episodes.num_episodes, buf.capacity
    if n > cap:
        raise ValueError(f"cannot insert {n} episodes into a buffer of {cap}")
    idx = (buf.insert_idx + jnp.arange(n, dtype=jnp.int32)) % cap
    data = jax.tree.map(lambda s, e: s.at[idx].set(e.astype(s.dtype), unique_indices=True),
                        buf.data, episodes)
    return ReplayBuffer(data=data,
                        insert_idx=(buf.insert_idx + n) % cap,
                        size=jnp.minimum(buf.size + n, cap))


def sample_indices(key, size, batch_size: int, horizon: int):
    """Uniform (episode, t) pairs with episode in [0, size) and t in [0, T)."""
    k_ep, k_t = jax.random.split(key)
    ep = jax.random.randint(k_ep, (batch_size,), 0, jnp.maximum(size, 1), dtype=jnp.int32)
    t = jax.random.randint(k_t, (batch_size,), 0, horizon, dtype=jnp.int32)
    return ep, t


def her_transitions(key, episodes: Episodes, ep, t, her: str, future_p: float,
                    compute_reward: Callable, n_step: int = 1, gamma: float = 1.0) -> dict:
    """Gathers transitions (ep, t) and relabels their goals.

    her='future': with probability future_p, t' ~ U{t+1, ..., T} and g' = ag[ep, t'] (both arms);
    her='final':  with probability future_p, g' = ag[ep, T];
    her='none':   the stored goals.
    The reward of each transition is compute_reward(ag[t+1], g', info[t]) -> [B, 2].
    Returns o, o2 [B,2,obs], g [B,2,3] (the goal for s_t and s_{t+1}), ag, ag2, a [B,8],
    r [B,2], info, and for inspection `relabel` [B] bool and `goal_t` [B] (index into ag).

    n_step > 1: n-step returns under the (relabelled) goal g', truncated at the episode end:
    with m = min(n_step, T - t), r = sum_{k<m} gamma^k compute_reward(ag[t+k+1], g', info[t+k]),
    o2 = obs[t+m] (the bootstrap state) and `discount` [B] = gamma^m for its value. n_step = 1
    gives the one-step transition above (no `discount`: the learner uses gamma).
    """
    horizon = episodes.horizon
    b = ep.shape[0]
    k_p, k_t = jax.random.split(key)
    g = episodes.g[ep, t]
    if her == "none":
        relabel = jnp.zeros((b,), bool)
        goal_t = jnp.full((b,), -1, jnp.int32)
    else:
        relabel = jax.random.uniform(k_p, (b,)) < future_p
        if her == "future":
            goal_t = jax.random.randint(k_t, (b,), t + 1, horizon + 1, dtype=jnp.int32)
        elif her == "final":
            goal_t = jnp.full((b,), horizon, jnp.int32)
        else:
            raise ValueError(f"unknown her mode {her!r}")
        goal_t = jnp.where(relabel, jnp.clip(goal_t, t + 1, horizon), -1)
        g = jnp.where(relabel[:, None, None], episodes.ag[ep, jnp.maximum(goal_t, 0)], g)
    ag2 = episodes.ag[ep, t + 1]
    info = {k: v[ep, t] for k, v in episodes.info.items()}
    out = dict(
        o=episodes.obs[ep, t], o2=episodes.obs[ep, t + 1], g=g,
        ag=episodes.ag[ep, t], ag2=ag2, a=episodes.actions[ep, t],
        r=compute_reward(ag2, g, info).astype(jnp.float32), info=info,
        relabel=relabel, goal_t=goal_t,
    )
    if n_step > 1:
        out.update(n_step_return(episodes, ep, t, g, compute_reward, n_step, gamma))
    return out


def n_step_return(episodes: Episodes, ep, t, g, compute_reward: Callable, n_step: int,
                  gamma: float) -> dict:
    """r [B, 2], o2 [B, 2, obs], discount [B] of n-step transitions (ep, t) under goals g
    [B, 2, 3], truncated at the episode end (see `her_transitions`)."""
    horizon = episodes.horizon
    k = jnp.arange(n_step, dtype=jnp.int32)                               # [n]
    m = jnp.minimum(n_step, horizon - t)                                   # [B] steps used
    tk = jnp.minimum(t[:, None] + k[None], horizon - 1)                    # [B, n]
    ag_k = episodes.ag[ep[:, None], tk + 1]                                # [B, n, 2, 3]
    info_k = {name: v[ep[:, None], tk] for name, v in episodes.info.items()}
    r_k = compute_reward(ag_k, g[:, None], info_k).astype(jnp.float32)     # [B, n, 2]
    w = jnp.where(k[None] < m[:, None], jnp.float32(gamma) ** k.astype(jnp.float32), 0.0)
    return dict(r=jnp.sum(w[..., None] * r_k, axis=1),
                o2=episodes.obs[ep, t + m],
                discount=jnp.float32(gamma) ** m.astype(jnp.float32))


def sample(key, buf: ReplayBuffer, batch_size: int, her: str, future_p: float,
           compute_reward: Callable, n_step: int = 1, gamma: float = 1.0) -> dict:
    """A HER-relabelled minibatch from the written part of the buffer (n-step returns with
    n_step > 1, see `her_transitions`)."""
    k_idx, k_her = jax.random.split(key)
    ep, t = sample_indices(k_idx, buf.size, batch_size, buf.data.horizon)
    out = her_transitions(k_her, buf.data, ep, t, her, future_p, compute_reward, n_step, gamma)
    out["ep"], out["t"] = ep, t
    return out
