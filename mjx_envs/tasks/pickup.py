"""Pick up: two arms lift the Push bar together to a pose above the table (paper section 4.1,
Fig. 4).

Same bar as Push (assets/scene_pickup.xml). Only the narrow necks near the ends fit between the
open fingers; the middle and the end caps are wider than the open gripper. A closed finger servo
squeezes a neck with ~4.5 N, enough for two grippers to carry the 0.5 kg bar but far too little
for one gripper to hold it level (it pivots about the grasp). Both end targets come from ONE
sampled bar pose 0.05-0.15 m above the bar's resting height; success when both ends are within
0.05 m. Fingers are active (the 4th action of each arm opens/closes its gripper).
"""

from __future__ import annotations

from mjx_envs.tasks.object_task import ObjectPoseTask, ObjectTaskConfig


class Pickup(ObjectPoseTask):
    task_name = "pickup"

    @classmethod
    def default_config(cls) -> ObjectTaskConfig:
        return ObjectTaskConfig(
            scene="scene_pickup.xml",
            distance_threshold=0.05,
            lock_fingers=False,
            cone="elliptic",
            timestep=0.005,
            n_substeps=8,
            goal_scale=1.0,
            team_scale=0.0,
            arm_contact_penalty=0.0,
            init_low=(0.23, -0.02, -0.10),
            init_high=(0.27, 0.02, 0.10),
            # bar centre (x, y, height above its resting height, yaw): the grippers keep a fixed
            # downward orientation, so the goal yaw stays small (+-0.1 rad moves an end by 0.013 m)
            target_low=(0.22, -0.03, 0.05, -0.10),
            target_high=(0.28, 0.03, 0.15, 0.10),
            target_radius=(0.0, 0.0),
        )
