"""Observation and action perturbations of a camera and a network, written once over ``xp``.

Every function takes the array module ``xp`` (``numpy`` or ``jax.numpy``) and a sampler of
`mjx_envs.rules` (``JaxSampler`` with PRNG keys, ``NumpySampler`` with a NumPy Generator), so
the JAX env (both engines: the perturbations act on observations and actions, not on the
physics) and the robot client (`daddpg_jax.deploy.robot`, sim-to-sim) run the same code.

The task fields (`mjx_envs.settings.TaskConfig`), each 0 = off:

==============  ================================================================================
obs_noise       std (m) of Gaussian noise on each arm's object point and gripper position,
                drawn every control step
obs_dropout     probability per control step that the object observation (position, rotation,
                velocities) stays at its last value, as under occlusion; the object's position
                relative to the gripper is recomputed from the held position
obs_bias        length (m) of one offset of the object positions per episode, in a random
                direction (a camera calibration error)
obs_period      a new observation every k control steps, the last one held in between
latency         actions are applied k control steps late (no motion before the first arrives)
==============  ================================================================================

``perturb_exact`` chooses what the values mean. False (training randomization): each episode
draws its own value uniformly up to the bound (noise std, dropout probability and bias length
in [0, bound]; period an integer in 1..k; latency an integer in 0..k). True (evaluation under a
perturbation, ``daddpg-evaluate --perturb``): every episode uses the values exactly.

Noise and bias move the object and gripper positions; ``object_rel_pos`` is recomputed from the
perturbed values, so the observation stays self-consistent. In reach (no object) the object
terms stay zero: noise moves the gripper positions only, bias and dropout change nothing. The
achieved goal, the reward and success are computed from the true state: only what the policy
sees changes.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from mjx_envs.observation import OBS_SIZE, obs_layout
from mjx_envs.settings import ObjectTaskConfig

FIELDS = ("obs_noise", "obs_dropout", "obs_bias", "obs_period", "latency")
"""the task fields of this module (all 0 = off), besides the mode ``perturb_exact``"""

OBJECT_FIELDS = ("object_pos", "object_rot", "object_velp", "object_velr")
"""held at their last value under dropout"""

ACTION_SIZE = 8

STREAM = 0x5E750
"""the perturbations' own PRNG stream (``fold_in`` of the trainer's reset key, second seed word
of the robot client's generator): the task's draws stay those of the unperturbed env"""

_SLICES = obs_layout()


@dataclasses.dataclass(frozen=True)
class Perturbation:
    """The perturbation fields of a task config (bounds, or exact values)."""
    obs_noise: float = 0.0
    obs_dropout: float = 0.0
    obs_bias: float = 0.0
    obs_period: int = 0
    latency: int = 0
    exact: bool = False
    has_object: bool = True
    """False in reach: its object terms stay zero (no noise, bias or relative position)"""

    @classmethod
    def from_config(cls, cfg) -> Perturbation:
        vals = {name: getattr(cfg, name, 0) for name in FIELDS}
        return cls(**vals, exact=bool(getattr(cfg, "perturb_exact", False)),
                   has_object=isinstance(cfg, ObjectTaskConfig))

    @property
    def observes(self) -> bool:
        """Whether observations are perturbed."""
        return bool(self.obs_noise or self.obs_dropout or self.obs_bias or self.obs_period > 1)

    @property
    def active(self) -> bool:
        return self.observes or self.latency > 0


def draw(xp, sampler, key, p: Perturbation) -> dict:
    """One episode's values: noise std, dropout probability, bias [3], period, latency."""
    k_noise, k_drop, k_dir, k_len, k_period, k_lat = sampler.split(key, 6)
    f32 = np.float32
    if p.exact:
        noise, dropout, length = f32(p.obs_noise), f32(p.obs_dropout), f32(p.obs_bias)
        period, latency = max(int(p.obs_period), 1), int(p.latency)
        period, latency = xp.asarray(period, xp.int32), xp.asarray(latency, xp.int32)
    else:
        noise = sampler.uniform(k_noise, (), 0.0, p.obs_noise)
        dropout = sampler.uniform(k_drop, (), 0.0, p.obs_dropout)
        length = sampler.uniform(k_len, (), 0.0, p.obs_bias)
        # integers uniform in 1..k and 0..k (the floor of a uniform draw, clipped at the top)
        period = xp.minimum(xp.floor(sampler.uniform(k_period, (), 1.0, max(p.obs_period, 1)
                                                     + 1.0)), max(p.obs_period, 1))
        latency = xp.minimum(xp.floor(sampler.uniform(k_lat, (), 0.0, p.latency + 1.0)),
                             p.latency)
        period, latency = period.astype(xp.int32), latency.astype(xp.int32)
    direction = sampler.normal(k_dir, (3,))
    direction = direction / xp.maximum(xp.linalg.norm(direction), f32(1e-6))
    return dict(noise=xp.asarray(noise, xp.float32), dropout=xp.asarray(dropout, xp.float32),
                bias=(direction * length).astype(xp.float32), period=period, latency=latency)


