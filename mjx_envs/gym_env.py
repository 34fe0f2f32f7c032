"""Gymnasium adapter: every task as a goal-conditioned ``gymnasium.Env`` (NumPy only, no JAX).

    import gymnasium as gym
    env = gym.make("mjx_envs:DualUR3Push-v0")   # importing mjx_envs registers the ids:
                                                # DualUR3{Reach,Push,Pickup,Pot}-v0 and the
                                                # dense-reward DualUR3{...}Dense-v0
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

One env, stepped step by step with MuJoCo's C engine from NumPy: the adapter wraps
``mjx_envs.numpy_env.NumpyDualArmEnv`` (``self.sim``), so no jitted function is dispatched per
step and JAX is never imported. The dynamics repeat the trainer's C-engine env (same MJCF,
timestep, substeps, mocap-weld control, float32 state between control steps, solver warmstart
reset every control step) and the task rules are the JAX env's (`mjx_envs.rules`), so a policy
trained by ``daddpg_jax`` behaves the same here.

Spaces
- observation: ``Dict(observation=Box[50], achieved_goal=Box[6], desired_goal=Box[6])``,
  float32: the env's per-arm arrays ``[2, 25]``, ``[2, 3]``, ``[2, 3]`` flattened arm-major
  (left arm first). With ``action_history=k`` each arm's array is ``[25 + 4 k]`` (its last k
  actions appended, as in the JAX env): ``Box[2 * (25 + 4 k)]``.
- action: ``Box[8]`` in [-1, 1]: per arm [dx, dy, dz, finger] (out-of-range values clipped).

Episodes: fixed length (``episode_length``, 50): ``terminated`` is always False and
``truncated`` becomes True at step 50; step again only after ``reset()``. The adapter does not
reset itself: vectorized wrappers (Gymnasium's, SB3's ``DummyVecEnv``) auto-reset and keep the
terminal observation.

Reward: the SUM over both arms of the env's per-arm reward, i.e. per arm
``goal_scale * -(d_i >= threshold) + team_scale * (success - 1) + info["arm_contact_penalty"][i]``;
with the defaults (team and contact terms 0) it lies in {-2, -1, 0} and is 0 exactly when both
arms are within the threshold. The dense variants (``reward_type="dense"``, ids
``DualUR3{Reach,Push,Pickup,Pot}Dense-v0``) replace the goal term by minus the distance, as
Gymnasium-Robotics' dense tasks do: per arm ``goal_scale * -d_i`` (metres) plus the same team
and contact terms, i.e. ``-(d_left + d_right)`` with the defaults.
``compute_reward(achieved_goal, desired_goal, info)`` computes the same value and is vectorized
over leading axes (HER relabelling calls it with ``[batch, 6]`` goals and an array of info
dicts); the goal-independent arm-contact penalty comes from ``info["arm_contact_penalty"]``: a
missing ``info``, an empty dict or a dict without the term counts as 0 (the Gymnasium/HER
convention). ``info["is_success"]`` is 1.0 when every arm is within the threshold.

Task settings are the tasks' entries of `mjx_envs.settings` (JAX-free data shared with the JAX
env); keyword arguments override any of them, e.g.
``gym.make("DualUR3Reach-v0", arm_contact_penalty=0.1)``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from mjx_envs import (  # noqa: F401  (ENV_IDS, DENSE_ENV_IDS: read here by callers too)
    DENSE_ENV_IDS,
    ENV_IDS,
    pipeline,
    registry,
    rules,
    settings,
)
from mjx_envs import observation as obs_lib
from mjx_envs.numpy_env import NumpyDualArmEnv
from mjx_envs.schema import fields, replace_config

NUM_ARMS = 2

REWARD_TYPES = ("sparse", "dense")


def task_config(task: str, **overrides) -> settings.TaskConfig:
    """The task's settings (`mjx_envs.registry.default_config`) with ``overrides`` applied
    (unknown names are a ValueError)."""
    base = registry.default_config(task)
    unknown = sorted(set(overrides) - set(fields(base)))
    if unknown:
        raise ValueError(f"unknown setting(s) {unknown} for task {task!r}; "
                         f"valid: {sorted(fields(base))}")
    return replace_config(base, **overrides)


def task_settings(task: str, **overrides) -> dict[str, Any]:
    """`task_config` as a plain dict."""
    return dataclasses.asdict(task_config(task, **overrides))


def _info_terms(info, lead: tuple) -> dict[str, np.ndarray] | None:
    """The goal-independent terms of ``info`` (one dict, or an array/list of dicts) as arrays
    [*lead, 2]; a term missing from a dict counts as 0."""
    if info is None:
        return None
    if isinstance(info, Mapping):
        return {k: np.broadcast_to(np.asarray(info[k], np.float32), lead + (NUM_ARMS,))
                for k in rules.INFO_KEYS if k in info}
    items = np.asarray(info, dtype=object).reshape(-1)
    zero = np.zeros(NUM_ARMS, np.float32)
    out = {}
    for k in rules.INFO_KEYS:
        has = [isinstance(i, Mapping) and k in i for i in items]
        if any(has):
            vals = [np.asarray(i[k], np.float32).reshape(NUM_ARMS) if h else zero
                    for i, h in zip(items, has, strict=True)]
            out[k] = np.stack(vals).reshape(lead + (NUM_ARMS,))
    return out


class DualUR3GoalEnv(gym.Env):
    """One dual-UR3 task as a goal-conditioned Gymnasium env; see the module docstring."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(self, task: str = settings.DEFAULT_TASK, render_mode: str | None = None,
                 width: int = 480, height: int = 360, reward_type: str = "sparse",
                 **overrides):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None")
        if reward_type not in REWARD_TYPES:
            raise ValueError(f"reward_type must be one of {REWARD_TYPES}, got {reward_type!r}")
        self.task = task
        self.reward_type = reward_type
        self.sim = NumpyDualArmEnv(task_config(task, **overrides), task=task, exact=True)
        self.config = cfg = self.sim.config
        self.settings = dataclasses.asdict(cfg)
        self.episode_length = int(cfg.episode_length)
        self.threshold = np.float32(cfg.distance_threshold)
        self.goal_scale = np.float32(cfg.goal_scale)
        self.team_scale = np.float32(cfg.team_scale)
        self.arm_contact_penalty = np.float32(cfg.arm_contact_penalty)
        self.arm_clearance_threshold = float(cfg.arm_clearance)
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / self.sim.dt)))
        self.render_mode = render_mode
        self._render_size = (int(width), int(height))
        self._renderer = None

        self.action_history = int(cfg.action_history)
        # what the policy sees: the action history stage (`mjx_envs.pipeline`, as the robot
        # client; the simulator applies no perturbation), its per-episode carry in _seen
        self._pipeline = pipeline.Pipeline(
            pipeline.stages(np, None, action_history=self.action_history))
        self._seen = None
        n_obs = NUM_ARMS * obs_lib.obs_size(self.action_history)
        box = lambda n: spaces.Box(-np.inf, np.inf, shape=(n,), dtype=np.float32)  # noqa: E731
        self.observation_space = spaces.Dict(
            {"observation": box(n_obs), "achieved_goal": box(NUM_ARMS * 3),
             "desired_goal": box(NUM_ARMS * 3)})
        self.action_space = spaces.Box(-1.0, 1.0, shape=(NUM_ARMS * 4,), dtype=np.float32)
        self._t = 0
        self._needs_reset = True
        self._last = None

    # -- rewards --------------------------------------------------------------------------------

    def per_arm_reward(self, achieved_goal, desired_goal, info=None) -> np.ndarray:
        """Per-arm reward [..., 2] (the JAX env's ``compute_reward``) for goals [..., 6]."""
        ag = np.asarray(achieved_goal, np.float32)
        dg = np.asarray(desired_goal, np.float32)
        lead = np.broadcast_shapes(ag.shape, dg.shape)[:-1]
        ag = ag.reshape(ag.shape[:-1] + (NUM_ARMS, 3))
        dg = dg.reshape(dg.shape[:-1] + (NUM_ARMS, 3))
        info = _info_terms(info, tuple(lead))
        if self.reward_type == "sparse":
            return self.sim.compute_reward(ag, dg, info)
        r = self.sim.rules
        terms = dict(r.reward_terms(np, ag, dg), goal=-rules.goal_distance(np, ag, dg))
        return np.asarray(r.reward(np, ag, dg, info, terms=terms), np.float32)

    def compute_reward(self, achieved_goal, desired_goal, info=None):
        """Reward = sum over arms of the per-arm reward; shape = leading axes of the goals
        (a float32 array [batch] for HER's batched calls, a 0-d value for one transition).
        ``info``: None, a dict or an array/list of dicts; missing terms count as 0."""
        r = np.sum(self.per_arm_reward(achieved_goal, desired_goal, info), axis=-1)
        return r.astype(np.float32)

    def compute_terminated(self, achieved_goal, desired_goal, info=None):
        return np.zeros(np.shape(achieved_goal)[:-1], bool)

    def compute_truncated(self, achieved_goal, desired_goal, info=None):
        return np.zeros(np.shape(achieved_goal)[:-1], bool)

    # -- API ------------------------------------------------------------------------------------

    def _observe(self, res, obs) -> tuple[dict, dict]:
        """(observation dict, info) from the simulator's `StepResult` and the observation the
        policy sees."""
        o = {"observation": obs.reshape(-1),
             "achieved_goal": res.achieved_goal.reshape(-1),
             "desired_goal": res.desired_goal.reshape(-1)}
        contact, terms = self.sim.info_terms(res.arm_clearance)
        info = {"is_success": float(res.success), "goal_distance": res.goal_distance,
                "arm_contact": contact, "arm_clearance": res.arm_clearance, **terms,
                "step": self._t}
        self._last = o
        return o, info

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """A new episode; ``options`` may fix the ``goal`` [2, 3] and the initial ``qpos``."""
        super().reset(seed=seed)
        options = options or {}
        res = self.sim.reset(self.np_random, goal=options.get("goal"), qpos=options.get("qpos"))
        self._t = 0
        self._needs_reset = False
        obs, self._seen = self._pipeline.start(None, res.observation)
        return self._observe(res, obs)

    def step(self, action):
        if self._needs_reset:
            raise RuntimeError("step() after the end of an episode (or before reset()); "
                               "call reset()")
        action, self._seen = self._pipeline.act(self._seen, action)
        res = self.sim.step(np.asarray(action, np.float32))
        self._t += 1
        obs, self._seen = self._pipeline.observe(self._seen, res.observation)
        o, info = self._observe(res, obs)
        reward = float(self.compute_reward(o["achieved_goal"], o["desired_goal"], info))
        truncated = self._t >= self.episode_length
        self._needs_reset = truncated
        return o, reward, False, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            # lazy: mjx_envs.render sets MUJOCO_GL, which only a rendering env should do
            from mjx_envs.render import make_camera

            w, h = self._render_size
            self._renderer = mujoco.Renderer(self.sim.model, height=h, width=w)
            self._camera = make_camera()
            m = self.sim.model
            self._goal_sites = [m.site(n).id for n in ("goal_l", "goal_r")]
        m, d = self.sim.model, self.sim.data
        for sid, g in zip(self._goal_sites, self.sim.goal, strict=True):
            m.site_pos[sid] = g
        mujoco.mj_forward(m, d)
        self._renderer.update_scene(d, camera=self._camera)
        return self._renderer.render().copy()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

