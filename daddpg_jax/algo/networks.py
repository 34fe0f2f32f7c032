"""Actor and critic MLPs, with both arms' parameters stacked on a leading agent axis.

One network definition serves every agent: parameters are created with `jax.vmap(init)` over A
keys (A = 2 arms, or 1 for 'single') and applied with `jax.vmap(apply)` over the agent axis.

Inputs per variant (o = normalized per-arm observations [B, 2, obs], g = normalized goals
[B, 2, 3], a = actions [B, 8] in [-1, 1], arm i owns a[:, 4i:4i+4]):
    daddpg  actor_i: (o_1, o_2, g_1, g_2)           critic_i: (o_1, o_2, g_1, g_2, a)
    maddpg  actor_i: (o_i, g_i)                     critic_i: (o_1, o_2, g_1, g_2, a)
    ddpg    actor_i: (o_i, g_i)                     critic_i: (o_i, g_i, a_i)
    single  actor:   (o_1, o_2, g_1, g_2) -> 8-d    critic:   (o_1, o_2, g_1, g_2, a)
"""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

ARM_ACTION = 4


class MLP(nn.Module):
    """ReLU MLP; tanh head for actors, scalar head for critics."""
    hidden: Sequence[int]
    out_dim: int
    tanh_out: bool

    @nn.compact
    def __call__(self, x):
        init = nn.initializers.xavier_uniform()
        for h in self.hidden:
            x = nn.relu(nn.Dense(h, kernel_init=init)(x))
        x = nn.Dense(self.out_dim, kernel_init=init)(x)
        return jnp.tanh(x) if self.tanh_out else x[..., 0]


def num_agents(algo: str) -> int:
    return 1 if algo == "single" else 2


def agent_action_dim(algo: str) -> int:
    return 2 * ARM_ACTION if algo == "single" else ARM_ACTION


def input_dims(algo: str, obs_size: int, goal_size: int = 3, num_arms: int = 2):
    """(actor input dim, critic input dim) for a variant."""
    both = num_arms * (obs_size + goal_size)
    own = obs_size + goal_size
    act = num_arms * ARM_ACTION
    if algo in ("daddpg", "single"):
        return both, both + act
    if algo == "maddpg":
        return own, both + act
    if algo == "ddpg":
        return own, own + ARM_ACTION
    raise ValueError(f"unknown algo {algo!r}")


def _flat(x):
    return x.reshape(x.shape[:-2] + (-1,))


def actor_inputs(algo: str, o, g):
    """o [B, 2, obs], g [B, 2, 3] -> [A, B, actor_in]."""
    if algo in ("daddpg", "single"):
        x = jnp.concatenate([_flat(o), _flat(g)], -1)
        return jnp.broadcast_to(x, (num_agents(algo),) + x.shape)
    x = jnp.concatenate([o, g], -1)  # [B, 2, obs+3]
    return jnp.moveaxis(x, -2, 0)


def critic_inputs(algo: str, o, g, a):
    """o [B, 2, obs], g [B, 2, 3], a [A, B, 8] (each agent's view of the joint action) ->
    [A, B, critic_in]."""
    n = num_agents(algo)
    if algo == "ddpg":
        own = jnp.moveaxis(jnp.concatenate([o, g], -1), -2, 0)            # [2, B, obs+3]
        a_own = jnp.stack([a[i, :, ARM_ACTION * i:ARM_ACTION * (i + 1)] for i in range(n)])
        return jnp.concatenate([own, a_own], -1)
    x = jnp.concatenate([_flat(o), _flat(g)], -1)
    x = jnp.broadcast_to(x, (n,) + x.shape)
    return jnp.concatenate([x, a], -1)


def joint_action(algo: str, agent_actions):
    """[A, B, act_dim] -> [B, 8] (arm 0 first)."""
    if algo == "single":
        return agent_actions[0]
    return jnp.concatenate([agent_actions[i] for i in range(agent_actions.shape[0])], -1)


def own_action_mask(algo: str):
    """[A, 8] bool: which joint-action entries agent i controls."""
    if algo == "single":
        return jnp.ones((1, 2 * ARM_ACTION), bool)
    return jnp.repeat(jnp.eye(2, dtype=bool), ARM_ACTION, axis=1)


def make_networks(algo: str, hidden: Sequence[int]):
    actor = MLP(tuple(hidden), agent_action_dim(algo), True)
    critic = MLP(tuple(hidden), 1, False)
    return actor, critic


def init_params(key, algo: str, hidden: Sequence[int], obs_size: int, goal_size: int = 3):
    """Stacked (actor_params, critic_params), leading agent axis of size A."""
    actor, critic = make_networks(algo, hidden)
    a_in, c_in = input_dims(algo, obs_size, goal_size)
    n = num_agents(algo)
    k_a, k_c = jax.random.split(key)
    actor_params = jax.vmap(actor.init, in_axes=(0, None))(
        jax.random.split(k_a, n), jnp.zeros((1, a_in), jnp.float32))
    critic_params = jax.vmap(critic.init, in_axes=(0, None))(
        jax.random.split(k_c, n), jnp.zeros((1, c_in), jnp.float32))
    return actor_params, critic_params


def apply_stacked(module, params, x):
    """params with agent axis A, x [A, B, in] -> [A, B, ...]."""
    return jax.vmap(module.apply)(params, x)
