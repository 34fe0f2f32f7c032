"""The trained actors as a deterministic policy: the part of a training state that acts.

`ActorParams` holds what acting needs of a `daddpg_jax.algo.train.TrainState`: the agents'
stacked actor parameters (``agent.actor``) and the two normalizers. `act` is the deterministic
joint action of the actors, the one function behind the trainer's ``act`` (and so its test
episodes) and the evaluation of a saved run. `abstract_params` gives the shapes and dtypes of a
run's ActorParams from the networks' and the normalizers' own init functions (``jax.eval_shape``:
nothing allocated), the target a checkpoint's actors are restored into
(``daddpg_jax.running.checkpoint_policy``, no training step built).

    o, g = normalize_inputs(cfg, params, obs, desired_goal)   # [B, 2, obs], [B, 2, 3]
    pi   = agent_actions(cfg, params, o, g)                    # [A, B, d], in [-1, 1]
    act(cfg, params, obs, desired_goal)                        # joint_action(pi): [..., 8]
"""

from __future__ import annotations

import jax
from flax import struct

from daddpg_jax.algo import networks as nets
from daddpg_jax.algo import normalizer as norm
from daddpg_jax.algo.config import TrainConfig
from daddpg_jax.variants import NUM_ARMS


@struct.dataclass
class ActorParams:
    actor: dict               # stacked actor params [A, ...] (a TrainState's agent.actor)
    obs_norm: norm.NormState  # per-arm observation statistics [2, obs_size]
    goal_norm: norm.NormState  # per-arm goal statistics [2, goal_size]


def of_state(state) -> ActorParams:
    """The ActorParams of a TrainState (its agent's actor and its normalizers); an ActorParams
    as it is."""
    if isinstance(state, ActorParams):
        return state
    return ActorParams(actor=state.agent.actor, obs_norm=state.obs_norm,
                       goal_norm=state.goal_norm)


def norm_kw(cfg: TrainConfig) -> dict:
    """The normalizers' settings of a config (keywords of `normalizer.normalize`)."""
    return dict(eps=cfg.norm_eps, clip=cfg.norm_clip, clip_obs=cfg.clip_obs)


def normalize_inputs(cfg: TrainConfig, params: ActorParams, o, g):
    """Raw observations o [..., 2, obs] and goals g [..., 2, 3], normalized."""
    kw = norm_kw(cfg)
    return norm.normalize(params.obs_norm, o, **kw), norm.normalize(params.goal_norm, g, **kw)


def actor_module(cfg: TrainConfig) -> nets.MLP:
    """The actor network of cfg's variant and hidden layers (one definition for every agent)."""
    return nets.make_networks(cfg.algo, cfg.hidden)[0]


def agent_actions(cfg: TrainConfig, params: ActorParams, o, g):
    """Normalized o [B, 2, obs], g [B, 2, 3] -> per-agent actions [A, B, d] (as
    `losses.policy_actions`)."""
    return nets.apply_stacked(actor_module(cfg), params.actor, nets.actor_inputs(cfg.algo, o, g))


def act(cfg: TrainConfig, params: ActorParams, obs, desired_goal):
    """Deterministic joint action [..., 8] for raw observations [..., 2, obs] and goals
    [..., 2, 3]."""
    lead = obs.shape[:-2]
    o = obs.reshape((-1,) + obs.shape[-2:])
    g = desired_goal.reshape((-1,) + desired_goal.shape[-2:])
    o, g = normalize_inputs(cfg, params, o, g)
    a = nets.joint_action(agent_actions(cfg, params, o, g))
    return a.reshape(lead + a.shape[-1:])


def abstract_params(cfg: TrainConfig, obs_size: int, goal_size: int = 3) -> ActorParams:
    """ShapeDtypeStructs of the ActorParams of a run of `cfg` on an env of `obs_size` /
    `goal_size`: the actors from `networks.init_params` (the Flax modules' init), the
    normalizers from `normalizer.init`, traced only (nothing allocated)."""
    def init():
        actor, _ = nets.init_params(jax.random.PRNGKey(0), cfg.algo, cfg.hidden, obs_size,
                                    goal_size)
        return ActorParams(actor=actor, obs_norm=norm.init((NUM_ARMS, obs_size)),
                           goal_norm=norm.init((NUM_ARMS, goal_size)))

    return jax.eval_shape(init)
