"""The limits a policy was trained under against the robot's own (NumPy, no JAX).

A policy trained with ``daddpg-train --limits FILE`` carries the values it learned under in its
export (``meta["trained_limits"]``, served in ``GET /info``); `compare` says in one line where
the robot's limits (`daddpg_jax.deploy.safety.SafetyLimits`, after every tightening) are
tighter, i.e. where the robot will refuse moves the policy learned to rely on. Looser robot
limits are not reported: the safety layer still applies the robot's own.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

TOLERANCE = 1e-6
"""Differences below this (m) are float rounding, not a tighter limit."""


def compare(trained: Mapping | None, robot) -> str | None:
    """One line naming every limit where ``robot`` (SafetyLimits) is tighter than ``trained``
    (a policy's ``trained_limits``), None when none is; a policy without trained limits gives
    a line saying so."""
    if not isinstance(trained, Mapping):
        return ("the policy was trained without robot limits (daddpg-train --limits): the "
                "robot's safety layer may refuse moves it relies on")
    out = []
    try:
        step = float(trained["max_step"])
        if robot.max_step < step - TOLERANCE:
            out.append(f"max step {robot.max_step * 1e3:.3g} mm < trained {step * 1e3:.3g} mm")
        clear = float(trained["min_clearance"])
        if robot.min_clearance > clear + TOLERANCE:
            out.append(f"min clearance {robot.min_clearance:g} m > trained {clear:g} m")
        lo = np.asarray(trained["workspace_low"], float).reshape(2, 3)
        hi = np.asarray(trained["workspace_high"], float).reshape(2, 3)
        for i, arm in enumerate(("left", "right")):
            if (np.any(robot.workspace_low[i] > lo[i] + TOLERANCE)
                    or np.any(robot.workspace_high[i] < hi[i] - TOLERANCE)):
                box = _box(robot.workspace_low[i], robot.workspace_high[i])
                out.append(f"{arm} workspace {box} inside trained {_box(lo[i], hi[i])}")
        f_lo, f_hi = float(trained["finger_low"]), float(trained["finger_high"])
        if robot.finger_low > f_lo + TOLERANCE or robot.finger_high < f_hi - TOLERANCE:
            out.append(f"fingers {robot.finger_low:g}..{robot.finger_high:g} m inside trained "
                       f"{f_lo:g}..{f_hi:g} m")
    except (KeyError, TypeError, ValueError):
        return "the policy's trained_limits are malformed: treated as trained without limits"
    if not out:
        return None
    return "the robot's limits are tighter than the policy's training: " + "; ".join(out)


def _box(low, high) -> str:
    return (f"[{', '.join(f'{x:g}' for x in low)}]..[{', '.join(f'{x:g}' for x in high)}]")


def check(info: Mapping, robot, require: bool = False) -> str | None:
    """`compare` of a served policy's ``GET /info`` (``trained_limits``); with ``require`` a
    mismatch (or no trained limits) raises ValueError with that line; without ``require`` a
    policy trained without limits gives None."""
    trained = info.get("trained_limits") if isinstance(info, Mapping) else None
    if trained is None and not require:  # an older or unlimited policy: nothing to compare
        return None
    line = compare(trained, robot)
    if line is not None and require:
        raise ValueError(f"--require-trained-limits: {line}")
    return line
