"""Slide: a task added from outside the package, in this one file (docs/TASKS.md, "Adding a
task"; tests/test_task_registry.py trains, evaluates and exports it).

The Push scene and bar, with fingers locked half open as in push; the goal slides the bar
straight along +x by 4-8 cm from the middle of its start range, without turning it. Its own
rules (`SlideRules.goal`) and scripted controller (`scripted_policy`); the placement, achieved
goal, success and reward are those of the object tasks (`mjx_envs.rules.ObjectRules`).
"""

from __future__ import annotations

import mjx_envs
from mjx_envs.rules import ObjectRules, object_points
from mjx_envs.settings import CONTACT_DEFAULTS, ObjectTaskConfig

SLIDE = (0.04, 0.08)
"""Range of the slide along +x, metres."""


class SlideRules(ObjectRules):
    """Goal: the bar's two ends after sliding it by dx ~ U(SLIDE) along +x from (0.25, 0), no
    yaw; everything else as in the object tasks."""

    def goal(self, xp, sampler, key):
        dx = sampler.uniform(key, (), *SLIDE)
        pos = xp.stack([xp.float32(0.25) + dx, xp.float32(0.0), xp.float32(self.rest_z)])
        return object_points(xp, pos, xp.float32(0.0), self.point_offsets)


def scripted_policy(obs, max_delta: float = 0.05):
    """Straddle both necks, then move both grippers by the ends' remaining offset."""
    import jax.numpy as jnp  # lazy: the registry reads this module without JAX

    from mjx_envs.tasks import scripted

    grip, _, point, goal = scripted.split_obs(obs)
    delta, at_point = scripted.approach(grip, point)
    both = jnp.all(at_point, axis=-1, keepdims=True)
    hold_z = point[..., 2] + scripted.GRASP_DZ - grip[..., 2]
    carry = jnp.concatenate([(goal - point)[..., :2], hold_z[..., None]], axis=-1)
    delta = jnp.where(both[..., None], carry,
                      jnp.where(at_point[..., None], jnp.zeros_like(delta), delta))
    return scripted.to_action(delta, jnp.zeros(delta.shape[:-1]), max_delta)


TASK = mjx_envs.register(mjx_envs.Task(
    name="slide",
    config=ObjectTaskConfig(scene="scene_push.xml", **CONTACT_DEFAULTS, lock_fingers=True,
                            locked_opening=0.025),
    rules=SlideRules,
    object=("bar", "bar", ("end_l", "end_r")),
    scripted=scripted_policy,
    cpu_preset=dict(n_cycles=10, n_epochs=20),
    accelerator_preset=dict(epoch_env_steps=500_000, n_epochs=20),
    module=__name__,
))
