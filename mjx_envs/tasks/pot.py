"""Pot: two arms grasp a pot by its handles and lift it to a target above the table (paper
section 4.1, Fig. 5).

A box-shaped pot with a lid and a round knob stands on the table (assets/scene_pot.xml); each
arm's achieved goal is its handle. Both handle targets come from ONE sampled pot pose
0.05-0.12 m above the pot's resting height (upright, no yaw), so no target can be reached by
pushing: the pot must be lifted. Success when both handles are within 0.05 m. Fingers active.
"""

from __future__ import annotations

from mjx_envs.tasks.object_task import ObjectPoseTask, ObjectTaskConfig


class Pot(ObjectPoseTask):
    task_name = "pot"
    object_joint = "pot"
    object_body = "pot"
    point_sites = ("handle_l", "handle_r")

    @classmethod
    def default_config(cls) -> ObjectTaskConfig:
        return ObjectTaskConfig(
            scene="scene_pot.xml",
            distance_threshold=0.05,
            lock_fingers=False,
            cone="elliptic",
            timestep=0.005,
            n_substeps=8,
            goal_scale=1.0,
            team_scale=0.0,
            arm_contact_penalty=0.0,
            init_low=(0.23, -0.02, -0.05),
            init_high=(0.27, 0.02, 0.05),
            # pot centre (x, y, height above its resting height, yaw)
            target_low=(0.22, -0.03, 0.05, 0.0),
            target_high=(0.28, 0.03, 0.12, 0.0),
            target_radius=(0.0, 0.0),
        )
