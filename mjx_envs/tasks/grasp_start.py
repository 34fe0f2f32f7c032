"""Grasped start states of the lifting tasks (Pick up, Pot) for ``grasp_start_fraction``.

A pickup or pot env with ``grasp_start_fraction > 0`` (a training-only field of
`mjx_envs.settings.LiftTaskConfig`) asks `grasp_states` for them when its first reset is traced
(building the env simulates nothing). It records ``n_grasp_states`` simulator states in which
both grippers are closed on the object, once per process and task config (cached):

1. a C-engine env of the same task and config with both training-only options off (the
   standard task, nominal physics) is reset with ``n_grasp_states + max(8, n_grasp_states // 4)``
   keys split from ``PRNGKey(GRASP_SEED)``: one seed, and so one initial object pose, per try;
2. the task's scripted controller (`mjx_envs.tasks.scripted.grasp_policy`) drives the whole
   batch for `MAX_STEPS` control steps in one jitted program; once both grippers hold, its
   carrying moves are replaced by zero motion (fingers kept closed), so the object stays where
   it lies on the table;
3. a try's state is taken at the first step at which the controller's own grasp signal
   (`mjx_envs.tasks.scripted.holding`) has been on for both arms for `SETTLE_STEPS` steps in a
   row, with the physics healthy;
4. that state is checked with MuJoCo's contacts: each of the four fingers touches the object
   with a normal force of at least `MIN_FINGER_FORCE`;
5. the first ``n_grasp_states`` tries that pass are kept; fewer raise `GraspRecordError`.

Only the simulator states are kept (qpos, qvel and the two Cartesian targets), never the
controller's actions. The env samples from them at reset (`mix`). The states are recorded with
the C engine whatever engine the env uses (an MJX env starts from the same states; recording
with MJX would compile a second MJX program). At the default 64 states the recording plays 80
tries of 30 control steps (its time: docs/TRAINING.md, "Training task distribution").
"""

from __future__ import annotations

import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjx_envs.schema import replace_config
from mjx_envs.tasks import scripted

GRASP_SEED = 20_240
"""Seed of the recording episodes' keys (independent of the training seed)."""
GRASP_STREAM = 0x6A5B
"""``fold_in`` constant of the reset key for the grasped-start draws (the standard reset's draws
are unchanged)."""
MAX_STEPS = 30
"""Control steps per recording episode (the controller grasps after 4-15 steps)."""
SETTLE_STEPS = 4
"""Consecutive control steps of the grasp signal before a state is taken."""
MIN_FINGER_FORCE = 0.5
"""Smallest normal force of each finger on the object in a kept state, newtons (a closed
finger squeezes a neck or handle with ~5-6 N)."""


class GraspRecordError(RuntimeError):
    """Too few scripted grasps succeeded to record ``n_grasp_states`` states."""


class GraspStates(NamedTuple):
    """Recorded grasped states (float32, NumPy) and how they were obtained."""

    qpos: np.ndarray  # [n, nq]
    qvel: np.ndarray  # [n, nv]
    mocap: np.ndarray  # [n, 2, 3] the grippers' Cartesian targets
    tries: int  # recording episodes played
    seconds: float  # wall time of the recording


_CACHE: dict = {}


def grasp_states(env_cls, config) -> GraspStates:
    """The grasped states of task ``env_cls.task_name`` under ``config`` (its training-only
    options do not matter: the standard task is recorded); recorded on first use, then cached
    per process. May be called while a reset is being traced: the recording runs eagerly
    (``jax.ensure_compile_time_eval``), outside the traced program."""
    task = env_cls.task_name
    # nominal: no perturbation either
    base = replace_config(config, **config.training_only_off())
    key = (task, base)
    if key not in _CACHE:
        with jax.ensure_compile_time_eval():
            _CACHE[key] = _record(env_cls, base)
    return _CACHE[key]


def mix(states: GraspStates, fraction: float, key, start):
    """The start ``(qpos, qvel, mocap, grasped)`` of one episode: with probability ``fraction``
    one of ``states`` (chosen uniformly; grasped = True), else ``start``; draws from
    ``fold_in(key, GRASP_STREAM)``."""
    qpos, qvel, mocap = start[:3]
    k_use, k_pick = jax.random.split(jax.random.fold_in(key, GRASP_STREAM))
    use = jax.random.uniform(k_use, (), jnp.float32) < fraction
    i = jax.random.randint(k_pick, (), 0, states.qpos.shape[0])

    def pick(table, x):
        return jnp.where(use, jnp.asarray(table, jnp.float32)[i], x)

    return pick(states.qpos, qpos), pick(states.qvel, qvel), pick(states.mocap, mocap), use


