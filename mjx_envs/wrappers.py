"""The env's cross-cutting concerns as wrappers around the plain dual-arm env, brax style.

A wrapper holds ``env``, forwards every attribute it does not define to it, and has the same
``reset(key) -> State`` / ``step(state, action) -> State`` contract; its per-episode carry
lives in ``State.info`` under its own key. `wrap` applies the ones a task config turns on, in
this order (``mjx_envs.make`` returns the result):

==================  ============  ===========================================================
wrapper             info key      fields (0 = off: no wrapper, no code, no carry)
==================  ============  ===========================================================
`Randomize`         ``physics``   the physics randomization fields (`mjx_envs.randomize`),
                                  including the arms' believed frames
`Perturb`           ``perturb``   obs_noise, obs_dropout, obs_bias, obs_period, latency
                                  (`mjx_envs.perturb`)
`ActionHistory`     ``action_     action_history (`mjx_envs.observation`)
                    history``
==================  ============  ===========================================================

`Randomize` acts on the physics, so it wraps the plain env itself and composes its parts
(``start_state``, ``launch``, ``move_targets``, ``advance``); like brax's domain
randomization wrapper, which swaps the model of the env it wraps, it gives the plain env a
backend that takes per-env model parameters. The two others act on what the policy sees and
sends only: each applies one stage of `mjx_envs.pipeline`, the code the robot client runs over
NumPy. Each keeps its own PRNG stream (``fold_in`` of the reset key), so a concern's draws do
not change those of the task or of another concern.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mjx_envs import perturb, pipeline, randomize
from mjx_envs.core import NUM_ARMS, SAMPLER, State, clip_action
from mjx_envs.observation import ARM_ACTION_SIZE
from mjx_envs.physics.backends import make_backend


class Wrapper:
    """An env around ``env`` with the same contract; attributes it lacks are ``env``'s."""

    def __init__(self, env):
        self.env = env

    def reset(self, key) -> State:
        return self.env.reset(key)

    def step(self, state: State, action) -> State:
        return self.env.step(state, action)

    @property
    def unwrapped(self):
        """The plain env inside every wrapper."""
        return self.env.unwrapped

    def __getattr__(self, name):
        if name == "env":  # not set yet (e.g. while unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.env, name)


class Randomize(Wrapper):
    """Per-env physics randomization drawn at reset (`mjx_envs.randomize`); ``info["physics"]``
    holds the episode's ``params`` [PARAMS] and ``action_scale`` []."""

    def __init__(self, env, randomization: randomize.Randomization):
        if env is not env.unwrapped:
            raise ValueError("Randomize wraps the plain env (it acts on its physics)")
        super().__init__(env)
        self.randomization = r = randomization
        rules = env.rules
        self.model_index = randomize.ModelIndex(
            env.mj_model, rules.object_body if rules.has_object else None, r)
        if r.physical:
            env.backend = make_backend(env.physics, env.mj_model, env.config.n_substeps,
                                       rand=self.model_index)

    def _params(self, rand):
        """The backend's per-env parameters (None without physical randomization)."""
        return rand["params"] if self.randomization.physical else None

    def _seen(self, state: State, rand) -> State:
        """``state`` with the episode's values in its info and, when the bases move, the
        observation as the arms believe it (each gripper in its arm's nominal frame)."""
        obs = state.obs
        if self.randomization.moves_base:
            seen = randomize.believed_obs(jnp, self.model_index, rand["params"],
                                          obs["observation"])
            obs = dict(obs, observation=seen.astype(jnp.float32))
        return state.replace(obs=obs, info=dict(state.info, physics=rand))

    def reset(self, key) -> State:
        env, r, ix = self.env, self.randomization, self.model_index
        goal, qpos = env.rules.reset(jnp, SAMPLER, key)
        values = randomize.draw(jnp, SAMPLER, jax.random.fold_in(key, randomize.STREAM), r)
        shift = values["rest_shift"]  # the object's resting height moves with size and table
        if env.rules.has_object:
            qpos = qpos.at[env.rules.qpos_adr + 2].add(shift)
            goal = goal.at[..., 2].add(shift)
        rand = dict(params=values["params"], action_scale=values["action_scale"])
        qpos, qvel, mocap, grasped = env.start_state(key, qpos)
        if r.physical:
            # a recorded grasped state is geometry-exact only under the nominal geometry: such
            # an episode keeps the size, table and arm bases nominal (and its goal); without
            # grasped starts `grasped` is a constant False and this changes nothing
            nominal = jnp.asarray(randomize.nominal_params())
            keep = jnp.asarray(randomize.GEOMETRY_MASK)
            rand = dict(rand, params=jnp.where(grasped & keep, nominal, rand["params"]))
            if env.rules.has_object:
                goal = jnp.where(grasped, goal.at[..., 2].add(-shift), goal)
            if r.moves_base:
                mocap = randomize.to_true(jnp, ix, rand["params"], mocap)
        return self._seen(env.launch(goal, qpos, qvel, mocap, self._params(rand)), rand)

    def step(self, state: State, action) -> State:
        env, ix, rand = self.env, self.model_index, state.info["physics"]
        moves_base = self.randomization.moves_base
        a = clip_action(action)
        target = env.backend.mocap_pos(state.data)[:NUM_ARMS]
        if moves_base:  # the arms' targets live in their nominal frames
            target = randomize.to_nominal(jnp, ix, rand["params"], target)
        target, intervened = env.limit_targets(state, target, env.move_targets(
            target, env.config.max_delta * a[:, :3] * rand["action_scale"]))
        if moves_base:
            target = randomize.to_true(jnp, ix, rand["params"], target)
        state = env.charge(env.advance(state, target, a[:, 3], self._params(rand)), intervened)
        return self._seen(state, rand)


