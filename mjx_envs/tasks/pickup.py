"""Pick up: two arms lift the Push bar together to a pose above the table (paper section 4.1,
Fig. 4).

Same bar as Push (assets/scene_pickup.xml). Only the narrow necks near the ends fit between the
open fingers; the middle and the end caps are wider than the open gripper. A closed finger servo
squeezes a neck with ~6 N, enough for two grippers to carry the 0.5 kg bar but far too little
for one gripper to hold it level (it pivots about the grasp). Both end targets come from ONE
sampled bar pose 0.05-0.15 m above the bar's resting height; success when both ends are within
0.05 m. Fingers are active (the 4th action of each arm opens/closes its gripper).
"""

from __future__ import annotations

from mjx_envs.tasks.object_task import ObjectPoseTask


class Pickup(ObjectPoseTask):
    task_name = "pickup"

