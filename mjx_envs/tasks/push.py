"""Push: two arms move a long bar across the table (paper section 4.1, Fig. 3).

The bar (assets/scene_push.xml) has a wide middle, a narrow neck at each end and an end cap
beyond it. Fingers are locked half open, so a gripper lowered over a neck straddles it between
the middle and the cap: it can shove the bar in any direction along the table but cannot grasp
or lift it. Both end targets come from ONE sampled bar pose (x, y, yaw) on the table, so the two
targets are always consistent with the rigid bar; the yaw range keeps end 0 (+y) on the left
arm's side. Each arm's achieved goal is its end of the bar (the neck centre). Success when both
ends are within 0.05 m of their targets. Rules: `mjx_envs.rules.ObjectRules`.
"""

from __future__ import annotations

from mjx_envs import registry
from mjx_envs.rules import ObjectRules
from mjx_envs.settings import CONTACT_DEFAULTS, ObjectTaskConfig


def scripted_policy(obs, max_delta: float = 0.05):
    """Straddle each neck with the (locked, half-open) fingers, then drag both ends to their
    targets together; an arm that is in place waits for the other."""
    import jax.numpy as jnp  # lazy: the registry reads this module without JAX

    from mjx_envs.tasks import scripted

    grip, _, point, goal = scripted.split_obs(obs)
    delta, at_point = scripted.approach(grip, point)
    both = jnp.all(at_point, axis=-1, keepdims=True)
    carry = goal - point
    carry = carry.at[..., 2].set(point[..., 2] + scripted.GRASP_DZ - grip[..., 2])
    # keep the gripper centred on its neck while dragging
    carry = carry.at[..., :2].add(0.5 * (point - grip)[..., :2])
    wait = jnp.zeros_like(delta)
    delta = jnp.where(both[..., None], carry, jnp.where(at_point[..., None], wait, delta))
    return scripted.to_action(delta, jnp.zeros(delta.shape[:-1]), max_delta)


TASK = registry.register(registry.Task(
    name="push",
    # bar centre within 5 mm of (0.25, 0), yaw +-0.1 rad; the goal pose lies 0.06-0.08 m away in
    # any direction with yaw +-0.15 rad, so no episode starts solved (the mean of the two end
    # displacements is the centre displacement, >= 0.053 m > threshold). Fingers locked half
    # open: a 0.05 m gap straddles the 0.03 m neck and never squeezes it.
    config=ObjectTaskConfig(
        scene="scene_push.xml", **CONTACT_DEFAULTS, lock_fingers=True, locked_opening=0.025,
        init_low=(0.245, -0.005, -0.10), init_high=(0.255, 0.005, 0.10),
        target_low=(0.25, 0.0, 0.0, -0.15), target_high=(0.25, 0.0, 0.0, 0.15),
        target_radius=(0.06, 0.08)),
    rules=ObjectRules,
    object=("bar", "bar", ("end_l", "end_r")),
    scripted=scripted_policy,
    cpu_preset=dict(n_cycles=50, n_epochs=100),
    accelerator_preset=dict(epoch_env_steps=1_000_000, n_epochs=40),
    module=__name__,
))
