"""The object-task base shared by Push, Pick up and Pot: an object with a free joint, two object
points (one per arm) at fixed offsets in the object frame, goals from one sampled object pose.

The rules themselves (placement, goals, achieved goals) are the task's (`mjx_envs.rules.ObjectRules`
or a subclass); the object's joint, body and point sites are the task's ``object``
(`mjx_envs.registry.Task`). With ``grasp_start_fraction > 0`` (pickup, pot; training only) the
env starts that fraction of its episodes from one of the grasped states of
`mjx_envs.tasks.grasp_start`, recorded when the first reset is traced (a few seconds, cached per
process), not when the env is built.
"""

from __future__ import annotations

import functools

from mjx_envs.core import DualArmEnv
from mjx_envs.settings import ObjectTaskConfig  # noqa: F401  (re-exported)
from mjx_envs.tasks import grasp_start


class ObjectPoseTask(DualArmEnv):
    """An object with a free joint; goals from one sampled object pose."""

    def __init__(self, config=None, physics="auto"):
        super().__init__(config, physics)
        r = self.rules
        self.object_joint, self.object_body, self.point_sites = (
            r.object_joint, r.object_body, r.point_sites)
        self._obj_qadr = r.qpos_adr
        self._rest_z = r.rest_z
        self.point_offsets = r.point_offsets  # [2, 3] in the object frame

    @functools.cached_property
    def grasp_states(self) -> grasp_start.GraspStates | None:
        """The recorded grasped states when grasp_start_fraction > 0 (recorded on first use),
        else None."""
        if getattr(self.config, "grasp_start_fraction", 0.0) > 0:
            return grasp_start.grasp_states(type(self), self.config)
        return None

    def start_state(self, key, qpos):
        start = super().start_state(key, qpos)
        if self.grasp_states is None:  # static: grasp_start_fraction == 0 draws nothing more
            return start
        return grasp_start.mix(self.grasp_states, self.config.grasp_start_fraction, key, start)

    def object_pos(self, state):
        """Object body position [..., 3] (from the obj_pos sensor)."""
        return self.sensors.read(self.backend.sensordata(state.data), "obj_pos")
