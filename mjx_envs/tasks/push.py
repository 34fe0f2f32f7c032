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

from mjx_envs.tasks.object_task import ObjectPoseTask, ObjectTaskConfig


class Push(ObjectPoseTask):
    task_name = "push"

    @classmethod
    def default_config(cls) -> ObjectTaskConfig:
        return ObjectTaskConfig(
            scene="scene_push.xml",
            distance_threshold=0.05,
            lock_fingers=True,
            locked_opening=0.025,  # 0.05 m gap: straddles the 0.03 m neck, never squeezes it
            cone="elliptic",
            timestep=0.005,  # contacts at 0.01 s tunnel and eject the bar at 1.25 m/s pushes
            n_substeps=8,  # control period stays 0.04 s
            goal_scale=1.0,
            team_scale=0.0,
            arm_contact_penalty=0.0,
            # bar centre within 5 mm of (0.25, 0), yaw +-0.1 rad; the goal pose lies 0.06-0.08 m
            # away in any direction with yaw +-0.15 rad, so no episode starts solved (the mean of
            # the two end displacements is the centre displacement, >= 0.053 m > threshold).
            init_low=(0.245, -0.005, -0.10),
            init_high=(0.255, 0.005, 0.10),
            target_low=(0.25, 0.0, 0.0, -0.15),
            target_high=(0.25, 0.0, 0.0, 0.15),
            target_radius=(0.06, 0.08),
        )
