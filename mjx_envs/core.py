"""Dual-arm environment core shared by every task.

Pure functional API for ONE env (batch with ``jax.vmap``)::

    env = mjx_envs.make("push", physics="c")
    state = env.reset(key)
    state = env.step(state, action)          # action: [8] = per arm [dx, dy, dz, finger]

Cartesian control: each gripper's tool centre point is welded to a mocap target (as in the
Fetch tasks). A step moves each target by ``max_delta * clip(a[:3], -1, 1)`` metres, clipped to
that arm's workspace box, with a fixed downward orientation; the weld pulls the arm along. The
finger command maps [-1, 1] to the finger opening [0, finger_stroke] (or is ignored and the
fingers held closed when ``lock_fingers``). See docs/ENVIRONMENTS.md for why.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjx_envs import observation as obs_lib
from mjx_envs import perturb, randomize, registry, rules, settings
from mjx_envs.model import home_state, load_model  # noqa: F401  (load_model re-exported)
from mjx_envs.physics.backends import default_physics, make_backend
from mjx_envs.settings import TaskConfig, replace_config  # noqa: F401  (re-exported)

NUM_ARMS = 2
SAMPLER = rules.JaxSampler()
PERTURB_STREAM = 0x5E750
"""fold_in constant of the observation/action perturbations' draws (mjx_envs/perturb.py): the
task's own draws stay those of the unperturbed env"""
RANDOMIZE_STREAM = 0x9A7D0
"""fold_in constant of the physics randomization's draws (mjx_envs/randomize.py)"""


@struct.dataclass
class State:
    """One env's state. ``obs`` arrays carry a leading arm axis of 2 (0 = left, 1 = right)."""

    data: Any
    obs: dict[str, jax.Array]
    reward: jax.Array  # [2] per-arm reward of the last step
    done: jax.Array  # [] 1.0 at the last step of the fixed-length episode
    metrics: dict[str, jax.Array]
    info: dict[str, jax.Array]


