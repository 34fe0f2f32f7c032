"""Hand-written controllers with the policy client's interface (``act(observation, goal) ->
(action, info)``), NumPy only: stand-ins for a served policy when the robot side is rehearsed
in-process (`daddpg_jax.deploy.robot.run_episodes`), e.g. to measure what the camera path does
to a closed loop without a trained policy.

- `ReachClient`: each arm steps towards its goal, ``tanh(gain * (goal - grip))``.
- `GraspClient`: the two-arm grasp of pick up and pot (`mjx_envs.tasks.scripted.grasp_policy`,
  the same rules written with NumPy): both grippers approach their object points open,
  descend, close, and carry the object to the goal once both hold. It reads the object points
  from the observation, so it sees what the object source (a camera) reports.

Both read only each arm's observation row (`mjx_envs.observation.obs_layout`) and the goal.
"""

from __future__ import annotations

import numpy as np

from mjx_envs import observation as obs_lib
from mjx_envs import registry
from mjx_envs.settings import LiftTaskConfig

_LAYOUT = obs_lib.obs_layout()
GRASP_DZ = -0.005
HOVER_DZ = 0.07
HOLD_OPENING = (0.004, 0.022)
CARRY_STEP = 0.02
MAX_DELTA = 0.05


def _field(obs, name):
    lo, hi = _LAYOUT[name]
    return np.asarray(obs, float)[:, lo:hi]


def _to_action(delta, finger, max_delta):
    a = np.clip(np.asarray(delta, float) / max_delta, -1.0, 1.0)
    return np.concatenate([a, np.clip(finger, -1.0, 1.0)[:, None]], axis=1).reshape(8)


class ReachClient:
    """Reach: ``tanh(gain * (goal - grip))`` per axis, fingers at 0."""

    def __init__(self, gain: float = 10.0):
        self.gain = float(gain)

    def act(self, observation, desired_goal):
        grip = _field(observation, "grip_pos")
        a = np.tanh(self.gain * (np.asarray(desired_goal, float).reshape(2, 3) - grip))
        return _to_action(a * MAX_DELTA, np.zeros(2), MAX_DELTA).tolist(), {}

    def close(self):
        pass


def _approach(grip, point, xy_tol=0.008):
    e = point - grip
    exy = np.linalg.norm(e[:, :2], axis=1)
    z_hold, z_hover = point[:, 2] + GRASP_DZ, point[:, 2] + HOVER_DZ
    low = grip[:, 2] < z_hover - 0.02
    aligned, near = exy < xy_tol, exy < 1.5 * xy_tol
    zero = np.zeros_like(exy)
    descend = np.column_stack([e[:, :2], z_hold - grip[:, 2]])
    correct = np.column_stack([e[:, :2], zero])
    rise = np.column_stack([zero, zero, z_hover - grip[:, 2]])
    travel = np.column_stack([e[:, :2], z_hover - grip[:, 2]])
    delta = np.where(aligned[:, None], descend,
                     np.where((near & low)[:, None], correct,
                              np.where(low[:, None], rise, travel)))
    return delta, near & (np.abs(grip[:, 2] - z_hold) < 0.012)


class GraspClient:
    """Pick up / Pot: the two-arm grasp (see the module doc)."""

    def act(self, observation, desired_goal):
        grip = _field(observation, "grip_pos")
        point = _field(observation, "object_pos")
        fingers = _field(observation, "fingers")
        goal = np.asarray(desired_goal, float).reshape(2, 3)
        delta, at_point = _approach(grip, point)
        q = fingers.mean(axis=1)
        hold_at = point + np.array([0.0, 0.0, GRASP_DZ])
        e = hold_at - grip
        holding = ((np.linalg.norm(e[:, :2], axis=1) < 0.02) & (np.abs(e[:, 2]) < 0.03)
                   & (q > HOLD_OPENING[0]) & (q < HOLD_OPENING[1]))
        carry = np.clip(goal - point + 0.5 * (hold_at - grip), -CARRY_STEP, CARRY_STEP)
        both = bool(np.all(holding))
        delta = np.where((both & holding)[:, None], carry,
                         np.where(at_point[:, None], 0.0, delta))
        finger = np.where(at_point | holding, -1.0, 1.0)
        return _to_action(delta, finger, MAX_DELTA).tolist(), {}

    def close(self):
        pass


def client_for(task: str):
    """The stand-in for ``task``: `ReachClient` for a task without an object, `GraspClient` for
    a lifting task (its settings are a `mjx_envs.settings.LiftTaskConfig`)."""
    cfg = registry.default_config(task)
    if task not in registry.OBJECTS:
        return ReachClient()
    if isinstance(cfg, LiftTaskConfig):
        return GraspClient()
    raise ValueError(f"no stand-in controller for task {task!r} (an object task that lifts "
                     f"nothing)")
