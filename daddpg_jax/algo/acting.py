"""Acting: the one place that rolls a batch of envs out under a policy (vmapped `env.reset`,
then `lax.scan` of the vmapped `env.step`), in the spirit of brax's `training/acting.py`.

Training (exploration rollouts and demonstrations), the trainer's evaluation, the evaluation of
a saved run, the benchmarks and the scripted demos all call it:

    s_0 = vmap(env.reset)(reset_keys)                    N envs, one key each
    for t in 0 .. T-1 (lax.scan):
        a_t     = policy(s_t, x_t)                       joint actions [N, action_size]
        s_{t+1} = vmap(env.step)(s_t, a_t)
        y_t     = record(s_t, a_t, s_{t+1})              stacked to [T, N, ...]

`x_t`, the policy's per-step input, is one of
- `step_keys` fresh PRNG keys from a key carried through the scan (`key`): each step splits
  k -> (k, key_1, ..., key_n), the training rollout's exploration noise (n = 3);
- the t-th slice of `xs` (e.g. precomputed actions or per-step keys);
- None (deterministic policies).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from daddpg_jax.algo import replay

Policy = Callable[[Any, Any], jax.Array]
"""policy(batched env state, per-step input x_t) -> joint actions [N, action_size]"""

TRAIN_STEP_KEYS = 3
"""PRNG keys per step of the training rollout (Gaussian noise, random-action coin, random action)"""


def next_state(s, a, s2):
    """`record` that keeps the state reached by each step."""
    return s2


def transitions(info_keys) -> Callable:
    """`record` of the training rollout: what the replay stores, and the per-step metrics."""
    def record(s, a, s2):
        return dict(obs=s2.obs["observation"], ag=s2.obs["achieved_goal"],
                    g=s.obs["desired_goal"], a=a,
                    info={k: s2.info[k] for k in info_keys},
                    reward=s2.reward, success=s2.metrics["success"],
                    arm_contact=s2.metrics["arm_contact"])
    return record


def reset(env, keys):
    """Vmapped reset: one env per key."""
    return jax.vmap(env.reset)(keys)


def unroll(env, state, policy: Policy, length: int | None = None, *, key=None,
           step_keys: int = 0, xs=None, record: Callable = next_state):
    """`length` steps of the batched env `state` under `policy` (one `lax.scan`).

    key: carried PRNG key, split into `step_keys` fresh keys per step (x_t, a list); else x_t
    is the t-th slice of `xs` (or None). Returns (final state, records [T, N, ...])."""
    if key is not None and xs is not None:
        raise ValueError("give the policy per-step keys (key) or per-step inputs (xs), not both")

    def step(carry, x):
        s, k = carry
        if k is not None:
            k, *x = jax.random.split(k, 1 + step_keys)
        a = policy(s, x)
        s2 = jax.vmap(env.step)(s, a)
        return (s2, k), record(s, a, s2)

    (s_last, _), ys = jax.lax.scan(step, (state, key), xs, length=length)
    return s_last, ys


def rollout(env, policy: Policy, reset_keys, length: int | None = None, *, key=None,
            step_keys: int = 0, xs=None, record: Callable = next_state):
    """len(reset_keys) fresh envs rolled out for `length` steps (default: env.episode_length;
    with xs, its leading axis). Returns (first states, records [T, N, ...])."""
    if length is None and xs is None:
        length = int(env.episode_length)
    s0 = reset(env, reset_keys)
    _, ys = unroll(env, s0, policy, length, key=key, step_keys=step_keys, xs=xs, record=record)
    return s0, ys


def episode_keys(key, num_envs: int):
    """The reset keys of `play_episodes(key, num_envs)`: split(split(key)[0], num_envs)."""
    k_reset, _ = jax.random.split(key)
    return jax.random.split(k_reset, num_envs)


def play_episodes(env, policy: Policy, key, num_envs: int, info_keys=None,
                  step_keys: int = TRAIN_STEP_KEYS):
    """num_envs whole episodes, stacked as replay `Episodes` [N, T(+1), ...].

    k_reset, k_scan = split(key): the envs are reset from split(k_reset, num_envs) and the
    policy gets `step_keys` fresh keys per step from k_scan. Returns (Episodes, the per-step
    records of `transitions` [T, N, ...])."""
    info_keys = tuple(env.info_keys if info_keys is None else info_keys)
    k_reset, k_scan = jax.random.split(key)
    s0, tr = rollout(env, policy, jax.random.split(k_reset, num_envs), key=k_scan,
                     step_keys=step_keys, record=transitions(info_keys))
    return stack_episodes(s0, tr), tr


def stack_episodes(s0, tr) -> replay.Episodes:
    """First states + `transitions` records [T, N, ...] -> Episodes [N, T(+1), ...]."""
    def bt(x):   # [T, N, ...] -> [N, T, ...]
        return jnp.swapaxes(x, 0, 1)

    return replay.Episodes(
        obs=jnp.concatenate([s0.obs["observation"][:, None], bt(tr["obs"])], 1),
        ag=jnp.concatenate([s0.obs["achieved_goal"][:, None], bt(tr["ag"])], 1),
        g=bt(tr["g"]), actions=bt(tr["a"]), info=jax.tree.map(bt, tr["info"]))
