"""Reach: each gripper to its own random 3-D target (paper section 4.1, Fig. 2).

No object, contacts off, fingers locked. The two goal regions overlap in the middle of the
table (|y| < 0.08 m), so the arms can get in each other's way. Success when both grippers are
within 0.02 m of their targets.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjx_envs.core import DualArmEnv


class Reach(DualArmEnv):
    task_name = "reach"


    def _sample_goal(self, key):
        lo = jnp.asarray(np.asarray(self.config.goal_low, np.float32))
        hi = jnp.asarray(np.asarray(self.config.goal_high, np.float32))
        return jax.random.uniform(key, (2, 3), jnp.float32, lo, hi)

    def _achieved_goal(self, arm, obj):
        return arm["grip_pos"]
