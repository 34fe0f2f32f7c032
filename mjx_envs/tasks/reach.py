"""Reach: each gripper to its own random 3-D target (paper section 4.1, Fig. 2).

No object, contacts off, fingers locked. The two goal regions overlap in the middle of the
table (|y| < 0.08 m), so the arms can get in each other's way. Goal: each arm's target
~ U(goal_low, goal_high) [2, 3]; the home keyframe as initial state; achieved goal: the tool
centre points. Success when both grippers are within 0.02 m of their targets. No scripted
controller.
"""

from __future__ import annotations

from mjx_envs import registry
from mjx_envs.rules import NUM_ARMS, TaskRules, bounds
from mjx_envs.settings import TaskConfig


class ReachRules(TaskRules):
    """Goals uniform in each arm's goal box; the grippers' tool centre points as achieved
    goals."""

    def goal(self, xp, sampler, key):
        lo, hi = bounds(xp, self.config.goal_low, self.config.goal_high)
        return sampler.uniform(key, (NUM_ARMS, 3), lo, hi)

    def achieved_goal(self, arm, obj):
        return arm["grip_pos"]


TASK = registry.register(registry.Task(
    name="reach",
    config=TaskConfig(scene="scene_reach.xml", distance_threshold=0.02, lock_fingers=True,
                      cone="pyramidal"),
    rules=ReachRules,
    cpu_preset=dict(n_cycles=20, n_epochs=20),
    accelerator_preset=dict(epoch_env_steps=400_000, n_epochs=10),
    module=__name__,
))
