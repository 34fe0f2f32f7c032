"""UR3 kinematics from the maker's DH table (NumPy only), used to check the MJCF and by the
real-robot conventions.

Standard DH: T_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i); joint angles equal the robot's own.
"""

from __future__ import annotations

import numpy as np

DH_D = np.array([0.1519, 0.0, 0.0, 0.11235, 0.08535, 0.0819])
DH_A = np.array([0.0, -0.24365, -0.21325, 0.0, 0.0, 0.0])
DH_ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])
TOOL_OFFSET = 0.10
"""Flange to tool centre point (between the fingertips) along z6, metres."""
JOINT_LIMIT = 2 * np.pi
"""UR3 joint range is +-360 deg on every joint."""

# Arm bases in the sim world frame (see assets/dual_ur3.xml): position and yaw.
BASE_POS = {"l": np.array([0.0, 0.25, 0.40]), "r": np.array([0.0, -0.25, 0.40])}
BASE_YAW = {"l": np.pi, "r": np.pi}


def dh_transform(theta, d, a, alpha) -> np.ndarray:
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return np.array([[ct, -st * ca, st * sa, a * ct],
                     [st, ct * ca, -ct * sa, a * st],
                     [0.0, sa, ca, d],
                     [0.0, 0.0, 0.0, 1.0]])


def base_transform(arm: str) -> np.ndarray:
    """World <- robot base frame (4x4) for arm 'l' or 'r'."""
    c, s = np.cos(BASE_YAW[arm]), np.sin(BASE_YAW[arm])
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = BASE_POS[arm]
    return T


def forward_kinematics(q, base: np.ndarray | None = None, tool: float = TOOL_OFFSET) -> np.ndarray:
    """Pose (4x4) of the tool centre point for joint angles ``q`` [6] (base frame by default)."""
    T = np.eye(4) if base is None else np.asarray(base, float)
    for i in range(6):
        T = T @ dh_transform(q[i], DH_D[i], DH_A[i], DH_ALPHA[i])
    tool_T = np.eye(4)
    tool_T[2, 3] = tool
    return T @ tool_T
