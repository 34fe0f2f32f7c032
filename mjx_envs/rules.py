"""Task rules written once over an array namespace ``xp`` (``numpy`` or ``jax.numpy``).

What a task decides besides the physics: where the object starts, which goal an episode gets,
what the achieved goal is, success, the goal distance and the goal-dependent reward terms. The
JAX env (`mjx_envs.core`) calls these with ``xp = jax.numpy`` and the NumPy simulator
(`mjx_envs.numpy_env`, used by the Gymnasium adapter and the robot client) with ``xp = numpy``.

Random numbers come from an injected sampler with two methods, ``split(key, num)`` and
``uniform(key, shape, low, high)`` (float32 values in [low, high)):

- `JaxSampler`: ``jax.random.split`` / ``jax.random.uniform(key, shape, float32, low, high)``;
  ``key`` is a PRNG key;
- `NumpySampler`: ``key`` is a ``numpy.random.Generator``; ``split`` hands the same generator to
  every part (the parts then draw one after the other, in the order the rules use them).

Given the same draws, both namespaces compute the same values (to float32 rounding).

Per episode (`TaskRules.reset`): the key is split into (goal, initial state) keys. Each task's
own hooks are a `TaskRules` subclass in its module (`mjx_envs/tasks/<task>.py`); the object
tasks share `ObjectRules`:
- object tasks: initial object pose (x, y, yaw) ~ U(init_low, init_high) on the table (resting
  height of the home keyframe); ONE goal pose (x, y, h, yaw) ~ U(target_low, target_high),
  shifted horizontally by r ~ U(target_radius) in a direction phi ~ U(0, 2 pi), at height
  rest + h; the goal of each arm is its object point (a site on the object) at that pose.
  With ``goal_rest_fraction`` p > 0 (pickup, pot; training only) the goal key is split in four
  instead of three and one more draw u ~ U(0, 1) follows the direction: where u < p the pose's
  height term is 0 (the goal lies at the object's resting height). With p = 0 nothing more is
  drawn, so the goals are those of the standard task.

This module imports neither JAX nor MuJoCo.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

NUM_ARMS = 2
INFO_KEYS: tuple[str, ...] = ("arm_contact_penalty", "intervention_penalty")
"""Goal-independent per-arm reward terms carried in ``info`` (already scaled and signed; an env
carries those it sets, `mjx_envs.core.DualArmEnv.info_keys`)."""


# -- samplers ---------------------------------------------------------------------------------

class NumpySampler:
    """Draws from a ``numpy.random.Generator`` (the ``key``), as float32."""

    @staticmethod
    def split(key, num: int):
        return (key,) * num

    @staticmethod
    def uniform(key, shape, low, high):
        low, high = np.asarray(low, np.float32), np.asarray(high, np.float32)
        return np.asarray(key.uniform(low, high, size=shape), np.float32)

    @staticmethod
    def normal(key, shape):
        return np.asarray(key.standard_normal(size=shape), np.float32)


class JaxSampler:
    """``jax.random`` draws (float32); JAX is imported when the sampler is made."""

    def __init__(self):
        import jax  # lazy: this module is JAX-free until a JAX sampler is made
        import jax.numpy as jnp

        self._random, self._dtype = jax.random, jnp.float32

    def split(self, key, num: int):
        return self._random.split(key, num)

    def uniform(self, key, shape, low, high):
        return self._random.uniform(key, shape, self._dtype, low, high)

    def normal(self, key, shape):
        return self._random.normal(key, shape, self._dtype)


# -- object geometry ----------------------------------------------------------------------------

def yaw_quat(xp, yaw):
    """Quaternion (w, x, y, z) of a rotation by ``yaw`` about world z."""
    zero = xp.zeros_like(yaw)
    return xp.stack([xp.cos(yaw / 2), zero, zero, xp.sin(yaw / 2)], axis=-1)


def object_points(xp, pos, yaw, offsets):
    """World positions [2, 3] of the object points (``offsets`` [2, 3] in the object frame) of
    an object at ``pos`` [3] turned by ``yaw``."""
    c, s = xp.cos(yaw), xp.sin(yaw)
    zero, one = xp.zeros_like(c), xp.ones_like(c)
    rot = xp.stack([xp.stack([c, -s, zero]), xp.stack([s, c, zero]), xp.stack([zero, zero, one])])
    return pos[None, :] + xp.asarray(offsets, xp.float32) @ rot.T


def placed_qpos(xp, home_qpos, qpos_adr: int, rest_z: float, pose):
    """``home_qpos`` with the object's free joint (at ``qpos_adr``) at ``pose`` = (x, y, yaw) on
    the table, at its resting height ``rest_z``."""
    x, y, yaw = pose[0], pose[1], pose[2]
    obj = xp.concatenate([xp.stack([x, y, xp.float32(rest_z)]), yaw_quat(xp, yaw)])
    home = xp.asarray(home_qpos)
    return xp.concatenate([home[:qpos_adr], obj, home[qpos_adr + 7:]])


def bounds(xp, low, high):
    """(low, high) as float32 arrays of namespace ``xp``."""
    return xp.asarray(np.asarray(low, np.float32)), xp.asarray(np.asarray(high, np.float32))


def object_goal(xp, sampler, key, cfg, rest_z: float, offsets):
    """Object-task goal [2, 3]: the object points at ONE sampled object pose (module doc)."""
    rest_p = float(getattr(cfg, "goal_rest_fraction", 0.0))
    if rest_p > 0:
        k_pose, k_r, k_phi, k_rest = sampler.split(key, 4)
    else:
        k_pose, k_r, k_phi = sampler.split(key, 3)
    lo, hi = bounds(xp, cfg.target_low, cfg.target_high)
    pose = sampler.uniform(k_pose, lo.shape, lo, hi)
    x, y, h, yaw = pose[0], pose[1], pose[2], pose[3]
    r_lo, r_hi = cfg.target_radius
    r = sampler.uniform(k_r, (), r_lo, r_hi)
    phi = sampler.uniform(k_phi, (), 0.0, 2 * np.pi)
    if rest_p > 0:  # a static choice: with p = 0 the draws are those of the standard task
        u = sampler.uniform(k_rest, (), 0.0, 1.0)
        h = xp.where(u < rest_p, xp.zeros_like(h), h)
    pos = xp.stack([x + r * xp.cos(phi), y + r * xp.sin(phi), xp.float32(rest_z) + h])
    return object_points(xp, pos, yaw, offsets)


def object_init_qpos(xp, sampler, key, cfg, home_qpos, qpos_adr: int, rest_z: float):
    """Initial qpos: the home keyframe with the object at a pose ~ U(init_low, init_high)."""
    lo, hi = bounds(xp, cfg.init_low, cfg.init_high)
    pose = sampler.uniform(key, lo.shape, lo, hi)
    return placed_qpos(xp, home_qpos, qpos_adr, rest_z, pose)


# -- goals and rewards --------------------------------------------------------------------------

def goal_distance(xp, achieved_goal, desired_goal):
    """Per-arm distance [..., 2] between goals [..., 2, 3]."""
    return xp.linalg.norm(achieved_goal - desired_goal, axis=-1)


def success(xp, achieved_goal, desired_goal, threshold: float):
    """1.0 where every arm is within ``threshold``; shape = leading axes."""
    d = goal_distance(xp, achieved_goal, desired_goal)
    return xp.all(d < threshold, axis=-1).astype(xp.float32)


def reward_terms(xp, achieved_goal, desired_goal, threshold: float) -> dict[str, Any]:
    """Goal-dependent per-arm terms [..., 2], raw (before scaling): ``goal`` = -(d_i >=
    threshold), ``team`` = success - 1 for both arms."""
    d = goal_distance(xp, achieved_goal, desired_goal)
    goal = -(d >= threshold).astype(xp.float32)
    ok = success(xp, achieved_goal, desired_goal, threshold)
    team = xp.broadcast_to(xp.asarray(ok - 1.0)[..., None], goal.shape)
    return {"goal": goal, "team": team}


def combine_reward(terms: Mapping[str, Any], goal_scale: float, team_scale: float,
                   info: Mapping[str, Any] | None = None, info_keys=INFO_KEYS):
    """Per-arm reward: scaled goal-dependent ``terms`` plus the goal-independent ``info``
    terms (a missing ``info`` or a missing term counts as 0, the Gymnasium/HER convention)."""
    r = goal_scale * terms["goal"] + team_scale * terms["team"]
    for k in info_keys:
        v = info.get(k) if info else None
        if v is not None:
            r = r + v
    return r


def contact_terms(xp, clearance, arm_clearance: float, arm_contact_penalty: float):
    """(arm_contact, info terms): 1.0 when the arms' link capsules are closer than
    ``arm_clearance``, and the per-arm penalty [2] it costs (goal-independent)."""
    arm_contact = (clearance < arm_clearance).astype(xp.float32)
    pen = xp.full((NUM_ARMS,), -arm_contact_penalty, xp.float32) * arm_contact
    return arm_contact, {"arm_contact_penalty": pen}


# -- a task's rules, bound to its settings and scene ---------------------------------------------

class TaskRules:
    """The rule hooks of one task, bound to its settings and compiled scene: the shared base.

    A task's module (`mjx_envs.registry.Task.rules`) subclasses it and defines ``goal`` and
    ``achieved_goal`` (and ``init_qpos`` when the start is not the home keyframe); success and
    reward come from the goal distance here unless the task overrides them. Built as
    ``rules(config, model, object)``: ``model`` a ``mujoco.MjModel`` (read for the home
    keyframe), ``object`` the task's (free joint, body, point sites) or None.
    """

    has_object = False

    def __init__(self, config, model, objects=None):
        self.config = config
        self.home_qpos = np.asarray(model.key("home").qpos, np.float32)

    # -- per episode --------------------------------------------------------------------------

    def goal(self, xp, sampler, key):
        """Desired goal [2, 3] (float32) drawn with ``key``."""
        raise NotImplementedError

    def init_qpos(self, xp, sampler, key):
        """Initial qpos [nq]: the home keyframe."""
        return xp.asarray(self.home_qpos)

    def reset(self, xp, sampler, key):
        """(goal [2, 3], initial qpos [nq]), both float32, from one key split in two."""
        k_goal, k_init = sampler.split(key, 2)
        goal = self.goal(xp, sampler, k_goal).astype(xp.float32)
        qpos = self.init_qpos(xp, sampler, k_init).astype(xp.float32)
        return goal, qpos

    # -- per step -----------------------------------------------------------------------------

    def achieved_goal(self, arm: Mapping[str, Any], obj: Mapping[str, Any]):
        """Achieved goal [..., 2, 3] from `mjx_envs.observation`'s readings."""
        raise NotImplementedError

    def goal_distance(self, xp, achieved_goal, desired_goal):
        return goal_distance(xp, achieved_goal, desired_goal)

    def success(self, xp, achieved_goal, desired_goal):
        return success(xp, achieved_goal, desired_goal, self.config.distance_threshold)

    def reward_terms(self, xp, achieved_goal, desired_goal):
        return reward_terms(xp, achieved_goal, desired_goal, self.config.distance_threshold)

    def reward(self, xp, achieved_goal, desired_goal, info=None, terms=None):
        """Per-arm reward [..., 2] (``terms``: `reward_terms` of these goals, when known)."""
        cfg = self.config
        if terms is None:
            terms = self.reward_terms(xp, achieved_goal, desired_goal)
        return combine_reward(terms, cfg.goal_scale, cfg.team_scale, info)

    def contact_terms(self, xp, clearance):
        cfg = self.config
        return contact_terms(xp, clearance, cfg.arm_clearance, cfg.arm_contact_penalty)


