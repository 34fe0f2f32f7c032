"""Physics backends: the one seam between the env core and a physics engine.

Both backends expose the same four pure functions, written for ONE env and batched with
``jax.vmap`` by the caller:

- ``init(qpos, qvel, mocap_pos, params=None) -> data``: a physics state with
  positions/velocities set and derived quantities (sensors) computed;
- ``step(data, ctrl, mocap_pos, params=None) -> data``: ``n_substeps`` physics steps holding
  ``ctrl`` (finger servo targets) and ``mocap_pos`` (the Cartesian targets of the two grippers)
  fixed;
- ``sensordata(data) -> [nsensordata]`` float32;
- ``mocap_pos(data) -> [nmocap, 3]``.

``params``: one env's physics randomization vector (`mjx_envs.randomize`), given when the
backend was built with a ``randomize.ModelIndex``; None = the nominal model.

``mjx``: MuJoCo MJX, ``mjx.Data`` stepped by ``mjx.step`` (the engine on accelerators); with
randomization the model fields of `randomize.model_fields` are replaced inside the (vmapped)
step, so every env steps its own ``mjx.Model``.
``c``: MuJoCo's C engine. ``step`` is a ``jax.pure_callback`` (``vmap_method="broadcast_all"``)
into ``mujoco.rollout`` over the whole batch at once (multi-threaded, persistent pool); with
randomization each env of the batch has its own ``MjModel`` copy, whose fields are rewritten
(on the host, `randomize.model_fields` over NumPy) only for the envs whose parameters changed,
i.e. after their reset.

Facts the C backend handles (mujoco 4.0.0):
- ``rollout`` resets mocap to the model default and zeroes the warmstart at every call, and its
  full-physics state holds neither: the mocap targets are passed as controls for every substep
  (``control_spec = CTRL | MOCAP_POS``) and kept in ``CData``.
- ``rollout`` silently freezes an env after an engine warning (its time stops advancing): the
  backend compares the returned time with the expected one and raises ``CData.ok`` to 0.0, which
  the env reports as ``metrics["physics_ok"]``.

``mjx`` does the same where its state becomes non-finite (MJX has no engine warnings): the env
stays at its last finite state for the rest of the episode, and ``physics_ok`` is 0.0.
"""

from __future__ import annotations

import atexit
import contextlib
import copy
import io
import logging
import os
import re
import sys
import threading

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from mujoco import rollout

from mjx_envs import randomize, settings
from mjx_envs.model import mjx_model
from mjx_envs.physics import mjx_contacts, mjx_solver


def default_physics() -> str:
    """``mjx`` when JAX sees an accelerator, else ``c``."""
    return "mjx" if jax.default_backend() in ("gpu", "cuda", "rocm", "tpu") else "c"


def default_chunk(physics: str, backend: str | None = None) -> int | None:
    """Episodes per batch when none is given: `mjx_envs.settings.MJX_CPU_CHUNK` for MJX on a
    CPU, else None (all episodes in one batch)."""
    backend = backend or jax.default_backend()
    return settings.MJX_CPU_CHUNK if physics == "mjx" and backend == "cpu" else None


# --------------------------------------------------------------------------------- MJX -----


_WARP_NOISE = re.compile(r"^Failed to import (mujoco_)?warp\b")


def import_mjx():
    """``mujoco.mjx`` with `mjx_contacts.install` and `mjx_solver.install` applied (scenes of
    physics version 3 get each box-box contact point once; version 4's, a finite line search),
    imported without the "Failed to import warp" / "Failed to import
    mujoco_warp" lines that mujoco 4.0's MJX prints when the optional Warp backend is not
    installed (it is not used here). Only those lines are held back (logged at debug level);
    anything else printed during the import passes through."""
    if "mujoco.mjx" in sys.modules:
        mjx_contacts.install()
        mjx_solver.install()
        return sys.modules["mujoco.mjx"]
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf):
            # lazy: MJX loads only when an MJX backend is built, under this stdout filter
            from mujoco import mjx
    finally:
        for line in buf.getvalue().splitlines():
            if _WARP_NOISE.match(line):
                logging.getLogger(__name__).debug("%s", line)
            else:
                print(line)
    mjx_contacts.install()
    mjx_solver.install()
    return mjx


