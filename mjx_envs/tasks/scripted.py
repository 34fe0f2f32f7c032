"""The building blocks of the tasks' scripted controllers, and the two-arm grasp controller
that pickup and pot share. Each task's controller is its module's ``scripted_policy``
(`mjx_envs.registry.Task.scripted`; `get_policy` looks it up).

Each controller reads only the env's observation dict (``observation`` [..., 2, obs_size],
``achieved_goal`` [..., 2, 3], ``desired_goal`` [..., 2, 3]) and returns the 8-d action
[..., 8]. No hidden state: the phase of each arm (approach, descend, close, carry) is inferred
from the observation itself, so a controller is jit-able, vmap-able and can drive the env from
inside ``lax.scan``. They serve as tests of the physics (a task is solvable), as demos, and,
only when asked for (``TrainConfig.n_demos`` / ``run.py --demos``), as the demonstrations the
trainer imitates; default training does not use them.

Conventions shared with the scenes: the object point of each arm (bar neck / pot handle) is the
place its gripper holds; the tool centre point sits ``GRASP_DZ`` above it when holding.
"""

from __future__ import annotations

import jax.numpy as jnp

from mjx_envs import observation as obs_lib
from mjx_envs import registry

_LAYOUT = obs_lib.obs_layout()
GRASP_DZ = -0.005
"""Tool centre point height above the object point while holding it, metres."""
HOVER_DZ = 0.07
"""Height above the object point at which a gripper travels before descending, metres."""


def split_obs(obs):
    """(gripper positions, finger openings, achieved goals, desired goals) of each arm."""
    o = obs["observation"]
    grip = o[..., slice(*_LAYOUT["grip_pos"])]
    fingers = o[..., slice(*_LAYOUT["fingers"])]
    return grip, fingers, obs["achieved_goal"], obs["desired_goal"]


def to_action(delta, finger, max_delta):
    """Per-arm displacement [..., 2, 3] and finger command [..., 2] -> action [..., 8]."""
    a = jnp.clip(delta / max_delta, -1.0, 1.0)
    a = jnp.concatenate([a, jnp.clip(finger, -1.0, 1.0)[..., None]], axis=-1)
    return a.reshape(a.shape[:-2] + (8,)).astype(jnp.float32)


def approach(grip, point, xy_tol=0.008):
    """Move above ``point``, then straight down to the holding height.

    Returns (delta [..., 2, 3], at_point [..., 2]): at_point when the gripper is aligned over the
    point and at the holding height.
    """
    e = point - grip
    exy = jnp.linalg.norm(e[..., :2], axis=-1)
    z_hold = point[..., 2] + GRASP_DZ
    z_hover = point[..., 2] + HOVER_DZ
    low = grip[..., 2] < z_hover - 0.02
    aligned = exy < xy_tol
    near = exy < 1.5 * xy_tol
    zero = jnp.zeros_like(exy)
    # aligned: descend (correcting xy on the way); near but not aligned and low: correct xy only;
    # far and low: rise first (never sweep through the object); far and high: travel at hover
    # height.
    descend = jnp.concatenate([e[..., :2], (z_hold - grip[..., 2])[..., None]], -1)
    correct = jnp.concatenate([e[..., :2], zero[..., None]], -1)
    rise = jnp.stack([zero, zero, z_hover - grip[..., 2]], -1)
    travel = jnp.concatenate([e[..., :2], (z_hover - grip[..., 2])[..., None]], -1)
    delta = jnp.where(aligned[..., None], descend,
                      jnp.where((near & low)[..., None], correct,
                                jnp.where(low[..., None], rise, travel)))
    at_point = near & (jnp.abs(grip[..., 2] - z_hold) < 0.012)
    return delta, at_point


HOLD_OPENING = (0.004, 0.022)
"""Finger opening range (per finger, metres) that means "closed on a neck or handle": a closed
gripper on nothing reads ~0, an open one 0.04."""


CARRY_STEP = 0.02
"""Largest move per control step while carrying a grasped object, metres (slower than
max_delta so that the load does not swing out of a two-point grasp)."""


def _holding(grip, fingers, point):
    """Closed on the object: fingers stopped by it, gripper still around the object point."""
    q = jnp.mean(fingers, axis=-1)
    e = point.at[..., 2].add(GRASP_DZ) - grip
    close = (jnp.linalg.norm(e[..., :2], axis=-1) < 0.02) & (jnp.abs(e[..., 2]) < 0.03)
    return close & (q > HOLD_OPENING[0]) & (q < HOLD_OPENING[1])


def holding(obs):
    """Per arm [..., 2]: the grasp controller's signal that the gripper is closed on its object
    point (fingers stopped by the object within `HOLD_OPENING`, gripper still around the point),
    read from the observation dict alone."""
    grip, fingers, point, _ = split_obs(obs)
    return _holding(grip, fingers, point)


def grasp_policy(obs, max_delta: float = 0.05, arms=(True, True)):
    """Pick up / Pot: both grippers approach their object points open, descend, close; once BOTH
    hold, they carry the object to the goal together. ``arms`` selects which arms take part (the
    others stay where they are, open): a one-armed variant is used to show that one gripper
    cannot lift the bar level."""
    grip, fingers, point, goal = split_obs(obs)
    delta, at_point = approach(grip, point)
    holding = _holding(grip, fingers, point)
    active = jnp.asarray(arms)
    both = jnp.all(holding | ~active, axis=-1, keepdims=True)
    hold = point.at[..., 2].add(GRASP_DZ)
    carry = goal - point + 0.5 * (hold - grip)  # carry, re-centring the grasp against slip
    carry = jnp.clip(carry, -CARRY_STEP, CARRY_STEP)
    wait = jnp.zeros_like(delta)
    delta = jnp.where(both[..., None] & holding[..., None], carry,
                      jnp.where(at_point[..., None], wait, delta))
    delta = jnp.where(active[:, None], delta, 0.0)
    # open while approaching, close once at the point (and keep closed while carrying)
    finger = jnp.where(at_point | holding, -1.0, 1.0)
    finger = jnp.where(active, finger, 1.0)
    return to_action(delta, finger, max_delta)


def get_policy(task: str):
    """The scripted controller ``(obs, max_delta) -> action`` of a registered task."""
    policy = registry.get(task).scripted
    if policy is None:
        have = sorted(t.name for t in registry.tasks() if t.scripted is not None)
        raise ValueError(f"no scripted controller for task {task!r}; available: {have}")
    return policy


def __getattr__(name: str):
    """``POLICIES``: task name -> scripted controller, of the registered tasks that have one."""
    if name == "POLICIES":
        return {t.name: t.scripted for t in registry.tasks() if t.scripted is not None}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
