"""Gymnasium adapter: every task as a goal-conditioned ``gymnasium.Env`` (NumPy only, no JAX).

    import gymnasium as gym
    import mjx_envs.gym_env          # registers DualUR3Reach-v0, DualUR3Push-v0,
                                     # DualUR3Pickup-v0, DualUR3Pot-v0
    env = gym.make("DualUR3Push-v0")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

One env, stepped step by step with MuJoCo's C engine from NumPy
(``mjx_envs.numpy_env.NumpyDualArmEnv``): no jitted function is dispatched per step and JAX is
never imported. The dynamics repeat the trainer's C-engine env (same MJCF, timestep, substeps,
mocap-weld control, float32 state between control steps, solver warmstart reset every control
step), so a policy trained by ``daddpg_jax`` behaves the same here.

Spaces
- observation: ``Dict(observation=Box[50], achieved_goal=Box[6], desired_goal=Box[6])``,
  float32: the env's per-arm arrays ``[2, 25]``, ``[2, 3]``, ``[2, 3]`` flattened arm-major
  (left arm first).
- action: ``Box[8]`` in [-1, 1]: per arm [dx, dy, dz, finger] (out-of-range values clipped).

Episodes: fixed length (``episode_length``, 50): ``terminated`` is always False and
``truncated`` becomes True at step 50; step again only after ``reset()``. The adapter does not
reset itself: vectorized wrappers (Gymnasium's, SB3's ``DummyVecEnv``) auto-reset and keep the
terminal observation.

Reward: the SUM over both arms of the env's per-arm reward, i.e. per arm
``goal_scale * -(d_i >= threshold) + team_scale * (success - 1) + info["arm_contact_penalty"][i]``;
with the defaults (team and contact terms 0) it lies in {-2, -1, 0} and is 0 exactly when both
arms are within the threshold. ``compute_reward(achieved_goal, desired_goal, info)`` computes the
same value and is vectorized over leading axes (HER relabelling calls it with ``[batch, 6]``
goals and an array of info dicts); the goal-independent arm-contact penalty comes from
``info["arm_contact_penalty"]`` (0 when ``info`` is None). ``info["is_success"]`` is 1.0 when
every arm is within the threshold.

Task settings are the tasks' ``default_config()`` values, copied here as plain data so that
this module needs no JAX (``tests/test_gym_env.py`` checks they equal the JAX tasks'); keyword
arguments override any of them, e.g. ``gym.make("DualUR3Reach-v0", arm_contact_penalty=0.1)``.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Optional

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from mjx_envs import observation as obs_lib
from mjx_envs.numpy_env import REACH_SETTINGS, NumpyDualArmEnv

NUM_ARMS = 2

# Fields of mjx_envs.core.TaskConfig not in numpy_env.REACH_SETTINGS (reward scales).
_REWARD_DEFAULTS = dict(goal_scale=1.0, team_scale=0.0, arm_contact_penalty=0.0)

# ObjectTaskConfig defaults of mjx_envs/{push,pickup,pot}.py (object pose and goal ranges).
_OBJECT_COMMON = dict(cone="elliptic", timestep=0.005, n_substeps=8, distance_threshold=0.05)

TASK_SETTINGS: dict[str, dict[str, Any]] = {
    "reach": dict(REACH_SETTINGS, **_REWARD_DEFAULTS),
    "push": dict(
        REACH_SETTINGS, **_REWARD_DEFAULTS, **_OBJECT_COMMON, scene="scene_push.xml",
        lock_fingers=True, locked_opening=0.025,
        init_low=(0.245, -0.005, -0.10), init_high=(0.255, 0.005, 0.10),
        target_low=(0.25, 0.0, 0.0, -0.15), target_high=(0.25, 0.0, 0.0, 0.15),
        target_radius=(0.06, 0.08)),
    "pickup": dict(
        REACH_SETTINGS, **_REWARD_DEFAULTS, **_OBJECT_COMMON, scene="scene_pickup.xml",
        lock_fingers=False,
        init_low=(0.23, -0.02, -0.10), init_high=(0.27, 0.02, 0.10),
        target_low=(0.22, -0.03, 0.05, -0.10), target_high=(0.28, 0.03, 0.15, 0.10),
        target_radius=(0.0, 0.0)),
    "pot": dict(
        REACH_SETTINGS, **_REWARD_DEFAULTS, **_OBJECT_COMMON, scene="scene_pot.xml",
        lock_fingers=False,
        init_low=(0.23, -0.02, -0.05), init_high=(0.27, 0.02, 0.05),
        target_low=(0.22, -0.03, 0.05, 0.0), target_high=(0.28, 0.03, 0.12, 0.0),
        target_radius=(0.0, 0.0)),
}

# object joint/body and the two object-point sites (one per arm) of the object tasks
_OBJECTS = {"push": ("bar", "bar", ("end_l", "end_r")),
            "pickup": ("bar", "bar", ("end_l", "end_r")),
            "pot": ("pot", "pot", ("handle_l", "handle_r"))}

ENV_IDS = {"reach": "DualUR3Reach-v0", "push": "DualUR3Push-v0",
           "pickup": "DualUR3Pickup-v0", "pot": "DualUR3Pot-v0"}


def task_settings(task: str, **overrides) -> dict[str, Any]:
    """The task's default settings with ``overrides`` applied (unknown names are an error)."""
    if task not in TASK_SETTINGS:
        raise ValueError(f"unknown task {task!r}; available: {sorted(TASK_SETTINGS)}")
    s = dict(TASK_SETTINGS[task])
    unknown = sorted(set(overrides) - set(s))
    if unknown:
        raise ValueError(f"unknown setting(s) {unknown} for task {task!r}; valid: {sorted(s)}")
    s.update(overrides)
    return s


