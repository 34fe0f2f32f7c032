"""A hand-built reach policy file (no training): the legacy reach file's format and meta with
weights that make each arm step towards its goal, action = tanh(gain * (goal - grip_pos)).
A policy that succeeds, for tests of the robot side (the shipped legacy policy is untrained)."""

from __future__ import annotations

import os

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LEGACY = os.path.join(ROOT, "tests", "data", "legacy_reach", "policy.npz")
OBS, GOAL = 25, 3


def write_reach_controller(path, gain: float = 10.0) -> str:
    """Writes the policy to ``path`` (.npz) and returns it."""
    src = np.load(LEGACY)
    arrays = {k: src[k] for k in src.files}
    w0 = np.zeros((2, 2 * OBS + 2 * GOAL, 16), np.float32)
    w1 = np.zeros((2, 16, 4), np.float32)
    for agent in range(2):
        for j in range(3):
            g, p = 2 * OBS + GOAL * agent + j, OBS * agent + j
            w0[agent, g, 2 * j], w0[agent, p, 2 * j] = 1.0, -1.0          # relu(g - p)
            w0[agent, g, 2 * j + 1], w0[agent, p, 2 * j + 1] = -1.0, 1.0  # relu(p - g)
            w1[agent, 2 * j, j], w1[agent, 2 * j + 1, j] = gain, -gain
    arrays.update({"actor/W0": w0, "actor/b0": np.zeros((2, 16), np.float32),
                   "actor/W1": w1, "actor/b1": np.zeros((2, 4), np.float32),
                   "obs_norm/mean": np.zeros((2, OBS), np.float32),
                   "obs_norm/std": np.ones((2, OBS), np.float32),
                   "goal_norm/mean": np.zeros((2, GOAL), np.float32),
                   "goal_norm/std": np.ones((2, GOAL), np.float32)})
    np.savez(path, **arrays)
    return os.fspath(path)
