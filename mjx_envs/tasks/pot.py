"""Pot: two arms grasp a pot by its handles and lift it to a target above the table (paper
section 4.1, Fig. 5).

A box-shaped pot with a lid and a round knob stands on the table (assets/scene_pot.xml); each
arm's achieved goal is its handle. Both handle targets come from ONE sampled pot pose
0.05-0.12 m above the pot's resting height (upright, no yaw), so no target can be reached by
pushing: the pot must be lifted. Success when both handles are within 0.05 m. Fingers active.
Rules: `mjx_envs.rules.ObjectRules`; scripted controller: the two-arm grasp shared with the other
lift task (`mjx_envs.tasks.lift`).
"""

from __future__ import annotations

from mjx_envs import registry
from mjx_envs.rules import ObjectRules
from mjx_envs.settings import CONTACT_DEFAULTS, LiftTaskConfig
from mjx_envs.tasks.lift import scripted_policy

TASK = registry.register(registry.Task(
    name="pot",
    # goal: pot centre (x, y, height above its resting height, yaw), upright
    config=LiftTaskConfig(
        scene="scene_pot.xml", **CONTACT_DEFAULTS, lock_fingers=False,
        init_low=(0.23, -0.02, -0.05), init_high=(0.27, 0.02, 0.05),
        target_low=(0.22, -0.03, 0.05, 0.0), target_high=(0.28, 0.03, 0.12, 0.0),
        target_radius=(0.0, 0.0)),
    rules=ObjectRules,
    object=("pot", "pot", ("handle_l", "handle_r")),
    scripted=scripted_policy,
    cpu_preset=dict(n_cycles=50, n_epochs=300),
    accelerator_preset=dict(epoch_env_steps=1_000_000, n_epochs=120),
    # half the episodes start grasped (docs/TRAINING.md, "Presets")
    env_preset=dict(grasp_start_fraction=0.5),
    # MJX -> C measured with --for-c-engine's recipe (docs/MJX_VS_C.md, "One recipe")
    for_c_engine=True,
    module=__name__,
))
