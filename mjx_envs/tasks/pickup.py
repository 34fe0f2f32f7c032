"""Pick up: two arms lift the Push bar together to a pose above the table (paper section 4.1,
Fig. 4).

Same bar as Push (assets/scene_pickup.xml). Only the narrow necks near the ends fit between the
open fingers; the middle and the end caps are wider than the open gripper. A closed finger servo
squeezes a neck with ~6 N, enough for two grippers to carry the 0.5 kg bar but far too little
for one gripper to hold it level (it pivots about the grasp). Both end targets come from ONE
sampled bar pose 0.05-0.15 m above the bar's resting height; success when both ends are within
0.05 m. Fingers are active (the 4th action of each arm opens/closes its gripper). Rules:
`mjx_envs.rules.ObjectRules`; scripted controller: the two-arm grasp shared with the other
lift task (`mjx_envs.tasks.lift`).
"""

from __future__ import annotations

from mjx_envs import registry
from mjx_envs.rules import ObjectRules
from mjx_envs.settings import CONTACT_DEFAULTS, LiftTaskConfig
from mjx_envs.tasks.lift import scripted_policy

TASK = registry.register(registry.Task(
    name="pickup",
    # goal: bar centre (x, y, height above its resting height, yaw); the grippers keep a fixed
    # downward orientation, so the goal yaw stays small (+-0.1 rad moves an end by 0.013 m)
    config=LiftTaskConfig(
        scene="scene_pickup.xml", **CONTACT_DEFAULTS, lock_fingers=False,
        init_low=(0.23, -0.02, -0.10), init_high=(0.27, 0.02, 0.10),
        target_low=(0.22, -0.03, 0.05, -0.10), target_high=(0.28, 0.03, 0.15, 0.10),
        target_radius=(0.0, 0.0)),
    rules=ObjectRules,
    object=("bar", "bar", ("end_l", "end_r")),
    scripted=scripted_policy,
    # 3-step returns on a CPU (docs/TRAINING.md, "Presets")
    cpu_preset=dict(n_cycles=50, n_epochs=200, n_step=3),
    accelerator_preset=dict(epoch_env_steps=1_000_000, n_epochs=80),
    # half the episodes start grasped (docs/TRAINING.md, "Presets")
    env_preset=dict(grasp_start_fraction=0.5),
    # MJX -> C measured with --for-c-engine's recipe (docs/MJX_VS_C.md, "One recipe")
    for_c_engine=True,
    module=__name__,
))
