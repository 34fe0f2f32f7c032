"""Observation code shared by the simulator envs and the robot client.

Written once over plain arrays: every function takes the array module ``xp`` (``numpy`` or
``jax.numpy``) so the JAX environments and the NumPy-only robot client build identical
observations from the same sensor readings.

Per-arm observation (Fetch layout, 25 values, float32):

====================  =====  ==================================================
field                 size   meaning
====================  =====  ==================================================
grip_pos              3      tool centre point (between the fingertips), world m
object_pos            3      the arm's object point (bar end / pot handle), m
object_rel_pos        3      object_pos - grip_pos
fingers               2      finger openings, m
object_rot            3      object orientation as xyz Euler angles, rad
object_velp           3      object linear velocity relative to gripper, * dt
object_velr           3      object angular velocity, * dt
grip_velp             3      gripper linear velocity, * dt
finger_vel            2      finger velocities, * dt
====================  =====  ==================================================

With the task field ``action_history = k > 0`` each arm's observation ends with one more field,
``action_history`` (4 k values): that arm's own last k actions as the policy chose them
(dx, dy, dz, finger; the newest first, clipped to [-1, 1], before any action latency; zeros
before the first step). Under latency the actions already sent but not yet applied are then
part of what the policy sees. ``obs_fields(k)``, ``obs_layout(k)`` and ``obs_size(k)`` give
that layout; ``with_action_history`` and ``push_action`` are the code the envs and the robot
client share.

Object terms are zero in tasks without an object (reach). Velocities are multiplied by the
control period ``dt`` (metres per control step), as in the Fetch tasks.

Sensor timing: MuJoCo evaluates sensors inside ``mj_step`` *before* the final integration, so a
reading returned after a control step describes the state one physics timestep before the end
of that step. Both engines and the robot client read ``sensordata`` right after stepping and
use it as is.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

ARMS = ("l", "r")

OBS_FIELDS: tuple[tuple[str, int], ...] = (
    ("grip_pos", 3),
    ("object_pos", 3),
    ("object_rel_pos", 3),
    ("fingers", 2),
    ("object_rot", 3),
    ("object_velp", 3),
    ("object_velr", 3),
    ("grip_velp", 3),
    ("finger_vel", 2),
)
OBS_SIZE = sum(n for _, n in OBS_FIELDS)
"""the sensor observation's length per arm (without an action history)"""
ARM_ACTION_SIZE = 4
"""one arm's action: dx, dy, dz, finger"""


def obs_fields(action_history: int = 0) -> tuple[tuple[str, int], ...]:
    """(name, size) of each field of one arm's observation, ``action_history`` last when on."""
    k = int(action_history)
    return OBS_FIELDS + ((("action_history", ARM_ACTION_SIZE * k),) if k > 0 else ())


def obs_size(action_history: int = 0) -> int:
    """One arm's observation length: 25, plus 4 per remembered action."""
    return sum(n for _, n in obs_fields(action_history))


def obs_layout(action_history: int = 0) -> dict[str, tuple[int, int]]:
    """Field name -> (start, stop) slice of one arm's observation vector."""
    out, i = {}, 0
    for name, n in obs_fields(action_history):
        out[name] = (i, i + n)
        i += n
    return out


def empty_action_history(xp, action_history: int, batch_shape=()):
    """The history at reset: zeros [..., k, 2, 4] (no action chosen yet)."""
    return xp.zeros(tuple(batch_shape) + (int(action_history), len(ARMS), ARM_ACTION_SIZE),
                    dtype=xp.float32)


def push_action(xp, history, action):
    """The history [..., k, 2, 4] after the policy chose ``action`` ([..., 8] or [..., 2, 4];
    clipped to [-1, 1]): the newest first, the oldest dropped."""
    a = xp.clip(xp.asarray(action, dtype=xp.float32), -1.0, 1.0)
    a = a.reshape(history.shape[:-3] + (1, len(ARMS), ARM_ACTION_SIZE))
    return xp.concatenate([a, history[..., :-1, :, :]], axis=-3)


