"""DADDPG losses and the gradient update of both agents (stacked on the agent axis).

Per agent i (A agents: 2 arms, or 1 for 'single'):
    critic:  y_i = clip(r_i + gamma * Q'_i(o', g, mu'(o', g)), lo, hi)       (no done mask:
             episodes are fixed-length time limits, as in the HER baselines); with n-step
             returns (TrainConfig.n_step > 1) r_i is the n-step return, o' the state m <= n
             steps later and gamma^m replaces gamma (batch["discount"])
             L_i = mean_B (y_i - Q_i(o, g, a))^2
    actor:   J_i = -mean_B Q_i(o, g, a with arm i's slot replaced by mu_i(o, g))
                   + action_l2 * mean(mu_i(o, g)^2)
             the other arm's slot holds the buffer action (or the current policy's action
             under stop_gradient), so J_i depends on actor i's parameters only.
    demos:   with demonstrations (TrainConfig.n_demos > 0, not in the paper) the batch also
             holds demo rows (batch["demo"]) and J_i gets + bc_weight * BC_i, the (Q-filtered)
             squared error between mu_i and the demo action on those rows (`bc_loss`).
The summed loss over agents has per-agent gradients (agents share no parameters), and Adam is
elementwise, so one optax update over the stacked parameters updates every agent independently.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from daddpg_jax.algo import networks as nets
from daddpg_jax.variants import NUM_ARMS, SUM, Variant


@struct.dataclass
class AgentState:
    actor: dict           # stacked actor params [A, ...]
    critic: dict          # stacked critic params [A, ...]
    target_actor: dict
    target_critic: dict
    actor_opt: optax.OptState
    critic_opt: optax.OptState


class Learner(NamedTuple):
    """Static pieces of the learner (variant, modules, optimizers, constants)."""
    variant: Variant
    actor: nets.MLP
    critic: nets.MLP
    actor_tx: optax.GradientTransformation
    critic_tx: optax.GradientTransformation
    gamma: float
    action_l2: float
    target_lo: float
    target_hi: float
    clip_target: bool
    other_action: str
    bc_weight: float = 0.0
    q_filter: bool = True


def target_bounds(variant: nets.VariantLike, reward_range, gamma: float):
    """[r_min/(1-gamma), r_max/(1-gamma)] per agent, r = the agent's reward: one arm's
    ('per_arm'), or the sum over the arms ('sum': the arms' bounds summed)."""
    r_min, r_max = float(reward_range[0]), float(reward_range[1])
    if nets.as_variant(variant).reward == SUM:
        r_min, r_max = NUM_ARMS * r_min, NUM_ARMS * r_max
    return r_min / (1.0 - gamma), r_max / (1.0 - gamma)


def make_learner(cfg, reward_range) -> Learner:
    variant = nets.as_variant(cfg.algo)
    actor, critic = nets.make_networks(variant, cfg.hidden)
    lo, hi = target_bounds(variant, reward_range, cfg.gamma)
    return Learner(variant, actor, critic, optax.adam(cfg.lr_actor), optax.adam(cfg.lr_critic),
                   cfg.gamma, cfg.action_l2, lo, hi, cfg.clip_target, cfg.other_action,
                   float(cfg.bc_weight) if cfg.n_demos > 0 else 0.0, bool(cfg.q_filter))


def init_agent_state(key, learner: Learner, hidden, obs_size: int,
                     goal_size: int = 3) -> AgentState:
    actor_p, critic_p = nets.init_params(key, learner.variant, hidden, obs_size, goal_size)
    return AgentState(actor=actor_p, critic=critic_p,
                      target_actor=jax.tree.map(jnp.copy, actor_p),
                      target_critic=jax.tree.map(jnp.copy, critic_p),
                      actor_opt=learner.actor_tx.init(actor_p),
                      critic_opt=learner.critic_tx.init(critic_p))


def agent_rewards(variant: nets.VariantLike, r):
    """Per-arm rewards [B, 2] -> per-agent rewards [A, B] (arm i's, or the sum over arms)."""
    if nets.as_variant(variant).reward == SUM:
        return jnp.sum(r, -1)[None]
    return jnp.swapaxes(r, 0, 1)


def td_target(r, q_next, gamma: float, lo: float, hi: float, clip: bool = True):
    y = r + gamma * q_next
    return jnp.clip(y, lo, hi) if clip else y


def polyak_update(target, online, polyak: float):
    """target <- polyak * target + (1 - polyak) * online."""
    return jax.tree.map(lambda t, o: polyak * t + (1.0 - polyak) * o, target, online)


def policy_actions(learner: Learner, actor_params, o, g):
    """Normalized o [B,2,obs], g [B,2,3] -> per-agent actions [A, B, act_dim]."""
    return nets.apply_stacked(learner.actor, actor_params,
                              nets.actor_inputs(learner.variant, o, g))


def q_values(learner: Learner, critic_params, o, g, a_joint):
    """a_joint [A, B, 8] (each agent's view of the joint action) -> Q [A, B]."""
    return nets.apply_stacked(learner.critic, critic_params,
                              nets.critic_inputs(learner.variant, o, g, a_joint))


def _bcast(a, n):
    return jnp.broadcast_to(a, (n,) + a.shape)


def critic_loss(critic_params, target_actor, target_critic, batch, learner: Learner):
    """batch: normalized o, o2, g, actions a [B,8], per-agent rewards r [A,B]."""
    n = batch["r"].shape[0]
    a2 = nets.joint_action(policy_actions(learner, target_actor, batch["o2"], batch["g"]))
    q2 = q_values(learner, target_critic, batch["o2"], batch["g"], _bcast(a2, n))
    # n-step batches carry each row's bootstrap discount gamma^m; one-step batches use gamma
    gamma = batch["discount"][None] if "discount" in batch else learner.gamma
    y = jax.lax.stop_gradient(td_target(batch["r"], q2, gamma, learner.target_lo,
                                        learner.target_hi, learner.clip_target))
    q = q_values(learner, critic_params, batch["o"], batch["g"], _bcast(batch["a"], n))
    per_agent = jnp.mean(jnp.square(y - q), axis=1)
    return jnp.sum(per_agent), dict(critic_loss=per_agent, mean_q=jnp.mean(q, 1),
                                    mean_target=jnp.mean(y, 1))


def actor_loss(actor_params, critic_params, batch, learner: Learner):
    pi = policy_actions(learner, actor_params, batch["o"], batch["g"])      # [A, B, d]
    n, _, d = pi.shape
    if learner.other_action == "policy":
        base = jax.lax.stop_gradient(nets.joint_action(pi))
    else:
        base = batch["a"]
    own = nets.own_action_mask(learner.variant)[:, None, :]                 # [A, 1, 8]
    mixed = jnp.where(own, jnp.tile(pi, (1, 1, own.shape[-1] // d)), _bcast(base, n))
    q = q_values(learner, critic_params, batch["o"], batch["g"], mixed)     # [A, B]
    per_agent = -jnp.mean(q, 1) + learner.action_l2 * jnp.mean(jnp.square(pi), axis=(1, 2))
    aux = dict(actor_loss=per_agent)
    if "demo" in batch:
        bc, passed = bc_loss(pi, q, critic_params, batch, learner)
        per_agent = per_agent + learner.bc_weight * bc
        aux.update(actor_loss=per_agent, bc_loss=bc, q_filter_pass=passed)
    return jnp.sum(per_agent), aux


def bc_loss(pi, q_pi, critic_params, batch, learner: Learner):
    """Behaviour cloning on the demo rows of a batch (batch["demo"] [B] bool).

    Per agent i: sum over demo rows of f_i * ||pi_i - a_demo,i||^2 / (number of demo rows),
    with f_i = [Q_i(o, g, a_demo) > Q_i(o, g, a with slot i = pi_i)] under the Q filter
    (q_pi: the latter, [A, B]) and f_i = 1 without it. Returns (bc [A], filter pass rate [A]
    over demo rows)."""
    demo = batch["demo"].astype(jnp.float32)                               # [B]
    n = pi.shape[0]
    err = jnp.sum(jnp.square(pi - nets.own_actions(learner.variant, batch["a"])), -1)   # [A, B]
    if learner.q_filter:
        q_demo = q_values(learner, critic_params, batch["o"], batch["g"], _bcast(batch["a"], n))
        keep = jax.lax.stop_gradient((q_demo > q_pi).astype(jnp.float32))
    else:
        keep = jnp.ones_like(err)
    w = keep * demo[None]
    n_demo = jnp.maximum(jnp.sum(demo), 1.0)
    return jnp.sum(w * err, 1) / n_demo, jnp.sum(w, 1) / n_demo


def update(agent: AgentState, batch, learner: Learner, axis_name=None):
    """One gradient step of every actor and critic from the same minibatch (both losses use the
    pre-update parameters, as the HER baselines do). Returns (agent, metrics).

    axis_name: inside ``shard_map`` over devices, each device holds an equal slice of the
    batch; gradients and metrics are ``pmean``-ed over that axis before the Optax update, so
    the result equals the update on the whole batch and parameters stay replicated."""
    critic_p, actor_p = agent.critic, agent.actor
    if axis_name is not None:
        # differentiate per-device copies: the gradients are then this device's batch-mean
        # gradients (with check_vma, JAX would otherwise psum gradients of replicated inputs
        # implicitly), averaged explicitly below
        critic_p, actor_p = _pvary((critic_p, actor_p), axis_name)
    (_, c_aux), c_grads = jax.value_and_grad(critic_loss, has_aux=True)(
        critic_p, agent.target_actor, agent.target_critic, batch, learner)
    (_, a_aux), a_grads = jax.value_and_grad(actor_loss, has_aux=True)(
        actor_p, agent.critic, batch, learner)
    if axis_name is not None:
        c_grads, a_grads, c_aux, a_aux = jax.lax.pmean((c_grads, a_grads, c_aux, a_aux), axis_name)
    c_upd, critic_opt = learner.critic_tx.update(c_grads, agent.critic_opt, agent.critic)
    a_upd, actor_opt = learner.actor_tx.update(a_grads, agent.actor_opt, agent.actor)
    agent = agent.replace(critic=optax.apply_updates(agent.critic, c_upd), critic_opt=critic_opt,
                          actor=optax.apply_updates(agent.actor, a_upd), actor_opt=actor_opt)
    return agent, {**c_aux, **a_aux}


def _pvary(tree, axis_name):
    """Marks replicated values as device-varying inside shard_map (no-op without VMA checks)."""
    def cast(x):
        try:
            return jax.lax.pcast(x, axis_name, to="varying")
        except ValueError:  # already varying over axis_name
            return x
    return jax.tree.map(cast, tree)


def update_targets(agent: AgentState, polyak: float) -> AgentState:
    return agent.replace(target_actor=polyak_update(agent.target_actor, agent.actor, polyak),
                         target_critic=polyak_update(agent.target_critic, agent.critic, polyak))
