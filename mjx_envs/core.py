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

`DualArmEnv` is the plain env; ``mjx_envs.make`` wraps it in the concerns its config turns on
(`mjx_envs.wrappers`: physics randomization, observation and action perturbations, action
history), each with the same ``reset`` / ``step`` contract.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjx_envs import limit_rules, registry, rules
from mjx_envs import observation as obs_lib
from mjx_envs.model import home_state, load_model  # noqa: F401  (load_model re-exported)
from mjx_envs.physics.backends import default_physics, make_backend
from mjx_envs.settings import TaskConfig

NUM_ARMS = 2
SAMPLER = rules.JaxSampler()


def clip_action(action):
    """A policy action [8] as per-arm commands [2, 4] (dx, dy, dz, finger) in [-1, 1]."""
    return jnp.clip(jnp.asarray(action, jnp.float32).reshape(NUM_ARMS, 4), -1.0, 1.0)


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
    """Two UR3 arms with grippers, the plain env: true observations, nominal physics. What
    differs between tasks (goals, object placement, achieved goals, rewards) is ``self.rules``,
    a `mjx_envs.rules.TaskRules` bound to the task's settings (`mjx_envs.registry`, chosen by
    ``task_name``) and scene. Randomization, perturbations and the action history are wrappers
    around it (`mjx_envs.wrappers`; ``mjx_envs.make`` applies the ones its config turns on)."""

    task_name = "base"
    num_arms = NUM_ARMS
    action_size = 8
    goal_size = 3
    obs_size = obs_lib.OBS_SIZE
    info_keys: tuple[str, ...] = ("arm_contact_penalty",)
    """the goal-independent reward terms this env sets in ``info`` (`mjx_envs.rules.INFO_KEYS`;
    ``intervention_penalty`` too when its setting is on)"""

    @classmethod
    def default_config(cls) -> TaskConfig:
        """The task's settings (`mjx_envs.registry.default_config`)."""
        return registry.default_config(cls.task_name)

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
        self.limits = limit_rules.from_config(jnp, cfg)  # the robot's rules (None: off)
        self.intervention_penalty = float(cfg.intervention_penalty)
        if self.intervention_penalty > 0:  # (the config refuses it without robot_limits)
            self.info_keys = (*type(self).info_keys, "intervention_penalty")
        self.reward_range = (-(cfg.goal_scale + cfg.team_scale + cfg.arm_contact_penalty
                               + self.intervention_penalty), 0.0)
        # the nominal model's engine (`mjx_envs.wrappers.Randomize` replaces it by one that
        # takes per-env model parameters)
        self.backend = make_backend(self.physics, self.mj_model, cfg.n_substeps)

    @property
    def unwrapped(self) -> DualArmEnv:
        return self

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

    # -- the parts of reset and step (`mjx_envs.wrappers.Randomize` composes them too) ------------

    def _finger_ctrl(self, finger_cmd):
        cfg = self.config
        if cfg.lock_fingers:
            opening = jnp.full((NUM_ARMS,), cfg.locked_opening, jnp.float32)
        else:
            opening = (finger_cmd + 1.0) * 0.5 * cfg.finger_stroke
        if self.limits is not None:  # the robot's finger range
            opening = limit_rules.finger_opening(jnp, self.limits, opening)
        return jnp.repeat(opening, 2)  # two finger servos per arm: [l1, l2, r1, r2]

    def _observe(self, data, desired_goal, step):
        sens = self.backend.sensordata(data)
        obs, arm, obj = obs_lib.observe(jnp, self.sensors, sens, self.dt)
        ag = self.rules.achieved_goal(arm, obj).astype(jnp.float32)
        clearance = obs_lib.arm_clearance(jnp, arm["link_points"])
        arm_contact, info = self.rules.contact_terms(jnp, clearance)
        if self.intervention_penalty > 0:  # set by `charge` after a step's rules
            info["intervention_penalty"] = jnp.zeros((NUM_ARMS,), jnp.float32)
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

    def start_state(self, key, qpos):
        """(qpos, qvel, Cartesian targets, grasped) an episode starts from: the rules' ``qpos``
        at rest and the home targets (`ObjectPoseTask` may start from a grasped state instead:
        grasped = True)."""
        del key
        return (qpos, jnp.zeros((self.mj_model.nv,), jnp.float32), jnp.asarray(self._home_mocap),
                jnp.zeros((), bool))

    def launch(self, goal, qpos, qvel, mocap, params=None) -> State:
        """The episode's first state from its goal and start (``params``: the per-env model
        parameters of `mjx_envs.randomize`, None = nominal)."""
        data = self.backend.init(qpos, qvel, mocap, params)
        obs, _, metrics, info = self._observe(data, goal, jnp.zeros((), jnp.int32))
        return State(data=data, obs=obs, reward=jnp.zeros((NUM_ARMS,), jnp.float32),
                     done=jnp.zeros((), jnp.float32), metrics=metrics, info=info)

    def move_targets(self, target, delta):
        """The Cartesian targets [2, 3] moved by ``delta`` [2, 3] metres, clipped to the
        workspace boxes."""
        return jnp.clip(target + delta, self._ws_low, self._ws_high)

    def limit_targets(self, state: State, current, target):
        """(``target`` [2, 3] after the robot's rules, whether they changed it): the rules of
        `mjx_envs.limit_rules` (workspace clamp, speed cap and arm clearance from ``current``,
        with the link points and tool positions measured in ``state``), as the robot client's
        safety layer moves them, and a bool that is True where its count of interventions would
        rise (the finger range aside: `_finger_ctrl` applies it); (``target`` itself, False)
        without limits (``robot_limits = ()``)."""
        if self.limits is None:
            return target, jnp.zeros((), bool)
        links, tool = limit_rules.measured(jnp, self.sensors, self.backend.sensordata(state.data),
                                           self.dt)
        t, _, flags = limit_rules.apply(jnp, self.limits, current, target, links, tool,
                                        jnp.zeros((NUM_ARMS,), jnp.float32))
        return t, flags["workspace"] | flags["speed"] | flags["clearance"]

    def charge(self, state: State, intervened) -> State:
        """``state`` (after `advance`) with the intervention penalty of a step whose targets the
        rules changed (``intervened``: `limit_targets`) in its reward and ``info`` (both arms
        pay: the arms share the clearance); ``state`` itself when the penalty is off."""
        if self.intervention_penalty <= 0:
            return state
        pen = jnp.full((NUM_ARMS,), -self.intervention_penalty, jnp.float32) * intervened
        info = {**state.info, "intervention_penalty": pen}
        return state.replace(reward=state.reward + pen, info=info)

    def advance(self, state: State, target, finger_cmd, params=None) -> State:
        """One control step towards the true Cartesian ``target`` [2, 3] with finger commands
        [2] (``params`` as in `launch`)."""
        ctrl = self._finger_ctrl(finger_cmd)
        data = self.backend.step(state.data, ctrl, target, params)
        step = state.info["step"] + 1
        obs, reward, metrics, info = self._observe(data, state.obs["desired_goal"], step)
        done = (step >= self.episode_length).astype(jnp.float32)
        return State(data=data, obs=obs, reward=reward, done=done, metrics=metrics, info=info)

    # -- API --------------------------------------------------------------------------------------

    def reset(self, key) -> State:
        goal, qpos = self.rules.reset(jnp, SAMPLER, key)
        qpos, qvel, mocap, _ = self.start_state(key, qpos)
        return self.launch(goal, qpos, qvel, mocap)

    def step(self, state: State, action) -> State:
        a = clip_action(action)
        current = self.backend.mocap_pos(state.data)[:NUM_ARMS]
        target = self.move_targets(current, self.config.max_delta * a[:, :3])
        target, intervened = self.limit_targets(state, current, target)
        return self.charge(self.advance(state, target, a[:, 3]), intervened)

    def render(self, state: State, width: int = 640, height: int = 480, camera=None):
        """RGB frame [H, W, 3] of an unbatched state (host side, C engine's renderer)."""
        from mjx_envs.render import render_state  # lazy: it sets MUJOCO_GL for rendering only

        return render_state(self, state, width=width, height=height, camera=camera)