class _TaskSim(NumpyDualArmEnv):
    """``NumpyDualArmEnv`` extended to the object tasks: object placement at reset, goals from
    one sampled object pose, achieved goals at the object points. Same stepping code."""

    def __init__(self, task: str, settings: Mapping[str, Any]):
        # NumpyDualArmEnv accepts task="reach" only; every task difference is in the settings
        # (scene, timestep, fingers, ...) and in the three methods overridden below.
        super().__init__(settings=settings, task="reach", exact=True)
        self.task = task
        self.has_object = task in _OBJECTS
        s = self.settings
        if self.has_object:
            joint, body, sites = _OBJECTS[task]
            m = self.model
            self._obj_qadr = int(m.jnt_qposadr[m.joint(joint).id])
            self._rest_z = float(self.home_qpos[self._obj_qadr + 2])
            self.point_offsets = np.stack([np.asarray(m.site(n).pos, np.float32) for n in sites])
            self._init_low = np.asarray(s["init_low"], np.float32)
            self._init_high = np.asarray(s["init_high"], np.float32)
            self._target_low = np.asarray(s["target_low"], np.float32)
            self._target_high = np.asarray(s["target_high"], np.float32)
            self._target_radius = tuple(float(v) for v in s["target_radius"])

    # -- task hooks (NumPy versions of mjx_envs.tasks.push.ObjectPoseTask) ---------------------------

    def _object_points(self, pos, yaw):
        c, s = math.cos(yaw), math.sin(yaw)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], np.float32)
        return (pos[None, :] + self.point_offsets @ rot.T).astype(np.float32)

    def sample_goal(self, rng: np.random.Generator) -> np.ndarray:
        if not self.has_object:
            return super().sample_goal(rng)
        x, y, h, yaw = rng.uniform(self._target_low, self._target_high).astype(np.float32)
        r = rng.uniform(*self._target_radius)
        phi = rng.uniform(0.0, 2.0 * np.pi)
        pos = np.array([x + r * math.cos(phi), y + r * math.sin(phi), self._rest_z + h], np.float32)
        return self._object_points(pos, float(yaw))

    def sample_qpos(self, rng: np.random.Generator) -> np.ndarray:
        qpos = self.home_qpos.copy()
        if self.has_object:
            x, y, yaw = rng.uniform(self._init_low, self._init_high).astype(np.float32)
            quat = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
            qpos[self._obj_qadr:self._obj_qadr + 7] = [x, y, self._rest_z, *quat]
        return qpos

    def reset_to(self, qpos, goal):
        """Home targets, the given initial ``qpos`` and desired ``goal`` [2, 3]."""
        m, d = self.model, self.data
        self._goal = np.asarray(goal, np.float32).reshape(NUM_ARMS, 3)
        self._t = 0
        self._target = self.home_mocap.copy()
        self._time = np.float32(0.0)
        self._qpos = np.asarray(qpos, np.float32).copy()
        self._qvel = np.zeros(m.nv, np.float32)
        self._act = np.zeros(m.na, np.float32)
        mujoco.mj_resetData(m, d)
        d.qpos[:] = self._qpos
        d.qvel[:] = self._qvel
        d.mocap_pos[:NUM_ARMS] = self._target
        mujoco.mj_forward(m, d)
        self._sens = np.asarray(d.sensordata, np.float32).copy()

    def read(self):
        """(observation [2, 25], achieved goal [2, 3], arm clearance) from the last sensors."""
        obs, arm, obj = obs_lib.observe(np, self.sensors, self._sens, self.dt)
        ag = obj["object_point"] if self.has_object else arm["grip_pos"]
        clearance = float(obs_lib.arm_clearance(np, arm["link_points"]))
        return obs.astype(np.float32), np.asarray(ag, np.float32), clearance


def _stack_info_term(info, key: str, lead: tuple) -> Optional[np.ndarray]:
    """``info[key]`` as an array [*lead, 2], from one dict or an array/list of dicts."""
    if info is None:
        return None
    if isinstance(info, Mapping):
        if key not in info:
            return None
        return np.broadcast_to(np.asarray(info[key], np.float32), lead + (NUM_ARMS,))
    items = np.asarray(info, dtype=object).reshape(-1)
    if items.size == 0 or not all(isinstance(i, Mapping) and key in i for i in items):
        return None
    vals = np.stack([np.asarray(i[key], np.float32).reshape(NUM_ARMS) for i in items])
    return vals.reshape(lead + (NUM_ARMS,))