class MjxBackend:
    name = "mjx"

    def __init__(self, model: mujoco.MjModel, n_substeps: int,
                 rand: randomize.ModelIndex | None = None):
        mjx = import_mjx()
        self._mjx = mjx
        self.mj_model = model
        self.n_substeps = int(n_substeps)
        self.model = mjx.put_model(mjx_model(model))   # MJX's own solver options (version 6)
        self._data0 = mjx.make_data(self.model)
        self.rand = rand

    def _model(self, params):
        """The nominal model, or this env's randomized one."""
        if params is None or self.rand is None:
            return self.model
        return self.model.replace(**randomize.model_fields(jnp, self.rand, params))

    def init(self, qpos, qvel, mocap_pos, params=None):
        model = self._model(params)
        d = self._data0.replace(qpos=qpos, qvel=qvel, mocap_pos=mocap_pos)
        if params is not None and self.rand is not None and self.rand.r.moves_base:
            quat = d.mocap_quat.at[self.rand.target_mocap].set(
                model.body_quat[self.rand.targets])
            d = d.replace(mocap_quat=quat)
        return self._mjx.forward(model, d)

    def step(self, data, ctrl, mocap_pos, params=None):
        d = data.replace(ctrl=ctrl, mocap_pos=mocap_pos)
        model = self._model(params)

        def body(_, d):
            return self._mjx.step(model, d)

        new = jax.lax.fori_loop(0, self.n_substeps, body, d)
        # An env whose state became non-finite is frozen at its last finite state for the rest
        # of the episode, as the C engine freezes an env after an engine warning, so that no
        # NaN reaches observations, rewards or a replay buffer. Its time becomes NaN: the
        # sticky mark that `ok` reads (the C backend's time stops instead).
        bad = ~_finite_state(new) | ~jnp.isfinite(data.time)
        frozen = d.replace(time=jnp.full_like(d.time, jnp.nan))
        return jax.tree.map(lambda f, n: jnp.where(bad, f, n), frozen, new)

    @staticmethod
    def sensordata(data):
        return data.sensordata.astype(jnp.float32)

    @staticmethod
    def mocap_pos(data):
        return data.mocap_pos

    @staticmethod
    def qpos(data):
        return data.qpos

    @staticmethod
    def ok(data):
        """1.0 while the env has not been frozen (`step`), else 0.0."""
        return (_finite_state(data) & jnp.isfinite(data.time)).astype(jnp.float32)


def _finite_state(data):
    return jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel))


# ------------------------------------------------------------------------------- C engine --

_POOLS: dict = {}  # nthread -> mujoco.rollout.Rollout shared by every C backend of the process
_POOL_LOCK = threading.Lock()


def _rollout_pool(nthread: int):
    if nthread not in _POOLS:
        pool = rollout.Rollout(nthread=nthread)
        atexit.register(pool.close)
        _POOLS[nthread] = pool
    return _POOLS[nthread]



@struct.dataclass
class CData:
    """Physics state of one env for the C backend (float32 mirror of MuJoCo's full state)."""

    time: jax.Array  # []
    qpos: jax.Array  # [nq]
    qvel: jax.Array  # [nv]
    act: jax.Array  # [na]
    mocap_pos: jax.Array  # [nmocap, 3]
    sensordata: jax.Array  # [nsensordata]
    ok: jax.Array  # [] 1.0 while the engine has not frozen this env


def _state_offsets(model: mujoco.MjModel) -> dict[str, tuple[int, int]]:
    """Offsets of the components inside a ``mjSTATE_FULLPHYSICS`` state vector."""
    spec = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
    out, i, bit = {}, 0, 1
    while bit <= spec:
        if spec & bit:
            n = mujoco.mj_stateSize(model, bit)
            out[mujoco.mjtState(bit).name] = (i, n)
            i += n
        bit <<= 1
    assert i == mujoco.mj_stateSize(model, spec)
    return out