def _field(obs, name):
    a, b = _SLICES[name]
    return obs[..., a:b]


def _with(xp, obs, **fields):
    """obs [2, OBS_SIZE] with the named fields replaced."""
    parts = [fields.get(name, obs[..., a:b]) for name, (a, b) in _SLICES.items()]
    return xp.concatenate(parts, axis=-1)


def _corrupt(xp, sampler, key, p: Perturbation, values: dict, obs):
    """Noise and bias on the object and gripper positions; object_rel_pos recomputed."""
    grip, obj = _field(obs, "grip_pos"), _field(obs, "object_pos")
    if p.obs_bias:
        obj = obj + values["bias"]
    if p.obs_noise:
        k_grip, k_obj = sampler.split(key, 2)
        grip = grip + values["noise"] * sampler.normal(k_grip, grip.shape)
        obj = obj + values["noise"] * sampler.normal(k_obj, obj.shape)
    if not p.has_object:   # reach: the object terms stay zero
        return _with(xp, obs, grip_pos=grip)
    return _with(xp, obs, grip_pos=grip, object_pos=obj, object_rel_pos=obj - grip)


def start(xp, sampler, key, p: Perturbation, obs) -> tuple:
    """(the observation [2, OBS_SIZE] the policy sees at reset, the episode's carry)."""
    k_draw, k_obs = sampler.split(key, 2)
    values = draw(xp, sampler, k_draw, p)
    seen = _corrupt(xp, sampler, k_obs, p, values, obs).astype(xp.float32)
    carry = dict(values, held=seen, t=xp.asarray(0, xp.int32),
                 queue=xp.zeros((max(int(p.latency), 1), ACTION_SIZE), xp.float32))
    return seen, carry


def observe(xp, sampler, key, p: Perturbation, carry: dict, obs) -> tuple:
    """(the observation the policy sees after a control step, the carry after it); obs: the
    true observation [2, OBS_SIZE] after the step."""
    k_obs, k_drop = sampler.split(key, 2)
    seen = _corrupt(xp, sampler, k_obs, p, carry, obs)
    held = carry["held"]
    if p.obs_dropout and p.has_object:
        drop = sampler.uniform(k_drop, (), 0.0, 1.0) < carry["dropout"]
        kept = {name: xp.where(drop, _field(held, name), _field(seen, name))
                for name in OBJECT_FIELDS}
        rel = kept["object_pos"] - _field(seen, "grip_pos")
        seen = _with(xp, seen, object_rel_pos=rel, **kept)
    t = carry["t"] + 1
    if p.obs_period > 1:
        seen = xp.where(t % carry["period"] == 0, seen, held)
    seen = seen.astype(xp.float32)
    return seen, dict(carry, held=seen, t=t)


def delay(xp, p: Perturbation, carry: dict, action) -> tuple:
    """(the action [8] applied now, the carry): the policy's action of `latency` steps ago,
    zeros (no motion) before the first one."""
    if p.latency <= 0:
        return action, carry
    action = xp.asarray(action, xp.float32).reshape(ACTION_SIZE)
    hist = xp.concatenate([action[None], carry["queue"]], axis=0)      # [L + 1, 8]
    applied = xp.take(hist, carry["latency"], axis=0)
    return applied, dict(carry, queue=hist[:-1])


assert OBS_SIZE == sum(b - a for a, b in _SLICES.values())