class DualUR3GoalEnv(gym.Env):
    """One dual-UR3 task as a goal-conditioned Gymnasium env; see the module docstring."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(self, task: str = "reach", render_mode: Optional[str] = None,
                 width: int = 480, height: int = 360, **overrides):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None")
        self.task = task
        self.settings = task_settings(task, **overrides)
        self.sim = _TaskSim(task, self.settings)
        s = self.settings
        self.episode_length = int(s["episode_length"])
        self.threshold = np.float32(s["distance_threshold"])
        self.goal_scale = np.float32(s["goal_scale"])
        self.team_scale = np.float32(s["team_scale"])
        self.arm_contact_penalty = np.float32(s["arm_contact_penalty"])
        self.arm_clearance_threshold = float(s["arm_clearance"])
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / self.sim.dt)))
        self.render_mode = render_mode
        self._render_size = (int(width), int(height))
        self._renderer = None

        n_obs = NUM_ARMS * obs_lib.OBS_SIZE
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
        d = np.linalg.norm(ag - dg, axis=-1)
        goal = -(d >= self.threshold).astype(np.float32)
        success = np.all(d < self.threshold, axis=-1).astype(np.float32)
        team = np.broadcast_to((success - np.float32(1.0))[..., None], goal.shape)
        r = self.goal_scale * goal + self.team_scale * team
        pen = _stack_info_term(info, "arm_contact_penalty", tuple(lead))
        if pen is not None:
            r = r + pen
        return r.astype(np.float32)

    def compute_reward(self, achieved_goal, desired_goal, info=None):
        """Reward = sum over arms of the per-arm reward; shape = leading axes of the goals
        (a float32 array [batch] for HER's batched calls, a 0-d value for one transition)."""
        r = np.sum(self.per_arm_reward(achieved_goal, desired_goal, info), axis=-1)
        return r.astype(np.float32)

    def compute_terminated(self, achieved_goal, desired_goal, info=None):
        return np.zeros(np.shape(achieved_goal)[:-1], bool)

    def compute_truncated(self, achieved_goal, desired_goal, info=None):
        return np.zeros(np.shape(achieved_goal)[:-1], bool)

    # -- API ------------------------------------------------------------------------------------

    def _observe(self):
        obs, ag, clearance = self.sim.read()
        dg = self.sim.goal
        return {"observation": obs.reshape(-1), "achieved_goal": ag.reshape(-1),
                "desired_goal": dg.reshape(-1)}, clearance

    def _info(self, o, clearance) -> dict:
        d = np.linalg.norm(o["achieved_goal"].reshape(NUM_ARMS, 3)
                           - o["desired_goal"].reshape(NUM_ARMS, 3), axis=-1).astype(np.float32)
        contact = clearance < self.arm_clearance_threshold
        return {
            "is_success": float(np.all(d < self.threshold)),
            "goal_distance": d,
            "arm_contact": float(contact),
            "arm_clearance": clearance,
            "arm_contact_penalty": np.full(NUM_ARMS, -self.arm_contact_penalty * np.float32(contact),
                                           np.float32),
            "step": self._t,
        }

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        super().reset(seed=seed)
        options = options or {}
        goal = options.get("goal")
        goal = self.sim.sample_goal(self.np_random) if goal is None else goal
        qpos = options.get("qpos")
        qpos = self.sim.sample_qpos(self.np_random) if qpos is None else qpos
        self.sim.reset_to(qpos, goal)
        self._t = 0
        self._needs_reset = False
        o, clearance = self._observe()
        self._last = o
        return o, self._info(o, clearance)

    def step(self, action):
        if self._needs_reset:
            raise RuntimeError("step() after the end of an episode (or before reset()); call reset()")
        self.sim.step(np.asarray(action, np.float32))
        self._t += 1
        o, clearance = self._observe()
        self._last = o
        info = self._info(o, clearance)
        reward = float(self.compute_reward(o["achieved_goal"], o["desired_goal"], info))
        truncated = self._t >= self.episode_length
        self._needs_reset = truncated
        return o, reward, False, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            from mjx_envs.render import make_camera

            w, h = self._render_size
            self._renderer = mujoco.Renderer(self.sim.model, height=h, width=w)
            self._camera = make_camera()
            m = self.sim.model
            self._goal_sites = [m.site(n).id for n in ("goal_l", "goal_r")]
        m, d = self.sim.model, self.sim.data
        for sid, g in zip(self._goal_sites, self.sim.goal):
            m.site_pos[sid] = g
        mujoco.mj_forward(m, d)
        self._renderer.update_scene(d, camera=self._camera)
        return self._renderer.render().copy()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def register_envs() -> list[str]:
    """Registers ``DualUR3{Reach,Push,Pickup,Pot}-v0`` with Gymnasium (idempotent)."""
    for task, env_id in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point="mjx_envs.gym_env:DualUR3GoalEnv",
                         kwargs={"task": task})
    return list(ENV_IDS.values())


register_envs()
