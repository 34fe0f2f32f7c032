"""The robot's limits on a Cartesian target, written once over NumPy or JAX (``xp``).

The robot client's safety layer (`daddpg_jax.deploy.safety.SafetyFilter`, ``xp = numpy``) and
the trainer's env under ``daddpg-train --limits`` (`mjx_envs.core.DualArmEnv.limit_targets`,
``xp = jax.numpy``) apply the same rules to a proposed move, in this order:

1. **workspace clamp**: each target clipped to its arm's box;
2. **speed cap**: each arm's displacement from its current target scaled down to at most
   ``max_step`` metres (Euclidean);
3. **arm clearance**: the link points after the move are predicted (the distal points move with
   the arm's motion from its measured tool position, the elbow by half of it); a move whose
   predicted capsule gap is below ``min_clearance`` and smaller than the current gap is refused.
   Candidates in order: the move shortened to `SHORTER` of itself (both arms go on, less far:
   arms approaching each other end at the limit instead of a full step short of it), then stop
   the arm that moves less, then the other, then both; a stopped arm keeps its previous target,
   else moves towards its measured tool position by at most ``max_step`` (inside its box); when
   none is safe both keep their previous targets;
4. **finger range**: each finger opening clipped to ``[finger_low, finger_high]``.

Static shapes, float32, no Python branching on values (`xp.where`), so the JAX version traces
once and both give the same targets (tests/test_limit_rules.py).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mjx_envs.observation import arm_clearance
from mjx_envs.observation import observe as obs_observe

NUM_ARMS = 2
LINK_FOLLOW = np.array([0.0, 0.5, 1.0, 1.0, 1.0], np.float32)
"""How far each link point (shoulder, elbow, wrist 1, flange, tool centre) moves with the
target in one period (first order)."""
SHORTER = (0.5, 0.25)
"""the fractions of a refused move tried before an arm is stopped (the clearance rule)"""
FLAT_SIZE = 16
"""Values of `Limits.flat`: box low [2 x 3], box high [2 x 3], max_step, min_clearance,
finger_low, finger_high (the env setting ``robot_limits``)."""


class Limits(NamedTuple):
    """The rules' limits (arrays: a JAX pytree as well)."""

    low: object  # [2, 3] world m
    high: object  # [2, 3]
    max_step: object  # [] m per control period
    min_clearance: object  # [] m
    finger_low: object  # [] m
    finger_high: object  # [] m

    @classmethod
    def from_flat(cls, xp, values) -> Limits:
        """Limits from the ``FLAT_SIZE`` numbers of `flat` (the env setting)."""
        v = xp.asarray(np.asarray(values, np.float32).reshape(FLAT_SIZE))
        return cls(v[0:6].reshape(NUM_ARMS, 3), v[6:12].reshape(NUM_ARMS, 3), v[12], v[13],
                   v[14], v[15])

    def flat(self) -> tuple:
        """The limits as ``FLAT_SIZE`` Python floats (config files, JSON)."""
        parts = [np.asarray(x, np.float32).reshape(-1) for x in self]
        return tuple(float(x) for x in np.concatenate(parts))


def clamp_workspace(xp, limits: Limits, target):
    """(targets clipped to the boxes, whether any changed)."""
    t = xp.asarray(target, xp.float32)
    c = xp.clip(t, limits.low, limits.high).astype(xp.float32)
    return c, xp.any(c != t)


def cap_speed(xp, limits: Limits, current, proposed):
    """(targets at most ``max_step`` from ``current`` per arm, whether any was capped)."""
    cur = xp.asarray(current, xp.float32)
    d = xp.asarray(proposed, xp.float32) - cur
    n = xp.sqrt(xp.sum(d * d, axis=-1, keepdims=True))
    step = xp.asarray(limits.max_step, xp.float32)
    over = n > step * xp.float32(1.0 + 1e-6)  # float32 rounding is not a violation
    scale = xp.where(over, step / xp.maximum(n, xp.float32(1e-12)), xp.float32(1.0))
    return (cur + d * scale).astype(xp.float32), xp.any(over)


def predict_link_points(xp, link_points, motion):
    """Link points [..., 2, 5, 3] after each arm moves by ``motion`` [..., 2, 3]."""
    follow = xp.asarray(LINK_FOLLOW)[:, None]
    return xp.asarray(link_points, xp.float32) + follow * xp.asarray(motion, xp.float32)[
        ..., :, None, :]


