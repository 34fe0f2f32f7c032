"""Frames and inverse kinematics of the two UR3 arms (NumPy only): world <- base transforms
(the nominal cell's, or any base pose), their inverse, the simulator's tool-down orientation in
a base frame, the link points of a joint configuration, and the joint solution of a tool pose
(damped least squares) with the joint-limit check. Kinematics and base poses:
`daddpg_jax.deploy.ur3`; the arms interface that uses these: `daddpg_jax.deploy.arms`.
"""

from __future__ import annotations

import numpy as np

from daddpg_jax.deploy import robot, ur3


def nominal_bases() -> np.ndarray:
    """World <- base [2, 4, 4] of the nominal cell (`ur3.BASE_POS` / ``BASE_YAW``)."""
    return np.stack([ur3.base_transform(a) for a in robot.ARMS])


def base_transform(pos, yaw: float) -> np.ndarray:
    """World <- base (4x4) of a base at ``pos`` [3] turned by ``yaw`` rad about z."""
    T = np.eye(4)
    T[:3, :3] = robot.rot_z(float(yaw))
    T[:3, 3] = np.asarray(pos, float)
    return T


def invert(T) -> np.ndarray:
    T = np.asarray(T, float)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def tool_down_rotvec(T_world_base) -> np.ndarray:
    """The simulator's tool-down orientation as a rotation vector in the base frame of
    ``T_world_base``."""
    R = np.asarray(T_world_base, float)[:3, :3].T @ robot.quat_to_matrix(robot.TOOL_DOWN_QUAT_WORLD)
    return robot.matrix_to_rotvec(R)


def link_points_base(q) -> np.ndarray:
    """Shoulder, elbow, wrist 1, flange and tool centre [5, 3] in the base frame for joint
    angles ``q`` [6] (the MJCF's link sites: DH frames 1, 2, 3 and 6, and the tool centre)."""
    T = np.eye(4)
    pts = []
    for i in range(6):
        T = T @ ur3.dh_transform(q[i], ur3.DH_D[i], ur3.DH_A[i], ur3.DH_ALPHA[i])
        if i in (0, 1, 2, 5):
            pts.append(T[:3, 3].copy())
    pts.append((T @ np.array([0.0, 0.0, ur3.TOOL_OFFSET, 1.0]))[:3])
    return np.stack(pts)


IK_ITERATIONS = 10
IK_TOLERANCE = (1e-4, 1e-3)
"""joint_solution: largest position (m) and rotation (rad) error of a solution"""
JOINT_MARGIN = 0.05
"""a target whose joint solution comes closer than this to a joint limit is refused, rad"""


def _pose_error(T, pose) -> np.ndarray:
    """[position error, rotation error (rotation vector)] of ``T`` against ``pose`` [6]."""
    R_goal = robot.rotvec_to_matrix(pose[3:])
    return np.concatenate([np.asarray(pose[:3]) - T[:3, 3],
                           robot.matrix_to_rotvec(R_goal @ T[:3, :3].T)])


def joint_solution(q0, pose, iterations: int = IK_ITERATIONS):
    """Joint angles [6] that put the tool centre at ``pose`` [x, y, z, rx, ry, rz] (base
    frame), by damped least squares from ``q0`` (the current or last solution), or None when
    it does not converge to `IK_TOLERANCE`."""
    q = np.asarray(q0, float).copy()
    pose = np.asarray(pose, float)
    for _ in range(iterations):
        err = _pose_error(ur3.forward_kinematics(q), pose)
        if np.linalg.norm(err[:3]) < IK_TOLERANCE[0] and np.linalg.norm(err[3:]) < \
                IK_TOLERANCE[1]:
            return q
        J = np.zeros((6, 6))
        for j in range(6):
            dq = q.copy()
            dq[j] += 1e-6
            J[:, j] = (err - _pose_error(ur3.forward_kinematics(dq), pose)) / 1e-6
        q = q + J.T @ np.linalg.solve(J @ J.T + 1e-6 * np.eye(6), err)
    err = _pose_error(ur3.forward_kinematics(q), pose)
    ok = np.linalg.norm(err[:3]) < IK_TOLERANCE[0] and np.linalg.norm(err[3:]) < IK_TOLERANCE[1]
    return q if ok else None


def within_joint_limits(q) -> bool:
    return bool(np.all(np.abs(np.asarray(q)) <= ur3.JOINT_LIMIT - JOINT_MARGIN))