class ObservationStage(Wrapper):
    """One stage of `mjx_envs.pipeline` applied to the env's observations and actions, its
    carry in ``info[info_key]``."""

    info_key: str
    stream: int | None = None
    """fold_in constant of the stage's draws (None: it draws nothing)"""

    def __init__(self, env, stage):
        super().__init__(env)
        self.stage = stage

    def reset(self, key) -> State:
        s = self.env.reset(key)
        k = key if self.stream is None else jax.random.fold_in(key, self.stream)
        seen, carry = self.stage.start(k, s.obs["observation"])
        return s.replace(obs=dict(s.obs, observation=seen),
                         info=dict(s.info, **{self.info_key: carry}))

    def step(self, state: State, action) -> State:
        action, carry = self.stage.act(state.info[self.info_key], clip_action(action).reshape(-1))
        s = self.env.step(state, action)
        seen, carry = self.stage.observe(carry, s.obs["observation"])
        return s.replace(obs=dict(s.obs, observation=seen),
                         info=dict(s.info, **{self.info_key: carry}))


class Perturb(ObservationStage):
    """Observation and action perturbations (`mjx_envs.perturb`); the true observation stays
    in nothing the policy sees, the achieved goal, reward and success stay true."""

    info_key = "perturb"
    stream = perturb.STREAM

    def __init__(self, env, perturbation: perturb.Perturbation):
        super().__init__(env, pipeline.PerturbStage(jnp, SAMPLER, perturbation))
        self.perturbation = perturbation


class ActionHistory(ObservationStage):
    """Each arm's observation ends with its own last ``k`` actions as the policy chose them
    (`mjx_envs.observation.obs_fields`)."""

    info_key = "action_history"

    def __init__(self, env, k: int):
        super().__init__(env, pipeline.HistoryStage(jnp, k))
        self.action_history = int(k)
        self.obs_size = env.obs_size + ARM_ACTION_SIZE * self.action_history


def wrap(env):
    """``env`` (a plain env) in the wrappers its config turns on (`Randomize`, `Perturb`,
    `ActionHistory`, innermost first); ``env`` itself when they are all off."""
    cfg = env.config
    r = randomize.Randomization.from_config(cfg)
    if r.active:
        env = Randomize(env, r)
    p = perturb.Perturbation.from_config(cfg)
    if p.active:
        env = Perturb(env, p)
    if int(cfg.action_history) > 0:
        env = ActionHistory(env, cfg.action_history)
    return env


def find(env, cls):
    """The wrapper of type ``cls`` around ``env``'s plain env, or None."""
    while env is not env.unwrapped:
        if isinstance(env, cls):
            return env
        env = env.env
    return None