def limit_clearance(xp, limits: Limits, current, target, link_points, tool):
    """(targets, refused, gap now, predicted gap) after the arm-clearance rule."""
    cur = xp.asarray(current, xp.float32)
    target = xp.asarray(target, xp.float32)
    tool = xp.asarray(tool, xp.float32).reshape(NUM_ARMS, 3)
    lp = xp.asarray(link_points, xp.float32)
    motion = target - tool
    dist = xp.sqrt(xp.sum(motion * motion, axis=-1))
    less = (dist[1] < dist[0]).astype(xp.int32)  # the arm that moves less (ties: left)
    towards_tool, _ = cap_speed(xp, limits, cur, clamp_workspace(xp, limits, tool)[0])
    arm = xp.arange(NUM_ARMS)
    stop_less, stop_more = arm == less, arm != less
    stop_both = xp.ones((NUM_ARMS,), bool)
    cands = [target] + [cur + xp.float32(f) * (target - cur) for f in SHORTER]
    for stopped in (stop_less, stop_more, stop_both):
        for hold in (cur, towards_tool):
            cands.append(xp.where(stopped[:, None], hold, target))
    cands = xp.stack(cands)  # [9, 2, 3]: the move itself first
    now = arm_clearance(xp, lp)
    gaps = arm_clearance(xp, predict_link_points(xp, lp[None], cands - tool[None]))
    ok = (gaps >= limits.min_clearance) | (gaps >= now)
    first = xp.argmax(ok)  # the first safe candidate (0 when none is: see below)
    any_ok = xp.any(ok)
    out = xp.where(any_ok, cands[first], cur)
    gap = xp.where(any_ok, gaps[first], now)
    refused = ~(any_ok & (first == 0))
    return out.astype(xp.float32), refused, now, gap


def finger_opening(xp, limits: Limits, opening):
    """Finger openings within ``[finger_low, finger_high]``."""
    return xp.clip(xp.asarray(opening, xp.float32), limits.finger_low, limits.finger_high)


def apply(xp, limits: Limits, current, proposed, link_points, tool, opening):
    """The whole rule set on one proposed move: (targets [2, 3], finger openings, flags) with
    flags a dict of booleans ``workspace``, ``speed``, ``clearance``, ``finger`` (each rule
    that changed something)."""
    t, clamped = clamp_workspace(xp, limits, proposed)
    t, capped = cap_speed(xp, limits, current, t)
    t, refused, _, _ = limit_clearance(xp, limits, current, t, link_points, tool)
    op = xp.asarray(opening, xp.float32)
    fingers = finger_opening(xp, limits, op)
    return t, fingers, dict(workspace=clamped, speed=capped, clearance=refused,
                            finger=xp.any(fingers != op))


def from_config(xp, cfg) -> Limits | None:
    """The limits of a task config's ``robot_limits`` (None when it is ``()``: off);
    ValueError for another length or an empty box, a step <= 0 or a reversed finger range."""
    values = tuple(getattr(cfg, "robot_limits", ()) or ())
    if not values:
        return None
    if len(values) != FLAT_SIZE:
        raise ValueError(f"robot_limits must hold {FLAT_SIZE} numbers, got {len(values)}")
    v = np.asarray(values, np.float64)
    if (not np.all(np.isfinite(v)) or np.any(v[0:6] >= v[6:12]) or v[12] <= 0
            or not 0 <= v[14] <= v[15]):
        raise ValueError(f"robot_limits {values!r}: boxes must be non-empty, max_step > 0 and "
                         f"0 <= finger_low <= finger_high")
    return Limits.from_flat(xp, values)


def measured(xp, layout, sensordata, dt: float):
    """(link points [2, 5, 3], tool positions [2, 3]) the rules take, from a sensor vector
    (what the robot client reads: the observation's gripper position and the link points)."""
    obs, arm, _ = obs_observe(xp, layout, sensordata, dt)
    return arm["link_points"], obs[..., :, 0:3]


def describe(values) -> dict:
    """The ``FLAT_SIZE`` numbers of ``robot_limits`` as named fields (JSON: a policy export's
    ``trained_limits``, `daddpg_jax.deploy.trained_limits`)."""
    v = [float(x) for x in values]
    return dict(workspace_low=[v[0:3], v[3:6]], workspace_high=[v[6:9], v[9:12]],
                max_step=v[12], min_clearance=v[13], finger_low=v[14], finger_high=v[15])