class ObjectRules(TaskRules):
    """The rules shared by the object tasks (push, pickup, pot): the object placed at a pose
    ~ U(init_low, init_high) on the table, goals from one sampled object pose (module doc), the
    object points as achieved goals. ``objects``: (free joint, body, (left point site, right
    point site)); the object's qpos address, resting height and point offsets are read from
    ``model``."""

    has_object = True

    def __init__(self, config, model, objects):
        super().__init__(config, model)
        joint, body, sites = objects
        names = [model.joint(i).name for i in range(model.njnt)]
        if joint not in names:
            raise ValueError(f"the scene {config.scene!r} has no object joint {joint!r} "
                             f"(joints: {names}); is it the task's scene?")
        self.object_joint, self.object_body, self.point_sites = joint, body, tuple(sites)
        self.qpos_adr = int(model.jnt_qposadr[model.joint(joint).id])
        self.rest_z = float(self.home_qpos[self.qpos_adr + 2])
        body_id = model.body(body).id
        offs = []
        for name in self.point_sites:
            site = model.site(name)
            if int(site.bodyid[0]) != body_id:
                raise ValueError(f"site {name} must belong to body {body}")
            offs.append(np.asarray(site.pos, np.float32))
        self.point_offsets = np.stack(offs)  # [2, 3] in the object frame

    def goal(self, xp, sampler, key):
        return object_goal(xp, sampler, key, self.config, self.rest_z, self.point_offsets)

    def init_qpos(self, xp, sampler, key):
        """Initial qpos [nq]: the home keyframe with the object placed."""
        return object_init_qpos(xp, sampler, key, self.config, self.home_qpos, self.qpos_adr,
                                self.rest_z)

    def achieved_goal(self, arm, obj):
        """The object points [..., 2, 3]."""
        return obj["object_point"]