class DualArmEnv:
    """Two UR3 arms with grippers. What differs between tasks (goals, object placement,
    achieved goals, rewards) is ``self.rules``, a `mjx_envs.rules.TaskRules` bound to the task's
    settings (`mjx_envs.settings`, chosen by ``task_name``) and scene."""

    task_name = "base"
    num_arms = NUM_ARMS
    action_size = 8
    goal_size = 3
    obs_size = obs_lib.OBS_SIZE
    info_keys: tuple[str, ...] = rules.INFO_KEYS

    @classmethod
    def default_config(cls) -> TaskConfig:
        """The task's settings from `mjx_envs.settings`."""
        return settings.default_config(cls.task_name)

    def __init__(self, config: TaskConfig | None = None, physics: str = "auto"):
        self.config = config or self.default_config()
        cfg = self.config
        if cfg.episode_length < 2:
            raise ValueError("episode_length must be >= 2")
        if cfg.n_substeps < 1:
            raise ValueError("n_substeps must be >= 1")
        self.physics = default_physics() if physics == "auto" else physics
        self.mj_model = load_model(cfg.scene, cfg.timestep, cfg.cone, cfg.physics_version)
        self.episode_length = int(cfg.episode_length)
        self.dt = float(cfg.timestep * cfg.n_substeps)
        self.sensors = obs_lib.SensorLayout.from_model(self.mj_model)
        self._home_qpos, self._home_mocap = home_state(self.mj_model)
        self._ws_low = np.asarray(cfg.workspace_low, np.float32)
        self._ws_high = np.asarray(cfg.workspace_high, np.float32)
        self.rules = registry.make_rules(self.task_name, cfg, self.mj_model)
        # static: with every randomization field 0 the env has no randomization code nor carry
        self.randomization = randomize.Randomization.from_config(cfg)
        self._rand_index = None
        if self.randomization.active:
            obj = settings.OBJECTS.get(self.task_name)
            self._rand_index = randomize.ModelIndex(self.mj_model, obj[1] if obj else None,
                                                    self.randomization)
        self.backend = make_backend(
            self.physics, self.mj_model, cfg.n_substeps,
            rand=self._rand_index if self.randomization.physical else None)
        self.reward_range = (-(cfg.goal_scale + cfg.team_scale + cfg.arm_contact_penalty), 0.0)
        # static: with every perturbation field 0 the env has no perturbation code nor carry
        self.perturbation = perturb.Perturbation.from_config(cfg)
        # static: the policy's last k actions end each arm's observation (0 = none, no carry)
        self.action_history = int(cfg.action_history)
        self.obs_size = obs_lib.obs_size(self.action_history)

    # -- rewards ----------------------------------------------------------------------------------

    def goal_distance(self, achieved_goal, desired_goal):
        return self.rules.goal_distance(jnp, achieved_goal, desired_goal)

    def success(self, achieved_goal, desired_goal):
        """1.0 where every arm is within the threshold; shape = leading axes."""
        return self.rules.success(jnp, achieved_goal, desired_goal)

    def reward_terms(self, achieved_goal, desired_goal) -> dict[str, jax.Array]:
        """Goal-dependent per-arm terms [..., 2] (raw, before scaling)."""
        return self.rules.reward_terms(jnp, achieved_goal, desired_goal)

    def compute_reward(self, achieved_goal, desired_goal, info=None):
        """Per-arm reward [..., 2]: goal term + team term + goal-independent ``info`` terms.

        Broadcasts over any leading axes; 0 exactly when the arm is within the threshold (and,
        with a team term, when both are) and no penalty applies. ``info`` may be None, ``{}`` or
        lack any of ``info_keys``: a missing term counts as 0 (the Gymnasium/HER convention).
        """
        return self.rules.reward(jnp, jnp.asarray(achieved_goal), jnp.asarray(desired_goal),
                                 info)

    # -- API --------------------------------------------------------------------------------------

    def _finger_ctrl(self, finger_cmd):
        cfg = self.config
        if cfg.lock_fingers:
            opening = jnp.full((NUM_ARMS,), cfg.locked_opening, jnp.float32)
        else:
            opening = (finger_cmd + 1.0) * 0.5 * cfg.finger_stroke
        return jnp.repeat(opening, 2)  # two finger servos per arm: [l1, l2, r1, r2]

    def _observe(self, data, desired_goal, step):
        sens = self.backend.sensordata(data)
        obs, arm, obj = obs_lib.observe(jnp, self.sensors, sens, self.dt)
        ag = self.rules.achieved_goal(arm, obj).astype(jnp.float32)
        clearance = obs_lib.arm_clearance(jnp, arm["link_points"])
        arm_contact, info = self.rules.contact_terms(jnp, clearance)
        info["step"] = step
        terms = self.reward_terms(ag, desired_goal)
        reward = self.rules.reward(jnp, ag, desired_goal, info, terms=terms)
        metrics = {
            "success": self.success(ag, desired_goal),
            "arm_contact": arm_contact,
            "arm_clearance": clearance.astype(jnp.float32),
            "goal_distance": jnp.mean(self.goal_distance(ag, desired_goal)),
            "reward": jnp.mean(reward),
            "reward_goal": jnp.mean(terms["goal"]),
            "reward_team": jnp.mean(terms["team"]),
            "reward_arm_contact": jnp.mean(info["arm_contact_penalty"]),
            "physics_ok": self.backend.ok(data),
        }
        o = {"observation": obs, "achieved_goal": ag,
             "desired_goal": desired_goal.astype(jnp.float32)}
        return o, reward.astype(jnp.float32), metrics, info

    def _start_state(self, key, qpos):
        """(qpos, qvel, Cartesian targets, grasped) an episode starts from: the rules' ``qpos``
        at rest and the home targets (`ObjectPoseTask` may start from a grasped state instead:
        grasped = True)."""
        del key
        return (qpos, jnp.zeros((self.mj_model.nv,), jnp.float32), jnp.asarray(self._home_mocap),
                jnp.zeros((), bool))

    def _randomize(self, key, goal, qpos):
        """(goal, qpos, this episode's randomization values, rest shift) with the resting height
        moved by the object's size and the table's height (mjx_envs/randomize.py)."""
        values = randomize.draw(jnp, SAMPLER, jax.random.fold_in(key, RANDOMIZE_STREAM),
                                self.randomization)
        if self.rules.has_object:
            z = self.rules.qpos_adr + 2
            qpos = qpos.at[z].add(values["rest_shift"])
            goal = goal.at[..., 2].add(values["rest_shift"])
        return (goal, qpos, dict(params=values["params"], action_scale=values["action_scale"]),
                values["rest_shift"])

    def _physics_params(self, info):
        """The backend's per-env parameters (None without physical randomization)."""
        return info["physics"]["params"] if self.randomization.physical else None

    def _believed(self, obs, info):
        """The observation as the arms believe it (base calibration error), else as is."""
        if not self.randomization.moves_base:
            return obs
        seen = randomize.believed_obs(jnp, self._rand_index, info["physics"]["params"],
                                      obs["observation"])
        return dict(obs, observation=seen.astype(jnp.float32))

    def reset(self, key) -> State:
        goal, qpos = self.rules.reset(jnp, SAMPLER, key)
        rand = None
        if self.randomization.active:
            goal, qpos, rand, shift = self._randomize(key, goal, qpos)
        qpos, qvel, mocap, grasped = self._start_state(key, qpos)
        params = None
        if rand is not None and self.randomization.physical:
            if getattr(self, "grasp_states", None) is not None:
                # a recorded grasped state is geometry-exact only under the nominal geometry:
                # such an episode keeps the size, table and arm bases nominal (and its goal)
                nominal = jnp.asarray(randomize.nominal_params())
                keep = jnp.asarray(randomize.GEOMETRY_MASK)
                rand = dict(rand, params=jnp.where(grasped & keep, nominal, rand["params"]))
                if self.rules.has_object:
                    goal = jnp.where(grasped, goal.at[..., 2].add(-shift), goal)
            params = rand["params"]
            if self.randomization.moves_base:
                mocap = randomize.to_true(jnp, self._rand_index, params, mocap)
        data = self.backend.init(qpos, qvel, mocap, params)
        step = jnp.zeros((), jnp.int32)
        obs, reward, metrics, info = self._observe(data, goal, step)
        if rand is not None:
            info = dict(info, physics=rand)
            obs = self._believed(obs, info)
        if self.perturbation.active:
            k_start, k_carry = jax.random.split(jax.random.fold_in(key, PERTURB_STREAM))
            seen, carry = perturb.start(jnp, SAMPLER, k_start, self.perturbation,
                                        obs["observation"])
            obs = dict(obs, observation=seen)
            info = dict(info, perturb=dict(carry, key=k_carry))
        if self.action_history:
            hist = obs_lib.empty_action_history(jnp, self.action_history)
            obs = dict(obs, observation=obs_lib.with_action_history(jnp, obs["observation"], hist))
            info = dict(info, action_history=hist)
        return State(data=data, obs=obs, reward=jnp.zeros((NUM_ARMS,), jnp.float32),
                     done=jnp.zeros((), jnp.float32), metrics=metrics, info=info)

    def step(self, state: State, action) -> State:
        a = jnp.clip(jnp.asarray(action, jnp.float32).reshape(NUM_ARMS, 4), -1.0, 1.0)
        chosen = a
        p = self.perturbation
        if p.active:
            carry = state.info["perturb"]
            a, carry = perturb.delay(jnp, p, carry, a.reshape(-1))
            a = a.reshape(NUM_ARMS, 4)
        r = self.randomization
        target = self.backend.mocap_pos(state.data)[:NUM_ARMS]
        delta = self.config.max_delta * a[:, :3]
        if r.active:
            rand = state.info["physics"]
            delta = delta * rand["action_scale"]
            if r.moves_base:  # the arms' targets live in their nominal frames
                target = randomize.to_nominal(jnp, self._rand_index, rand["params"], target)
        target = jnp.clip(target + delta, self._ws_low, self._ws_high)
        if r.moves_base:
            target = randomize.to_true(jnp, self._rand_index, rand["params"], target)
        ctrl = self._finger_ctrl(a[:, 3])
        params = self._physics_params(state.info) if r.active else None
        data = self.backend.step(state.data, ctrl, target, params)
        step = state.info["step"] + 1
        obs, reward, metrics, info = self._observe(data, state.obs["desired_goal"], step)
        if r.active:
            info = dict(info, physics=rand)
            obs = self._believed(obs, info)
        if p.active:
            key, k_obs = jax.random.split(carry["key"])
            if p.observes:
                seen, carry = perturb.observe(jnp, SAMPLER, k_obs, p, carry, obs["observation"])
                obs = dict(obs, observation=seen)
            info = dict(info, perturb=dict(carry, key=key))
        if self.action_history:
            hist = obs_lib.push_action(jnp, state.info["action_history"], chosen)
            obs = dict(obs, observation=obs_lib.with_action_history(jnp, obs["observation"], hist))
            info = dict(info, action_history=hist)
        done = (step >= self.episode_length).astype(jnp.float32)
        return State(data=data, obs=obs, reward=reward, done=done, metrics=metrics, info=info)

    def render(self, state: State, width: int = 640, height: int = 480, camera=None):
        """RGB frame [H, W, 3] of an unbatched state (host side, C engine's renderer)."""
        from mjx_envs.render import render_state

        return render_state(self, state, width=width, height=height, camera=camera)

