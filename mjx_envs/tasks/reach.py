"""Reach: each gripper to its own random 3-D target (paper section 4.1, Fig. 2).

No object, contacts off, fingers locked. The two goal regions overlap in the middle of the
table (|y| < 0.08 m), so the arms can get in each other's way. Success when both grippers are
within 0.02 m of their targets. Goals and achieved goals: `mjx_envs.rules`.
"""

from __future__ import annotations

from mjx_envs.core import DualArmEnv


class Reach(DualArmEnv):
    task_name = "reach"
