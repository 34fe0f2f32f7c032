"""Pot: two arms grasp a pot by its handles and lift it to a target above the table (paper
section 4.1, Fig. 5).

A box-shaped pot with a lid and a round knob stands on the table (assets/scene_pot.xml); each
arm's achieved goal is its handle. Both handle targets come from ONE sampled pot pose
0.05-0.12 m above the pot's resting height (upright, no yaw), so no target can be reached by
pushing: the pot must be lifted. Success when both handles are within 0.05 m. Fingers active.
"""

from __future__ import annotations

from mjx_envs.tasks.object_task import ObjectPoseTask


class Pot(ObjectPoseTask):
    task_name = "pot"