class CBackend:
    name = "c"

    def __init__(self, model: mujoco.MjModel, n_substeps: int, nthread: int | None = None,
                 rand: randomize.ModelIndex | None = None):
        self.mj_model = model
        self.n_substeps = int(n_substeps)
        self.nthread = int(nthread or max(1, os.cpu_count() or 1))
        self._datas = [mujoco.MjData(model) for _ in range(self.nthread)]
        self._fwd_data = mujoco.MjData(model)
        self._lock = threading.Lock()
        self.nq, self.nv, self.na = model.nq, model.nv, model.na
        self.nmocap, self.nu, self.ns = model.nmocap, model.nu, model.nsensordata
        self.nstate = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        self._off = _state_offsets(model)
        self._ctrl_spec = int(mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_MOCAP_POS)
        self._dt = float(model.opt.timestep)
        # Fast path of _host_step: our own persistent pool called with skip_checks (no shape
        # inference, tiling or output allocation inside rollout) on inputs we lay out here.
        self._models: list = []
        i, k = self._off["mjSTATE_QPOS"]
        self._sl_qpos = slice(i, i + k)
        i, k = self._off["mjSTATE_QVEL"]
        self._sl_qvel = slice(i, i + k)
        i, k = self._off["mjSTATE_ACT"]
        self._sl_act = slice(i, i + k)
        self._i_time = self._off["mjSTATE_TIME"][0]
        self.rand = rand
        # randomized parameters per env (0: no randomization)
        self.n_rand_params = randomize.PARAMS if rand is not None else 0
        self._env_models: dict = {}  # batch size -> (per-env MjModel copies, their params)

    def models_for(self, params) -> list:
        """Per-env ``MjModel`` copies holding the randomized fields of ``params`` [n, PARAMS]
        (one list per batch size, rewritten only where an env's parameters changed)."""
        params = np.asarray(params, np.float32).reshape(-1, randomize.PARAMS)
        n = params.shape[0]
        if n not in self._env_models:
            models = [copy.copy(self.mj_model) for _ in range(n)]
            self._env_models[n] = (models, np.tile(randomize.nominal_params(), (n, 1)))
        models, applied = self._env_models[n]
        for i in np.flatnonzero(np.any(params != applied, axis=1)):
            for name, value in randomize.model_fields(np, self.rand, params[i]).items():
                getattr(models[i], name)[...] = value
            applied[i] = params[i]
        return models

    # -- host functions (NumPy, run inside pure_callback) -------------------------------------

    def _host_forward(self, qpos, qvel, mocap_pos, params=None):
        lead = qpos.shape[:-1]
        qpos = np.asarray(qpos, np.float64).reshape(-1, self.nq)
        qvel = np.asarray(qvel, np.float64).reshape(-1, self.nv)
        mocap = np.asarray(mocap_pos, np.float64).reshape(-1, self.nmocap, 3)
        out = np.empty((qpos.shape[0], self.ns), np.float32)
        d = self._fwd_data
        with self._lock:
            models = ([self.mj_model] * qpos.shape[0] if params is None
                      else self.models_for(params))
            for b in range(qpos.shape[0]):
                m = models[b]
                mujoco.mj_resetData(m, d)
                d.qpos[:] = qpos[b]
                d.qvel[:] = qvel[b]
                d.mocap_pos[:] = mocap[b]
                mujoco.mj_forward(m, d)
                out[b] = d.sensordata
        return out.reshape(lead + (self.ns,))

    def _run_rollout(self, state, control, n, models=None):
        """``rollout`` of n envs for n_substeps from full-physics states ``state`` [n, nstate]
        under ``control`` [n, n_substeps, nu + 3 nmocap]; returns (states, sensordata) of every
        substep. Our own persistent pool with skip_checks: the inputs are laid out by the caller
        exactly as rollout expects (C-contiguous float64), outputs preallocated here."""
        if models is None:
            if len(self._models) != n:
                self._models = [self.mj_model] * n
            models = self._models
        st = np.empty((n, self.n_substeps, self.nstate), np.float64)
        sens = np.empty((n, self.n_substeps, self.ns), np.float64)
        with _POOL_LOCK:
            pool = _rollout_pool(len(self._datas) if len(self._datas) > 1 else 0)
            pool.rollout(models, self._datas, state, control, control_spec=self._ctrl_spec,
                         skip_checks=True, nstep=self.n_substeps, state=st, sensordata=sens)
        return st, sens

    def _host_step(self, time, qpos, qvel, act, ctrl, mocap_pos, params=None):
        lead = qpos.shape[:-1]
        n = int(np.prod(lead)) if lead else 1
        time = np.asarray(time, np.float64).reshape(n)
        # full-physics state: time, qpos, qvel, act (other components have size 0 here; any
        # that did not would stay zero)
        state = np.zeros((n, self.nstate), np.float64)
        state[:, self._i_time] = time
        state[:, self._sl_qpos] = np.asarray(qpos).reshape(n, self.nq)
        state[:, self._sl_qvel] = np.asarray(qvel).reshape(n, self.nv)
        if self.na:
            state[:, self._sl_act] = np.asarray(act).reshape(n, self.na)
        # the same control (finger targets, mocap targets) for every substep, written in place
        control = np.empty((n, self.n_substeps, self.nu + 3 * self.nmocap), np.float64)
        control[:, :, : self.nu] = np.asarray(ctrl).reshape(n, 1, self.nu)
        control[:, :, self.nu:] = np.asarray(mocap_pos).reshape(n, 1, 3 * self.nmocap)
        with self._lock:
            models = None if params is None else self.models_for(params)
            st, sens = self._run_rollout(state, control, n, models)
        last = st[:, -1]
        new_time = last[:, self._i_time]
        expected = time + self.n_substeps * self._dt
        ok = (np.abs(new_time - expected) < 0.5 * self._dt).astype(np.float32)
        f32 = lambda a, k: a.astype(np.float32).reshape(lead + (k,))  # noqa: E731
        return (new_time.astype(np.float32).reshape(lead),
                f32(last[:, self._sl_qpos], self.nq),
                f32(last[:, self._sl_qvel], self.nv),
                f32(last[:, self._sl_act], self.na),
                f32(sens[:, -1], self.ns),
                ok.reshape(lead))

    # -- traced functions (one env) -----------------------------------------------------------

    def init(self, qpos, qvel, mocap_pos, params=None):
        qpos = jnp.asarray(qpos, jnp.float32)
        qvel = jnp.asarray(qvel, jnp.float32)
        mocap_pos = jnp.asarray(mocap_pos, jnp.float32)
        args = (qpos, qvel, mocap_pos)
        if params is not None and self.rand is not None:
            args += (jnp.asarray(params, jnp.float32),)
        sens = jax.pure_callback(
            self._host_forward, jax.ShapeDtypeStruct((self.ns,), jnp.float32),
            *args, vmap_method="broadcast_all")
        return CData(time=jnp.zeros((), jnp.float32), qpos=qpos, qvel=qvel,
                     act=jnp.zeros((self.na,), jnp.float32), mocap_pos=mocap_pos,
                     sensordata=sens, ok=jnp.ones((), jnp.float32))

    def _host_step_packed(self, x):
        """_host_step on one packed float32 array [..., 1 + nq + nv + na + nu + 3 nmocap]
        (time, qpos, qvel, act, ctrl, mocap) -> [..., 1 + nq + nv + na + ns + 1] (time, qpos,
        qvel, act, sensordata, ok): one argument and one result per callback instead of six of
        each, fewer transfers per call (measured: docs/BENCHMARKS.md, "Profiling pass (CPU)")."""
        x = np.asarray(x)
        lead = x.shape[:-1]
        parts = np.split(x, np.cumsum([1, self.nq, self.nv, self.na, self.nu,
                                       3 * self.nmocap]), axis=-1)
        time, qpos, qvel, act, ctrl, mocap, params = parts
        out = self._host_step(time[..., 0], qpos, qvel, act, ctrl,
                              mocap.reshape(lead + (self.nmocap, 3)),
                              params if self.n_rand_params else None)
        t, q, v, a, sens, ok = out
        return np.concatenate([t[..., None], q, v, a, sens, ok[..., None]], axis=-1)

    def step(self, data: CData, ctrl, mocap_pos, params=None):
        ctrl = jnp.asarray(ctrl, jnp.float32)
        mocap_pos = jnp.asarray(mocap_pos, jnp.float32)
        parts = [data.time[None], data.qpos, data.qvel, data.act, ctrl, mocap_pos.reshape(-1)]
        if self.n_rand_params:
            if params is None:
                raise ValueError("this backend was built with randomization: step needs params")
            parts.append(jnp.asarray(params, jnp.float32).reshape(-1))
        x = jnp.concatenate(parts)
        n_out = 1 + self.nq + self.nv + self.na + self.ns + 1
        y = jax.pure_callback(self._host_step_packed, jax.ShapeDtypeStruct((n_out,), jnp.float32),
                              x, vmap_method="broadcast_all")
        time, qpos, qvel, act, sens, ok = jnp.split(
            y, np.cumsum([1, self.nq, self.nv, self.na, self.ns]))
        return CData(time=time[0], qpos=qpos, qvel=qvel, act=act, mocap_pos=mocap_pos,
                     sensordata=sens, ok=data.ok * ok[0])

    @staticmethod
    def sensordata(data: CData):
        return data.sensordata

    @staticmethod
    def mocap_pos(data: CData):
        return data.mocap_pos

    @staticmethod
    def qpos(data: CData):
        return data.qpos

    @staticmethod
    def ok(data: CData):
        return data.ok


def make_backend(physics: str, model: mujoco.MjModel, n_substeps: int,
                 rand: randomize.ModelIndex | None = None):
    """The backend; ``rand``: where the physics randomization acts (None: nominal physics)."""
    if physics == "auto":
        physics = default_physics()
    if physics == "mjx":
        return MjxBackend(model, n_substeps, rand=rand)
    if physics == "c":
        return CBackend(model, n_substeps, rand=rand)
    raise ValueError(f"unknown physics {physics!r}: choose 'auto', 'mjx' or 'c'")
