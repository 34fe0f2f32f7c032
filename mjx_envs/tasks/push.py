"""Push: two arms move a long bar across the table (paper section 4.1, Fig. 3).

The bar (assets/scene_push.xml) has a wide middle, a narrow neck at each end and an end cap
beyond it. Fingers are locked half open, so a gripper lowered over a neck straddles it between
the middle and the cap: it can shove the bar in any direction along the table but cannot grasp
or lift it. Both end targets come from ONE sampled bar pose (x, y, yaw) on the table, so the two
targets are always consistent with the rigid bar; the yaw range keeps end 0 (+y) on the left
arm's side. Each arm's achieved goal is its end of the bar (the neck centre). Success when both
ends are within 0.05 m of their targets.
"""

from __future__ import annotations

from mjx_envs.tasks.object_task import ObjectPoseTask


class Push(ObjectPoseTask):
    task_name = "push"

