"""Actor and critic MLPs, with every agent's parameters stacked on a leading agent axis.

One network definition serves every agent: parameters are created with `jax.vmap(init)` over A
keys (A = the variant's `num_agents`: 2 arms, or 1 for 'single') and applied with
`jax.vmap(apply)` over the agent axis.

What each network sees is read from the variant's row in `daddpg_jax.variants` (o =
normalized per-arm observations [B, 2, obs], g = normalized goals [B, 2, 3], a = joint actions
[B, 8] in [-1, 1]; agent j controls a[:, j*d:(j+1)*d], d = `agent_action_dim`):
    actor_sees  'both': (o_1, o_2, g_1, g_2)       'own': agent i's (o_i, g_i)
    critic_sees 'both': (o_1, o_2, g_1, g_2, a)    'own': agent i's (o_i, g_i, a_i)
Every function takes a `Variant` or its name.
"""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from daddpg_jax import variants
from daddpg_jax.variants import ARM_ACTION as ARM_ACTION  # re-exported (export, trainer)
from daddpg_jax.variants import BOTH, OWN, Variant

VariantLike = Variant | str


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


def as_variant(v: VariantLike) -> Variant:
    """The variants-table row `v`, or the row named `v`."""
    return v if isinstance(v, Variant) else variants.get(v)


def input_dims(variant: VariantLike, obs_size: int, goal_size: int = 3) -> tuple[int, int]:
    """(actor input dim, critic input dim) for a variant."""
    return as_variant(variant).input_dims(obs_size, goal_size)


def _flat(x):
    return x.reshape(x.shape[:-2] + (-1,))


def _both(v: Variant, o, g):
    """(o_1, o_2, g_1, g_2) flattened, one copy per agent: [A, B, 2 * (obs + 3)]."""
    x = jnp.concatenate([_flat(o), _flat(g)], -1)
    return jnp.broadcast_to(x, (v.num_agents,) + x.shape)


def _own(o, g):
    """Each arm's own (o_i, g_i), arm axis first: [2, B, obs + 3] (one agent per arm)."""
    return jnp.moveaxis(jnp.concatenate([o, g], -1), -2, 0)


def actor_inputs(variant: VariantLike, o, g):
    """o [B, 2, obs], g [B, 2, 3] -> [A, B, actor_in]."""
    v = as_variant(variant)
    if v.actor_sees == BOTH:
        return _both(v, o, g)
    assert v.actor_sees == OWN and v.arms_per_agent == 1, v
    return _own(o, g)


def critic_inputs(variant: VariantLike, o, g, a):
    """o [B, 2, obs], g [B, 2, 3], a [A, B, 8] (each agent's view of the joint action) ->
    [A, B, critic_in]."""
    v = as_variant(variant)
    if v.critic_sees == BOTH:
        return jnp.concatenate([_both(v, o, g), a], -1)
    assert v.critic_sees == OWN and v.arms_per_agent == 1, v
    d = v.agent_action_dim
    a_own = jnp.stack([a[i, :, d * i:d * (i + 1)] for i in range(v.num_agents)])
    return jnp.concatenate([_own(o, g), a_own], -1)


def joint_action(agent_actions):
    """[A, B, d] -> [B, A * d]: the agents' actions concatenated in agent order (arm 0 first)."""
    return jnp.concatenate([agent_actions[i] for i in range(agent_actions.shape[0])], -1)


def own_actions(variant: VariantLike, a):
    """Joint actions [B, 8] -> each agent's own slot [A, B, d] (inverse of `joint_action`)."""
    v = as_variant(variant)
    return jnp.swapaxes(a.reshape(a.shape[0], v.num_agents, v.agent_action_dim), 0, 1)


def own_action_mask(variant: VariantLike):
    """[A, 8] bool: agent j controls the joint-action columns [j * d, (j + 1) * d)."""
    v = as_variant(variant)
    return jnp.repeat(jnp.eye(v.num_agents, dtype=bool), v.agent_action_dim, axis=1)


def make_networks(variant: VariantLike, hidden: Sequence[int]):
    actor = MLP(tuple(hidden), as_variant(variant).agent_action_dim, True)
    critic = MLP(tuple(hidden), 1, False)
    return actor, critic


def init_params(key, variant: VariantLike, hidden: Sequence[int], obs_size: int,
                goal_size: int = 3):
    """Stacked (actor_params, critic_params), leading agent axis of size A."""
    v = as_variant(variant)
    actor, critic = make_networks(v, hidden)
    a_in, c_in = v.input_dims(obs_size, goal_size)
    n = v.num_agents
    k_a, k_c = jax.random.split(key)
    actor_params = jax.vmap(actor.init, in_axes=(0, None))(
        jax.random.split(k_a, n), jnp.zeros((1, a_in), jnp.float32))
    critic_params = jax.vmap(critic.init, in_axes=(0, None))(
        jax.random.split(k_c, n), jnp.zeros((1, c_in), jnp.float32))
    return actor_params, critic_params


def apply_stacked(module, params, x):
    """params with agent axis A, x [A, B, in] -> [A, B, ...]."""
    return jax.vmap(module.apply)(params, x)