def with_action_history(xp, obs, history):
    """Each arm's observation [..., 2, n] followed by its own actions of ``history``
    [..., k, 2, 4], newest first: [..., 2, n + 4 k]."""
    h = xp.moveaxis(history, -3, -2)                       # [..., 2, k, 4]
    h = h.reshape(h.shape[:-2] + (h.shape[-2] * h.shape[-1],))
    return xp.concatenate([obs, h.astype(obs.dtype)], axis=-1)


class SensorLayout(NamedTuple):
    """Name -> (address, dimension) of every sensor in a compiled model."""

    slices: Mapping[str, tuple[int, int]]
    size: int

    @classmethod
    def from_model(cls, model: Any) -> SensorLayout:
        slices = {}
        for i in range(model.nsensor):
            s = model.sensor(i)
            slices[s.name] = (int(s.adr[0]), int(s.dim[0]))
        return cls(slices=slices, size=int(model.nsensordata))

    def has(self, name: str) -> bool:
        return name in self.slices

    def read(self, sensordata, name: str):
        adr, dim = self.slices[name]
        return sensordata[..., adr : adr + dim]

    def to_dict(self) -> dict[str, list[int]]:
        return {k: [int(a), int(d)] for k, (a, d) in self.slices.items()}


def quat_to_euler(xp, q):
    """Unit quaternion (w, x, y, z) [..., 4] -> xyz Euler angles [..., 3] (roll, pitch, yaw)."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    roll = xp.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    sinp = xp.clip(2.0 * (w * y - z * x), -1.0, 1.0)
    pitch = xp.arcsin(sinp)
    yaw = xp.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return xp.stack([roll, pitch, yaw], axis=-1)


def read_arm_sensors(xp, layout: SensorLayout, sensordata) -> dict[str, Any]:
    """Per-arm readings stacked on a leading arm axis of 2 (0 = left, 1 = right)."""

    def both(fmt):
        return xp.stack([layout.read(sensordata, fmt.format(p=p)) for p in ARMS], axis=-2)

    return {
        "grip_pos": both("{p}_grip_pos"),
        "grip_vel": both("{p}_grip_vel"),
        "fingers": xp.concatenate([both("{p}_finger1_pos"), both("{p}_finger2_pos")], axis=-1),
        "finger_vel": xp.concatenate([both("{p}_finger1_vel"), both("{p}_finger2_vel")], axis=-1),
        # link points for the analytic arm-contact check: [..., 2, 5, 3]
        "link_points": xp.stack(
            [both("{p}_shoulder_pos"), both("{p}_elbow_pos"), both("{p}_wrist1_pos"),
             both("{p}_flange_pos"), both("{p}_grip_pos")],
            axis=-2,
        ),
    }


def read_object_sensors(xp, layout: SensorLayout, sensordata, batch_shape=()) -> dict[str, Any]:
    """Object readings; zeros when the scene has no object (sensor ``obj_pos`` absent).

    ``object_point`` [..., 2, 3] is each arm's object point (``obj_point_l`` / ``obj_point_r``
    sensors: bar ends or pot handles); without those sensors the object centre serves both arms.
    """
    if not layout.has("obj_pos"):
        z3 = xp.zeros(tuple(batch_shape) + (3,), dtype=xp.float32)
        z2x3 = xp.zeros(tuple(batch_shape) + (2, 3), dtype=xp.float32)
        return {"pos": z3, "quat": xp.concatenate([z3[..., :1] + 1.0, z3], axis=-1),
                "linvel": z3, "angvel": z3, "object_point": z2x3, "present": False}
    pos = layout.read(sensordata, "obj_pos")
    if layout.has("obj_point_l"):
        point = xp.stack([layout.read(sensordata, "obj_point_l"),
                          layout.read(sensordata, "obj_point_r")], axis=-2)
    else:
        point = xp.stack([pos, pos], axis=-2)
    return {
        "pos": pos,
        "quat": layout.read(sensordata, "obj_quat"),
        "linvel": layout.read(sensordata, "obj_linvel"),
        "angvel": layout.read(sensordata, "obj_angvel"),
        "object_point": point,
        "present": True,
    }


def build_observation(xp, arm: Mapping[str, Any], obj: Mapping[str, Any], dt: float):
    """Per-arm observation [..., 2, OBS_SIZE] from the readings of ``read_*_sensors``."""
    grip_pos = arm["grip_pos"]
    grip_velp = arm["grip_vel"] * dt
    obj_point = obj["object_point"]
    shape = grip_pos.shape  # [..., 2, 3]
    if obj["present"]:
        rot = quat_to_euler(xp, obj["quat"])
        rot = xp.broadcast_to(rot[..., None, :], shape)
        velr = xp.broadcast_to((obj["angvel"] * dt)[..., None, :], shape)
        velp = xp.broadcast_to((obj["linvel"] * dt)[..., None, :], shape) - grip_velp
        rel = obj_point - grip_pos
    else:
        rot = velr = velp = rel = xp.zeros(shape, dtype=grip_pos.dtype)
        obj_point = xp.zeros(shape, dtype=grip_pos.dtype)
    parts = [grip_pos, obj_point, rel, arm["fingers"], rot, velp, velr, grip_velp,
             arm["finger_vel"] * dt]
    return xp.concatenate(parts, axis=-1).astype(xp.float32)


def observe(xp, layout: SensorLayout, sensordata, dt: float):
    """Sensor vector [..., nsensordata] -> (observation [..., 2, 25], arm readings, object
    readings)."""
    arm = read_arm_sensors(xp, layout, sensordata)
    obj = read_object_sensors(xp, layout, sensordata, batch_shape=sensordata.shape[:-1])
    return build_observation(xp, arm, obj, dt), arm, obj


# -- analytic arm-contact check -------------------------------------------------------------

# Capsules between consecutive link points (shoulder, elbow, wrist 1, flange, tool centre):
# upper arm, forearm, wrist, gripper. Radii bound the link housings of ur3_gripper.xml.
LINK_RADII = np.array([0.055, 0.045, 0.045, 0.06], dtype=np.float32)


def segment_distance(xp, p1, q1, p2, q2, eps: float = 1e-9):
    """Closest distance between segments [p1, q1] and [p2, q2] (broadcasting over leading axes).

    Ericson, Real-Time Collision Detection, 5.1.9, written without branches so it vectorizes.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = xp.sum(d1 * d1, -1)
    e = xp.sum(d2 * d2, -1)
    f = xp.sum(d2 * r, -1)
    c = xp.sum(d1 * r, -1)
    b = xp.sum(d1 * d2, -1)
    denom = a * e - b * b
    s = xp.where(denom > eps, xp.clip((b * f - c * e) / xp.maximum(denom, eps), 0.0, 1.0), 0.0)
    t = (b * s + f) / xp.maximum(e, eps)
    # clamp t and recompute s where needed
    t_c = xp.clip(t, 0.0, 1.0)
    s = xp.where(t < 0.0, xp.clip(-c / xp.maximum(a, eps), 0.0, 1.0),
                 xp.where(t > 1.0, xp.clip((b - c) / xp.maximum(a, eps), 0.0, 1.0), s))
    c1 = p1 + d1 * s[..., None]
    c2 = p2 + d2 * t_c[..., None]
    return xp.sqrt(xp.sum((c1 - c2) ** 2, -1))


def arm_clearance(xp, link_points, radii=LINK_RADII):
    """Smallest surface gap between the two arms' link capsules, metres (negative = overlap).

    ``link_points``: [..., 2, 5, 3] (arm, point, xyz).
    """
    left, right = link_points[..., 0, :, :], link_points[..., 1, :, :]
    p1, q1 = left[..., :-1, None, :], left[..., 1:, None, :]  # [..., 4, 1, 3]
    p2, q2 = right[..., None, :-1, :], right[..., None, 1:, :]  # [..., 1, 4, 3]
    dist = segment_distance(xp, p1, q1, p2, q2)  # [..., 4, 4]
    rad = xp.asarray(radii)
    gap = dist - (rad[:, None] + rad[None, :])
    return xp.min(gap.reshape(gap.shape[:-2] + (-1,)), axis=-1)
