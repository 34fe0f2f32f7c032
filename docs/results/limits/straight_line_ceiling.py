"""Success ceiling of reach under a limits file's rules, estimated by a straight-line controller
(each gripper moves towards its goal at full speed) in the NumPy simulator under
``robot_limits`` (the same rules as the robot client's safety layer), 200 episodes, seed 5.
Run from the repository root: python docs/results/limits/straight_line_ceiling.py
Output (2-core CPU, 114 s): straight_line_ceiling.json."""
import sys
import time

import numpy as np

from daddpg_jax.algo import resolve
from mjx_envs.numpy_env import NumpyDualArmEnv


def episode(env, rng):
    """One episode of the straight-line controller: its last step's result."""
    res = env.reset(rng)
    for _ in range(env.episode_length):
        a = np.zeros((2, 4), np.float32)
        a[:, :3] = np.clip((res.desired_goal - res.achieved_goal) / env.max_delta, -1, 1)
        res = env.step(a.reshape(-1))
    return res


def ceiling(limits, scale, episodes=200, seed=5):
    flat = resolve.limits_values(limits, scale, "reach", {}) if limits else ()
    env = NumpyDualArmEnv({"robot_limits": flat}, task="reach")
    rng = np.random.default_rng(seed)
    return sum(bool(episode(env, rng).success) for _ in range(episodes)) / episodes


if __name__ == "__main__":
    t = time.time()
    for lim, s in ((None, 1.0), ("daddpg_jax/deploy/limits/sim.toml", 1.0),
                   ("daddpg_jax/deploy/limits/ur3_cell.toml", 1.0),
                   ("daddpg_jax/deploy/limits/ur3_cell.toml", 0.25)):
        print(lim, s, ceiling(lim, s), round(time.time() - t, 1), flush=True)
    sys.exit(0)
