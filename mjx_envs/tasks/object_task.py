"""The object-task base shared by Push, Pick up and Pot: an object with a free joint, two object
points (one per arm) at fixed offsets in the object frame, goals from one sampled object pose.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjx_envs import settings
from mjx_envs.core import DualArmEnv
from mjx_envs.settings import ObjectTaskConfig  # noqa: F401  (re-exported)


def yaw_quat(yaw):
    """Quaternion (w, x, y, z) of a rotation by ``yaw`` about world z."""
    return jnp.stack([jnp.cos(yaw / 2), jnp.zeros_like(yaw), jnp.zeros_like(yaw), jnp.sin(yaw / 2)],
                     axis=-1)


def object_points(pos, yaw, offsets):
    """World positions [2, 3] of the two object points of an object at ``pos`` [3] with ``yaw``."""
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    rot = jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], jnp.float32)
    return pos[None, :] + jnp.asarray(offsets, jnp.float32) @ rot.T


class ObjectPoseTask(DualArmEnv):
    """An object with a free joint; goals from one sampled object pose. The joint, body and the
    two object-point sites are the task's entry of `mjx_envs.settings.OBJECTS`."""

    def __init__(self, config=None, physics="auto"):
        super().__init__(config, physics)
        self.object_joint, self.object_body, self.point_sites = settings.OBJECTS[self.task_name]
        m = self.mj_model
        self._obj_qadr = int(m.jnt_qposadr[m.joint(self.object_joint).id])
        self._rest_z = float(self._home_qpos[self._obj_qadr + 2])
        body = m.body(self.object_body).id
        offs = []
        for name in self.point_sites:
            site = m.site(name)
            if int(site.bodyid[0]) != body:
                raise ValueError(f"site {name} must belong to body {self.object_body}")
            offs.append(np.asarray(site.pos, np.float32))
        self.point_offsets = np.stack(offs)  # [2, 3] in the object frame

    def _sample_pose(self, key, low, high):
        lo = jnp.asarray(np.asarray(low, np.float32))
        hi = jnp.asarray(np.asarray(high, np.float32))
        return jax.random.uniform(key, lo.shape, jnp.float32, lo, hi)

    def _sample_goal(self, key):
        k_pose, k_r, k_phi = jax.random.split(key, 3)
        x, y, h, yaw = self._sample_pose(k_pose, self.config.target_low, self.config.target_high)
        r_lo, r_hi = self.config.target_radius
        r = jax.random.uniform(k_r, (), jnp.float32, r_lo, r_hi)
        phi = jax.random.uniform(k_phi, (), jnp.float32, 0.0, 2 * np.pi)
        pos = jnp.stack([x + r * jnp.cos(phi), y + r * jnp.sin(phi), self._rest_z + h])
        return object_points(pos, yaw, self.point_offsets)

    def _init_qpos(self, key):
        x, y, yaw = self._sample_pose(key, self.config.init_low, self.config.init_high)
        obj = jnp.concatenate([jnp.stack([x, y, jnp.float32(self._rest_z)]), yaw_quat(yaw)])
        qpos = jnp.asarray(self._home_qpos)
        return qpos.at[self._obj_qadr:self._obj_qadr + 7].set(obj)

    def _achieved_goal(self, arm, obj):
        return obj["object_point"]

    def object_pos(self, state):
        """Object body position [..., 3] (from the obj_pos sensor)."""
        return self.sensors.read(self.backend.sensordata(state.data), "obj_pos")