def _play(env, keys):
    """The batch of recording episodes: per step (qpos, qvel, mocap, both arms holding and
    physics healthy), each [MAX_STEPS, B, ...] (NumPy)."""
    policy = scripted.get_policy(env.task_name)
    max_delta = env.config.max_delta

    def run(keys):
        s = jax.vmap(env.reset)(keys)

        def body(s, _):
            a = policy(s.obs, max_delta)
            # once both grippers hold: fingers stay closed (the controller's choice), no motion
            both = jnp.all(scripted.holding(s.obs), axis=-1)
            still = a.reshape(a.shape[:-1] + (2, 4)).at[..., :3].set(0.0).reshape(a.shape)
            s = jax.vmap(env.step)(s, jnp.where(both[..., None], still, a))
            held = jnp.all(scripted.holding(s.obs), axis=-1) & (s.metrics["physics_ok"] > 0.5)
            return s, (s.data.qpos, s.data.qvel, s.data.mocap_pos, held)

        return jax.lax.scan(body, s, None, length=MAX_STEPS)[1]

    return jax.device_get(jax.jit(run)(keys))


def _settled_step(held) -> np.ndarray:
    """Per episode, the first step ending `SETTLE_STEPS` steps of ``held`` [T, B] in a row;
    -1 where there is none."""
    held = np.asarray(held, bool)
    run = np.zeros(held.shape[1], int)
    out = np.full(held.shape[1], -1)
    for t in range(held.shape[0]):
        run = np.where(held[t], run + 1, 0)
        out = np.where((out < 0) & (run >= SETTLE_STEPS), t, out)
    return out


class FingerContacts:
    """Which fingers touch the object in a state (MuJoCo's C engine, ``mj_forward``)."""

    FINGERS = ("l_finger1", "l_finger2", "r_finger1", "r_finger2")

    def __init__(self, model: mujoco.MjModel, object_body: str):
        self.model, self.data = model, mujoco.MjData(model)
        # every geom of a finger's body counts as that finger (physics version 4 adds a mesh
        # copy of each finger box for its grasp pairs, `mjx_envs.model.PHYSICS_V4`)
        bodies = {int(model.geom(name).bodyid[0]): name for name in self.FINGERS}
        self.fingers = {g: bodies[int(model.geom_bodyid[g])] for g in range(model.ngeom)
                        if int(model.geom_bodyid[g]) in bodies}
        self.body = model.body(object_body).id

    def forces(self, qpos, qvel, mocap) -> dict[str, float]:
        """Finger geom name -> total normal force on the object, newtons."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[:] = qpos
        d.qvel[:] = qvel
        d.mocap_pos[: len(mocap)] = mocap
        mujoco.mj_forward(m, d)
        out = dict.fromkeys(self.FINGERS, 0.0)
        f = np.zeros(6)
        for i in range(d.ncon):
            c = d.contact[i]
            for a, b in ((c.geom1, c.geom2), (c.geom2, c.geom1)):
                if a in self.fingers and m.geom_bodyid[b] == self.body:
                    mujoco.mj_contactForce(m, d, i, f)
                    out[self.fingers[a]] += float(f[0])
        return out

    def holds(self, qpos, qvel, mocap) -> bool:
        return min(self.forces(qpos, qvel, mocap).values()) >= MIN_FINGER_FORCE


def _record(env_cls, config) -> GraspStates:
    t0 = time.perf_counter()
    env = env_cls(config, physics="c")
    n = int(config.n_grasp_states)
    tries = n + max(8, n // 4)
    keys = jax.random.split(jax.random.PRNGKey(GRASP_SEED), tries)
    qpos, qvel, mocap, held = _play(env, keys)
    step = _settled_step(held)
    check = FingerContacts(env.mj_model, env.rules.object_body)
    kept = []
    for b in np.flatnonzero(step >= 0):
        t = step[b]
        if check.holds(qpos[t, b], qvel[t, b], mocap[t, b]):
            kept.append((t, b))
        if len(kept) == n:
            break
    if len(kept) < n:
        raise GraspRecordError(
            f"grasp_start_fraction: only {len(kept)} of {tries} scripted grasps of task "
            f"{env.task_name!r} held the object with both grippers; n_grasp_states={n} are "
            f"needed. Lower n_grasp_states, or check the task's settings (object placement, "
            f"finger_stroke, max_delta).")
    t_idx, b_idx = np.asarray(kept).T
    return GraspStates(qpos=np.asarray(qpos[t_idx, b_idx], np.float32),
                       qvel=np.asarray(qvel[t_idx, b_idx], np.float32),
                       mocap=np.asarray(mocap[t_idx, b_idx], np.float32), tries=tries,
                       seconds=time.perf_counter() - t0)
