"""Safety layer between the policy service's answer and the robot's Cartesian targets (NumPy).

Applied every control period by the robot client, in this order:

1. **stop**: no answer, a malformed answer (wrong size, NaN/inf) or one later than the deadline
   makes both arms hold (targets kept where they are, fingers unchanged);
2. **workspace clamp**: targets are clipped to each arm's box;
3. **speed cap**: each arm's displacement from its current target towards the clamped target
   is scaled down to at most ``max_step`` metres (Euclidean). The cap runs last of the two, so
   that a target inside its box moves at most ``max_step`` and stays inside (the box is
   convex);
4. **arm clearance**: the link points after the move are predicted by moving each arm's
   distal points (wrist 1, flange, tool centre) by its motion this period (new target minus
   measured tool position) and the elbow by half of it (shoulders fixed), and the capsule gap
   between the arms is computed with ``mjx_envs.observation.arm_clearance`` (the trainer's own
   arm-contact check). A move whose predicted gap is below ``min_clearance`` and smaller than
   the current gap is refused: it is tried at half and a quarter of its length, then one arm
   is stopped (the one that moves less), else both;
   a stopped arm keeps its previous target if that is safe, else moves towards its measured
   position by at most ``max_step`` (inside its box), else keeps its previous target. Moves
   that increase the gap are always allowed, so arms that are too close can separate.

No rule here leaves a target that the gate after it (`daddpg_jax.deploy.gate`) must refuse:
every output lies in its box and within ``max_step`` of the current target when the current
target does. A hold keeps the current targets.

The prediction is first order (the arm follows its target within one period; a real arm's
links move differently, the elbow most), so set ``min_clearance`` with margin. Everything here
is NumPy; the limits default from the env settings saved in the policy export.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mjx_envs import limit_rules
from mjx_envs.observation import arm_clearance
from mjx_envs.settings import TaskConfig

NUM_ARMS = 2
_DEFAULTS = TaskConfig()  # settings an env mapping lacks
LINK_FOLLOW = limit_rules.LINK_FOLLOW  # how far each link point moves with the target


@dataclass(frozen=True)
class SafetyLimits:
    workspace_low: np.ndarray  # [2, 3] world m
    workspace_high: np.ndarray  # [2, 3]
    max_step: float  # largest target displacement of one arm per control period, m
    min_clearance: float  # smallest allowed capsule gap between the arms, m
    deadline_s: float  # latest acceptable answer of the policy service, s
    finger_low: float = 0.0  # finger opening range, m
    finger_high: float = _DEFAULTS.finger_stroke

    def __post_init__(self):
        """Refuses limits that would switch a rule off or turn it around: NaN/inf anywhere, a
        step or deadline <= 0, an empty or non-finite box, a finger range outside 0 <= low <=
        high (ValueError, one line)."""
        low = np.asarray(self.workspace_low, np.float32)
        high = np.asarray(self.workspace_high, np.float32)
        if low.shape != (NUM_ARMS, 3) or high.shape != (NUM_ARMS, 3):
            raise ValueError(f"workspace boxes must be [{NUM_ARMS}, 3], got {list(low.shape)} "
                             f"and {list(high.shape)}")
        if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
            raise ValueError("workspace boxes must be finite")
        if np.any(low >= high):
            raise ValueError("workspace boxes must be non-empty (low < high on every axis)")
        for name in ("max_step", "deadline_s"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        if not math.isfinite(float(self.min_clearance)):
            raise ValueError(f"min_clearance must be finite, got {self.min_clearance!r}")
        fl, fh = float(self.finger_low), float(self.finger_high)
        if not (math.isfinite(fl) and math.isfinite(fh) and 0.0 <= fl <= fh):
            raise ValueError(f"finger range must be finite with 0 <= low <= high, got "
                             f"[{fl!r}, {fh!r}]")
        object.__setattr__(self, "workspace_low", low)
        object.__setattr__(self, "workspace_high", high)

    @classmethod
    def from_env(cls, env: Mapping[str, Any], max_speed: float | None = None,
                 min_clearance: float | None = None, deadline_s: float | None = None,
                 margin: float = 0.0) -> SafetyLimits:
        """Limits from a policy export's env settings (``NumpyPolicy.env``).

        max_speed: m/s (default: what the policy can command, ``sqrt(3) * max_delta / dt``);
        min_clearance: m (default: the env's ``arm_clearance``); deadline_s: default one
        control period; margin: shrinks the workspace boxes on every side, m.
        """
        control_period_s = float(env["dt"])
        if max_speed is None:
            max_step = math.sqrt(3.0) * float(env["max_delta"])
        else:
            max_step = float(max_speed) * control_period_s
        low = np.asarray(env["workspace_low"], np.float32) + np.float32(margin)
        high = np.asarray(env["workspace_high"], np.float32) - np.float32(margin)
        if np.any(low > high):
            raise ValueError(f"workspace margin {margin} m leaves an empty box")
        if min_clearance is None:
            min_clearance = env.get("arm_clearance", _DEFAULTS.arm_clearance)
        return cls(workspace_low=low, workspace_high=high, max_step=max_step,
                   min_clearance=float(min_clearance),
                   deadline_s=control_period_s if deadline_s is None else float(deadline_s),
                   finger_low=0.0,
                   finger_high=float(env.get("finger_stroke", _DEFAULTS.finger_stroke)))


@dataclass
class SafetyDecision:
    target: np.ndarray  # [2, 3] Cartesian targets to send
    stopped: bool  # the answer was refused and both arms hold
    reasons: list = field(default_factory=list)  # what the layer changed: ["speed", ...]
    clearance_before: float = float("nan")
    clearance_after: float = float("nan")  # predicted


class SafetyFilter:
    def __init__(self, limits: SafetyLimits):
        self.limits = limits
        self.counts: dict[str, int] = {}

    def _count(self, reasons):
        for r in reasons:
            self.counts[r] = self.counts.get(r, 0) + 1

    # -- pieces (tested one by one) -----------------------------------------------------------

    @staticmethod
    def validate_action(action, size: int = 8) -> np.ndarray | None:
        """The action as float32 [size], or None unless it is exactly ``size`` finite numbers:
        a list or tuple of JSON numbers (int or float, not bool, not strings) or a real
        floating/integer NumPy array, each finite in float32 (``1e300`` is not)."""
        if isinstance(action, np.ndarray):
            if action.dtype.kind not in "fiu" or action.shape != (size,):
                return None
            a = action.astype(np.float64)
        elif isinstance(action, (list, tuple)):
            if len(action) != size or any(
                    isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, float, np.number))
                    or isinstance(x, (complex, np.complexfloating)) for x in action):
                return None
            try:
                a = np.array([float(x) for x in action], np.float64)
            except (OverflowError, TypeError, ValueError):  # ints beyond float range
                return None
        else:
            return None
        with np.errstate(over="ignore", invalid="ignore"):
            out = a.astype(np.float32)
        if not np.all(np.isfinite(out)):
            return None
        return out

    @property
    def rules(self) -> limit_rules.Limits:
        """The limits as the shared rules take them (`mjx_envs.limit_rules`)."""
        lim = self.limits
        if getattr(self, "_rules_for", None) is not lim:  # built once per limits object
            f32 = np.float32
            self._rules = limit_rules.Limits(
                np.asarray(lim.workspace_low, f32), np.asarray(lim.workspace_high, f32),
                f32(lim.max_step), f32(lim.min_clearance), f32(lim.finger_low),
                f32(lim.finger_high))
            self._rules_for = lim
        return self._rules

    def cap_speed(self, current, proposed) -> tuple[np.ndarray, bool]:
        t, capped = limit_rules.cap_speed(np, self.rules, current, proposed)
        return t, bool(capped)

    def clamp_workspace(self, target) -> tuple[np.ndarray, bool]:
        t, clamped = limit_rules.clamp_workspace(np, self.rules, target)
        return t, bool(clamped)

    @staticmethod
    def predict_link_points(link_points, delta) -> np.ndarray:
        """Link points [2, 5, 3] after the targets move by ``delta`` [2, 3] (first order)."""
        return limit_rules.predict_link_points(np, link_points, delta)

    def clearance(self, link_points) -> float:
        return float(arm_clearance(np, np.asarray(link_points, np.float32)))

    def limit_clearance(self, current, target, link_points, tool=None):
        """(target, refused, gap now, predicted gap) after the arm-clearance rule
        (`mjx_envs.limit_rules.limit_clearance`).

        The arm is assumed to travel from its measured tool position ``tool`` [2, 3] (default:
        the current targets) to the new target within the period. A refused move is tried
        shorter (`mjx_envs.limit_rules.SHORTER`), then stops one arm (the one that moves less
        first), else the other, else both; a stopped arm keeps its
        previous target when that is safe (holding the measured position instead would let a
        real or simulated arm sag under gravity step after step), else moves towards its
        measured position by at most ``max_step``.
        """
        cur = np.asarray(current, np.float32).reshape(NUM_ARMS, 3)
        tool = cur if tool is None else np.asarray(tool, np.float32).reshape(NUM_ARMS, 3)
        target = np.asarray(target, np.float32)
        # the usual case first (the rule's first candidate, the move itself, is safe): the
        # rule would return it; this saves the other candidates' gaps (~0.4 ms per period)
        now = self.clearance(link_points)
        after = self.clearance(self.predict_link_points(link_points, target - tool))
        if after >= self.rules.min_clearance or after >= now:
            return target, False, now, after
        t, refused, now, gap = limit_rules.limit_clearance(np, self.rules, cur, target,
                                                           link_points, tool)
        return t, bool(refused), float(now), float(gap)

    # -- the whole layer ----------------------------------------------------------------------

    def hold(self, current_target, measured_tool=None, reason: str = "stop") -> SafetyDecision:
        """Stop: keep the current targets (the arms settle on the last commanded pose, at most
        one step away), or, with ``measured_tool``, move towards those positions by at most
        ``max_step`` (inside the box)."""
        t = np.asarray(current_target, np.float32).reshape(NUM_ARMS, 3).copy()
        if measured_tool is not None:
            t, _ = self.cap_speed(t, self.clamp_workspace(measured_tool)[0])
        self._count([reason])
        return SafetyDecision(target=t, stopped=True, reasons=[reason])

    def filter(self, current_target, proposed_target, link_points, tool=None) -> SafetyDecision:
        """Safe targets [2, 3] for a proposed move from ``current_target`` (both [2, 3]);
        ``link_points`` [2, 5, 3] and ``tool`` [2, 3] are the measured link and tool positions."""
        cur = np.asarray(current_target, np.float32).reshape(NUM_ARMS, 3)
        prop = np.asarray(proposed_target, np.float32).reshape(NUM_ARMS, 3)
        if not np.all(np.isfinite(prop)):
            return self.hold(cur, reason="malformed")
        reasons = []
        t, clamped = self.clamp_workspace(prop)
        if clamped:
            reasons.append("workspace")
        t, capped = self.cap_speed(cur, t)
        if capped:
            reasons.append("speed")
        t, refused, before, after = self.limit_clearance(cur, t, link_points, tool)
        if refused:
            reasons.append("clearance")
        self._count(reasons)
        return SafetyDecision(target=t, stopped=False, reasons=reasons, clearance_before=before,
                              clearance_after=after)

    def finger_opening(self, opening) -> np.ndarray:
        return limit_rules.finger_opening(np, self.rules, opening)
