"""Per-env physics randomization, drawn at reset on the device, for both engines.

The task fields (`mjx_envs.settings`), each a scalar with 0 = off:

===============  ====================================================================  =======
field            what it changes                                                       tasks
===============  ====================================================================  =======
object_mass      the object's mass and inertia, x (1 + v)                              objects
object_size      every object geom's half-sizes, + v metres (a few mm); the resting    objects
                 height moves by v
object_friction  the tangential friction of every contact pair with the object,        objects
                 x (1 + v)
table_height     the table top's height, + v metres; the resting height moves by v     objects
grasp_timeconst  the contact time constant (solref[0]) of every finger-object pair,    objects
                 x (1 + v): the grip's contact stiffness goes as 1 / timeconst^2
base_offset      each arm's base (mount) position, moved by v metres in a random       all
                 direction (one per arm)
base_yaw         each arm's base turned by v degrees about the vertical (one draw per  all
                 arm)
finger_force     the finger servos' stiffness and force limit, x (1 + v)               all
action_scale     the gripper's Cartesian step per action, x (1 + v)                    all
===============  ====================================================================  =======

``perturb_exact`` (shared with `mjx_envs.perturb`) chooses what the values mean. False
(training randomization): each episode draws v uniformly in [-|b|, |b|] for the bound b (the
offset length in [0, b], its direction uniform). True (``daddpg-evaluate --perturb``): every
episode uses v = b exactly (the base offset keeps a random direction, of length b, and both
arms turn by b).

How the fields act:
- The model fields are computed once per draw by `model_fields`, written over ``xp``: the MJX
  backend replaces them in its ``mjx.Model`` inside the vmapped step (a per-env model), the
  C engine writes them into per-env ``MjModel`` copies that ``mujoco.rollout`` steps, so both
  engines run the same values. Quantities MuJoCo precomputes at compile time from these fields
  (``body_invweight0``, ``dof_invweight0``, ``stat``) stay nominal on both engines.
- Object size and table height move the object's resting height (`rest_shift`): the initial
  pose and the goal heights (which are relative to the resting height) move with it.
- Base offset and yaw model a calibration error of each arm's base. The arm's mount is moved
  and turned, and the arm's Cartesian target, which the policy gives in the nominal frame, is
  mapped to the true one: target_true = R(yaw) (target - base) + base + offset (so the arm's
  home posture and its gripper orientation move with the base, with no jump at reset). The
  gripper position and velocity the policy observes are the arm's own belief: mapped back to
  the nominal frame (`believed_obs`); the object, observed by a camera in the world frame, is
  not. The achieved goal, the reward and success use the true positions.
- Action scale multiplies the target step ``max_delta * a`` before the workspace clip.

Grasped-state starts (`mjx_envs.tasks.grasp_start`) are recorded under nominal physics. A
recorded grasp is exact only under the nominal geometry, so an episode that starts from one
keeps the object size, table height and arm bases nominal (`GEOMETRY_MASK`) and its goal at the
nominal height; mass, friction, finger force and action scale are randomized as in any episode.
Object size changes the geometry only: mass and inertia are `object_mass`'s.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from mjx_envs.observation import obs_layout
from mjx_envs.rules import yaw_quat
from mjx_envs.settings import RANDOMIZATION_FIELDS as FIELDS

OBJECT_FIELDS = FIELDS[:5]

NUM_ARMS = 2
STREAM = 0x9A7D0
"""``fold_in`` constant of the randomization's draws from the reset key (`mjx_envs.wrappers.
Randomize`): the task's draws stay those of the nominal env"""
PARAMS = 14
"""length of one env's parameter vector: mass scale, size delta, friction scale, table delta,
finger scale, base offsets [2, 3], base yaws [2] (radians), grasp time-constant scale (last, so
that the first 13 keep their places)"""

GEOMETRY_MASK = np.array([False, True, False, True, False] + [True] * 8 + [False])
"""the parameters that move geometry (object size, table height, arm bases): nominal in an
episode that starts from a recorded grasped state"""

_MOUNTS = ("l_mount", "r_mount")
_TARGETS = ("l_target", "r_target")
_FINGERS = ("l_finger1", "l_finger2", "r_finger1", "r_finger2")
_TABLE = "tabletop"


@dataclasses.dataclass(frozen=True)
class Randomization:
    """The randomization fields of a task config (bounds, or exact values)."""
    object_mass: float = 0.0
    object_size: float = 0.0
    object_friction: float = 0.0
    table_height: float = 0.0
    grasp_timeconst: float = 0.0
    base_offset: float = 0.0
    base_yaw: float = 0.0
    finger_force: float = 0.0
    action_scale: float = 0.0
    exact: bool = False

    @classmethod
    def from_config(cls, cfg) -> Randomization:
        vals = {name: float(getattr(cfg, name, 0.0)) for name in FIELDS}
        return cls(**vals, exact=bool(getattr(cfg, "perturb_exact", False)))

    @property
    def physical(self) -> bool:
        """Whether the physics model differs between envs (every field but action_scale)."""
        return any(getattr(self, name) for name in FIELDS if name != "action_scale")

    @property
    def moves_base(self) -> bool:
        return bool(self.base_offset or self.base_yaw)

    @property
    def active(self) -> bool:
        return self.physical or bool(self.action_scale)


def _signed(sampler, key, bound: float, exact: bool, shape=()):
    if exact:
        return np.full(shape, bound, np.float32) if shape else np.float32(bound)
    b = abs(float(bound))
    return sampler.uniform(key, shape, -b, b)


def draw(xp, sampler, key, r: Randomization) -> dict:
    """One episode's values: ``params`` [PARAMS] (the model's, `model_fields`), ``action_scale``
    [] and ``rest_shift`` [] (metres the object's resting height moves)."""
    keys = sampler.split(key, 10)   # the 10th (grasp_timeconst) last: the others' draws stay
    f32 = xp.float32
    mass = 1.0 + _signed(sampler, keys[0], r.object_mass, r.exact)
    size = _signed(sampler, keys[1], r.object_size, r.exact)
    friction = 1.0 + _signed(sampler, keys[2], r.object_friction, r.exact)
    table = _signed(sampler, keys[3], r.table_height, r.exact)
    finger = 1.0 + _signed(sampler, keys[4], r.finger_force, r.exact)
    direction = sampler.normal(keys[5], (NUM_ARMS, 3))
    direction = direction / xp.maximum(xp.linalg.norm(direction, axis=-1, keepdims=True),
                                       f32(1e-6))
    if r.exact:
        length = xp.full((NUM_ARMS, 1), r.base_offset, f32)
    else:
        length = sampler.uniform(keys[6], (NUM_ARMS, 1), 0.0, abs(r.base_offset))
    offset = direction * length
    yaw = np.float32(np.pi / 180.0) * _signed(sampler, keys[7], r.base_yaw, r.exact,
                                              (NUM_ARMS,))
    action = 1.0 + _signed(sampler, keys[8], r.action_scale, r.exact)
    # drawn only when on: a NumPy sampler's stream (one generator, draws in order) stays as it was
    timeconst = (1.0 + _signed(sampler, keys[9], r.grasp_timeconst, r.exact)
                 if r.grasp_timeconst else np.float32(1.0))
    scalars = xp.stack([xp.asarray(v, f32) for v in (mass, size, friction, table, finger)])
    params = xp.concatenate([scalars, offset.reshape(-1).astype(f32),
                             xp.asarray(yaw, f32).reshape(-1),
                             xp.asarray(timeconst, f32).reshape(1)])
    return dict(params=params.astype(f32), action_scale=xp.asarray(action, f32),
                rest_shift=xp.asarray(table + size, f32))


def unpack(params) -> dict:
    """The named parts of a parameter vector [..., PARAMS]."""
    return dict(mass=params[..., 0], size=params[..., 1], friction=params[..., 2],
                table=params[..., 3], finger=params[..., 4],
                offset=params[..., 5:11].reshape(params.shape[:-1] + (NUM_ARMS, 3)),
                yaw=params[..., 11:13], timeconst=params[..., 13])


def nominal_params() -> np.ndarray:
    """The parameter vector of the nominal model."""
    p = np.zeros(PARAMS, np.float32)
    p[[0, 2, 4, 13]] = 1.0
    return p


# -- the model's fields ---------------------------------------------------------------------

def quat_mul(xp, a, b):
    """Hamilton product of quaternions (w, x, y, z) [..., 4]."""
    aw, ax, ay, az = (a[..., i] for i in range(4))
    bw, bx, by, bz = (b[..., i] for i in range(4))
    return xp.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def _rot_z(xp, yaw):
    """Rotation matrices [..., 3, 3] about z."""
    c, s = xp.cos(yaw), xp.sin(yaw)
    zero, one = xp.zeros_like(c), xp.ones_like(c)
    return xp.stack([xp.stack([c, -s, zero], -1), xp.stack([s, c, zero], -1),
                     xp.stack([zero, zero, one], -1)], -2)


def _set_rows(xp, a, rows, value):
    if xp is np:
        out = np.array(a, copy=True)
        out[rows] = value
        return out
    return a.at[rows].set(value)


class ModelIndex:
    """Where the randomized quantities live in a compiled scene, and their nominal values
    (float32). ``object_body``: the task's object body name (None: reach)."""

    def __init__(self, model, object_body: str | None, r: Randomization):
        self.r = r
        self.mounts = np.array([model.body(n).id for n in _MOUNTS])
        self.targets = np.array([model.body(n).id for n in _TARGETS])
        self.target_mocap = np.asarray(model.body_mocapid[self.targets])
        self.base_pos = np.asarray(model.body_pos[self.mounts], np.float32)  # [2, 3]
        self.fingers = np.array([model.actuator(n).id for n in _FINGERS])
        self.has_object = object_body is not None
        if self.has_object:
            self.body = model.body(object_body).id
            self.geoms = np.flatnonzero(model.geom_bodyid == self.body)
            g1, g2 = model.pair_geom1, model.pair_geom2
            self.pairs = np.flatnonzero(np.isin(g1, self.geoms) | np.isin(g2, self.geoms))
            self.table = model.geom(_TABLE).id
            on_table = (g1[self.pairs] == self.table) | (g2[self.pairs] == self.table)
            self.grip_pairs = self.pairs[~on_table]   # the finger-object pairs
        names = ["actuator_gainprm", "actuator_biasprm", "actuator_forcerange"]
        if r.moves_base:
            names += ["body_pos", "body_quat"]
        if self.has_object:
            names += ["body_mass", "body_inertia", "body_subtreemass", "geom_size",
                      "geom_rbound", "geom_pos", "pair_friction", "pair_solref"]
        # float64 (the C engine's own values, so that rows left nominal stay bit-exact there);
        # model_fields casts to float32 under jax.numpy
        self.nominal = {n: np.array(getattr(model, n), np.float64) for n in names}

    def fields(self) -> tuple[str, ...]:
        """The model fields `model_fields` returns (static for this randomization)."""
        r, out = self.r, []
        if r.finger_force:
            out += ["actuator_gainprm", "actuator_biasprm", "actuator_forcerange"]
        if r.moves_base:
            out += ["body_pos", "body_quat"]
        if self.has_object:
            if r.object_mass:
                out += ["body_mass", "body_inertia", "body_subtreemass"]
            if r.object_size:
                out += ["geom_size", "geom_rbound"]
            if r.table_height:
                out += ["geom_pos"]
            if r.object_friction:
                out += ["pair_friction"]
            if r.grasp_timeconst:
                out += ["pair_solref"]
        return tuple(out)


def model_fields(xp, ix: ModelIndex, params) -> dict:
    """The randomized model fields (full arrays: float64 over NumPy for the C engine, float32
    over jax.numpy for MJX) of one env's parameter vector [PARAMS]; only the fields
    `ModelIndex.fields` names (the others stay nominal), and in them only the randomized rows
    differ from the nominal values."""
    dtype = np.float64 if xp is np else xp.float32
    params = xp.asarray(params).astype(dtype)
    p, nom, out = unpack(params), {k: xp.asarray(v).astype(dtype)
                                   for k, v in ix.nominal.items()}, {}
    names = ix.fields()
    if "actuator_gainprm" in names:
        f, rows = p["finger"], ix.fingers
        out["actuator_gainprm"] = _set_rows(xp, nom["actuator_gainprm"], (rows, 0),
                                            nom["actuator_gainprm"][rows, 0] * f)
        out["actuator_biasprm"] = _set_rows(xp, nom["actuator_biasprm"], (rows, 1),
                                            nom["actuator_biasprm"][rows, 1] * f)
        out["actuator_forcerange"] = _set_rows(xp, nom["actuator_forcerange"], rows,
                                               nom["actuator_forcerange"][rows] * f)
    if "body_pos" in names:
        out["body_pos"] = _set_rows(xp, nom["body_pos"], ix.mounts,
                                    nom["body_pos"][ix.mounts] + p["offset"])
        q = yaw_quat(xp, p["yaw"])
        quat = _set_rows(xp, nom["body_quat"], ix.mounts,
                         quat_mul(xp, q, nom["body_quat"][ix.mounts]))
        out["body_quat"] = _set_rows(xp, quat, ix.targets,
                                     quat_mul(xp, q, nom["body_quat"][ix.targets]))
    if "body_mass" in names:
        b, m = ix.body, p["mass"]
        out["body_mass"] = _set_rows(xp, nom["body_mass"], b, nom["body_mass"][b] * m)
        out["body_inertia"] = _set_rows(xp, nom["body_inertia"], b, nom["body_inertia"][b] * m)
        sub = _set_rows(xp, nom["body_subtreemass"], b, nom["body_subtreemass"][b] * m)
        out["body_subtreemass"] = _set_rows(xp, sub, 0, nom["body_subtreemass"][0]
                                            + nom["body_mass"][b] * (m - 1.0))
    if "geom_size" in names:
        g, d = ix.geoms, p["size"]
        out["geom_size"] = _set_rows(xp, nom["geom_size"], g,
                                     xp.maximum(nom["geom_size"][g] + d, 1e-4))
        out["geom_rbound"] = _set_rows(xp, nom["geom_rbound"], g, nom["geom_rbound"][g]
                                       + np.sqrt(3.0) * xp.maximum(d, 0.0))
    if "geom_pos" in names:
        out["geom_pos"] = _set_rows(xp, nom["geom_pos"], (ix.table, 2),
                                    nom["geom_pos"][ix.table, 2] + p["table"])
    if "pair_friction" in names:
        rows = ix.pairs
        out["pair_friction"] = _set_rows(xp, nom["pair_friction"], (rows[:, None],
                                         np.array([0, 1])[None, :]),
                                         nom["pair_friction"][rows][:, :2] * p["friction"])
    if "pair_solref" in names:
        rows = ix.grip_pairs
        out["pair_solref"] = _set_rows(xp, nom["pair_solref"], (rows, 0),
                                       nom["pair_solref"][rows, 0] * p["timeconst"])
    return out


# -- the arms' frames ------------------------------------------------------------------------

def to_true(xp, ix: ModelIndex, params, target):
    """The true Cartesian targets [2, 3] of nominal-frame targets [2, 3]."""
    p = unpack(params)
    rot = _rot_z(xp, p["yaw"])                                   # [2, 3, 3]
    rel = (target - ix.base_pos)[..., None]
    return (rot @ rel)[..., 0] + ix.base_pos + p["offset"]


def to_nominal(xp, ix: ModelIndex, params, pos):
    """The nominal-frame positions [2, 3] of true positions [2, 3] (`to_true`'s inverse)."""
    p = unpack(params)
    rot = _rot_z(xp, p["yaw"])
    rel = (pos - ix.base_pos - p["offset"])[..., None]
    return (xp.swapaxes(rot, -1, -2) @ rel)[..., 0] + ix.base_pos


def believed_obs(xp, ix: ModelIndex, params, obs):
    """The observation [2, OBS_SIZE] with each gripper's position and velocity in its arm's
    nominal frame (what the arm believes); in object tasks the object's position and velocity
    relative to the gripper (object_rel_pos, object_velp) follow the believed gripper (reach
    keeps its zero object terms)."""
    sl = obs_layout()

    def field(name):
        a, b = sl[name]
        return obs[:, a:b]

    rot = _rot_z(xp, unpack(params)["yaw"])
    grip = to_nominal(xp, ix, params, field("grip_pos"))
    vel = (xp.swapaxes(rot, -1, -2) @ field("grip_velp")[..., None])[..., 0]
    parts = {"grip_pos": grip, "grip_velp": vel}
    if ix.has_object:
        parts["object_rel_pos"] = field("object_pos") - grip
        parts["object_velp"] = field("object_velp") + field("grip_velp") - vel
    return xp.concatenate([parts.get(name, obs[:, i:j]) for name, (i, j) in sl.items()],
                          axis=-1)
