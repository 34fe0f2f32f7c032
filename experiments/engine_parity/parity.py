"""Where MJX and MuJoCo's C engine part on grasps: one measurement per candidate cause.

For a task and a *candidate* (a change of the scene, the solver options or of how one engine is
stepped), `measure` builds the task on both engines with that change and reports:

- **divergence**: the scripted controller's actions of the first `SHORT_STEPS` control steps,
  taken closed loop on the unchanged C engine (as ``tests/test_env_contact.py`` does), replayed
  open loop on both changed engines; the object deviation is the largest absolute difference of
  the observation's ``object_pos`` / ``object_rel_pos`` components over those steps (the test's
  measure). ``div_test_mm`` is taken over the test's two episodes (keys of
  ``PRNGKey(TEST_KEY)``), ``div_mean_mm`` is the mean over all episodes of each episode's
  largest object-point distance (Euclidean), ``div_max_mm`` the largest one;
- **scripted success**: the task's scripted controller (`mjx_envs.tasks.scripted`) closed loop
  on each engine over the same fixed episodes (same reset keys), success at the last step, and
  the mean final goal distance.

Both engines start every episode from the same state: the reset runs on the C engine and the
MJX env starts from its ``qpos``/``qvel``/targets (``mjx.Data`` with a zero warmstart; the first
``mjx.step`` computes everything else), so each MJX variant compiles one program only (the
batched policy + step) instead of two (compile time: docs/MJX_VS_C.md).

Ways of stepping the C engine (`C_MODES`): ``rollout`` is the backend as it is
(`mjx_envs.physics.backends.CBackend`: ``mujoco.rollout`` per control step, which zeroes the
solver warmstart; state kept in float32 between control steps). The others use
`StatefulCBackend` (measurement only): one persistent ``MjData`` per env stepped with
``mj_step``, optionally carrying the warmstart and/or the float64 state across control steps.
MJX (`MJX_MODES`): ``step`` is the backend as it is (``mjx.Data`` carries ``qacc_warmstart``);
``zero_ws`` zeroes the warmstart at every control step, as the C backend does.

``candidate("a+b")`` combines candidates (edits in order, engine modes); the candidates and
model edits are defined in `experiments.engine_parity.candidates`. `forward_gap` is the
force-level view: one forward pass at the C engine's grasped states on both engines (finger
contacts, object acceleration difference), which isolates collision and solver from the
closed loop.

Results are rows of plain dicts (`measure`); `main` (``python -m experiments.engine_parity.parity``
or ``python experiments/engine_parity/parity.py``) runs candidates
and writes them to a JSON store and a Markdown table (docs/MJX_VS_C.md).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import mjx_envs
from mjx_envs import model as model_lib
from mjx_envs import observation as obs_lib
from mjx_envs import registry
from mjx_envs.physics import backends
from mjx_envs.tasks import scripted

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

# C_MODES, MJX_MODES, _pairs_with: used through this module by tests and the hold scripts
from experiments.engine_parity.candidates import (  # noqa: E402, F401
    C_MODES,
    CANDIDATES,
    MJX_MODES,
    Candidate,
    _finger_geoms,
    _pairs_with,
    candidate,
)

TASKS = tuple(registry.OBJECTS)   # the tasks with an object
SHORT_STEPS = 10
"""open-loop control steps of the divergence measure (tests/test_env_contact.py: T_SHORT)"""
TEST_KEY, TEST_EPISODES = 7, 2
"""the parity test's episodes: jax.random.split(PRNGKey(7), 2)"""
EPISODE_SEED = 2024
"""seed of the other fixed episodes (keys split from PRNGKey(EPISODE_SEED))"""
_LAY = obs_lib.obs_layout()


# -- backends for the measurement ---------------------------------------------------------------

class StatefulCBackend(backends.CBackend):
    """C engine with one persistent ``MjData`` per env of the batch, stepped with ``mj_step``
    (measurement only: sequential, not for training).

    An env continues from its own float64 ``MjData`` when the float32 state it is handed equals
    that ``MjData`` rounded (i.e. it is the state this backend returned last); otherwise (a
    reset) it starts from the given state with a zero warmstart. ``round_f32``: start every
    control step from the float32 state instead (as `CBackend`); ``warmstart``: keep
    ``qacc_warmstart`` across control steps (else zero it, as ``mujoco.rollout`` does)."""

    def __init__(self, model, n_substeps, warmstart: bool, round_f32: bool):
        super().__init__(model, n_substeps, nthread=1)
        self.warmstart, self.round_f32 = bool(warmstart), bool(round_f32)
        self._env_data: list[mujoco.MjData] = []

    def _host_step(self, time_, qpos, qvel, act, ctrl, mocap_pos, params=None):
        m = self.mj_model
        lead = qpos.shape[:-1]
        n = int(np.prod(lead)) if lead else 1
        t32 = np.asarray(time_, np.float32).reshape(n)
        q32 = np.asarray(qpos, np.float32).reshape(n, self.nq)
        v32 = np.asarray(qvel, np.float32).reshape(n, self.nv)
        a32 = np.asarray(act, np.float32).reshape(n, self.na)
        ctrl = np.asarray(ctrl, np.float64).reshape(n, self.nu)
        mocap = np.asarray(mocap_pos, np.float64).reshape(n, self.nmocap, 3)
        while len(self._env_data) < n:
            self._env_data.append(mujoco.MjData(m))
        out_t = np.empty(n, np.float32)
        out_q = np.empty((n, self.nq), np.float32)
        out_v = np.empty((n, self.nv), np.float32)
        out_a = np.empty((n, self.na), np.float32)
        out_s = np.empty((n, self.ns), np.float32)
        for b in range(n):
            d = self._env_data[b]
            same = (np.float32(d.time) == t32[b] and np.array_equal(d.qpos.astype(np.float32),
                                                                   q32[b])
                    and np.array_equal(d.qvel.astype(np.float32), v32[b]))
            if not same or self.round_f32:
                ws = d.qacc_warmstart.copy() if (same and self.warmstart) else None
                mujoco.mj_resetData(m, d)
                d.time = float(t32[b])
                d.qpos[:] = q32[b]
                d.qvel[:] = v32[b]
                if self.na:
                    d.act[:] = a32[b]
                if ws is not None:
                    d.qacc_warmstart[:] = ws
            elif not self.warmstart:
                d.qacc_warmstart[:] = 0.0
            d.ctrl[:] = ctrl[b]
            d.mocap_pos[:] = mocap[b]
            for _ in range(self.n_substeps):
                mujoco.mj_step(m, d)
            out_t[b], out_q[b], out_v[b] = d.time, d.qpos, d.qvel
            if self.na:
                out_a[b] = d.act
            out_s[b] = d.sensordata
        ok = np.ones(n, np.float32)
        return (out_t.reshape(lead), out_q.reshape(lead + (self.nq,)),
                out_v.reshape(lead + (self.nv,)), out_a.reshape(lead + (self.na,)),
                out_s.reshape(lead + (self.ns,)), ok.reshape(lead))


class ZeroWarmstartMjxBackend(backends.MjxBackend):
    """MJX with the solver warmstart zeroed at the start of every control step (the C
    backend's ``rollout`` semantics)."""

    def step(self, data, ctrl, mocap_pos, params=None):
        data = data.replace(qacc_warmstart=jnp.zeros_like(data.qacc_warmstart))
        return super().step(data, ctrl, mocap_pos, params)


def make_env(task: str, engine: str, cand: Candidate):
    """The task's env on ``engine`` with the candidate's change (test episodes' settings)."""
    env = mjx_envs.make(task, physics=engine)
    edit = cand.edit if engine in cand.edit_engines else None
    mode = cand.c_mode if engine == "c" else cand.mjx_mode
    if edit is None and mode in ("rollout", "step"):
        return env
    m = copy.copy(env.mj_model)
    if edit is not None:
        edit(m)
    n = env.config.n_substeps
    if engine == "c":
        opts = C_MODES[mode]
        env.backend = (backends.CBackend(m, n) if opts is None
                       else StatefulCBackend(m, n, **opts))
    else:
        env.backend = (ZeroWarmstartMjxBackend(m, n) if mode == "zero_ws"
                       else backends.MjxBackend(m, n))
    env.mj_model = m
    return env


# -- runs ---------------------------------------------------------------------------------------

def episode_keys(n: int) -> jax.Array:
    """The fixed episodes: the parity test's two, then ``n - 2`` from `EPISODE_SEED`."""
    test = jax.random.split(jax.random.PRNGKey(TEST_KEY), TEST_EPISODES)
    if n <= TEST_EPISODES:
        return test[:n]
    return jnp.concatenate([test, jax.random.split(jax.random.PRNGKey(EPISODE_SEED),
                                                   n - TEST_EPISODES)])


class Runner:
    """One env: a jitted episode (``lax.scan`` of the batched step over the episode; each step
    takes the scripted controller's action or a given one), reset on the C engine. One program
    per env and batch size (the same executable serves every call)."""

    def __init__(self, env, c_env):
        self.env, self.c_env = env, c_env
        self.traces = 0
        policy = scripted.get_policy(env.task_name)

        def episode(s, actions, use):  # actions [T, B, 8], use [T]
            self.traces += 1

            def body(s, x):
                given, u = x
                a = jnp.where(u, given, policy(s.obs, env.config.max_delta))
                s = jax.vmap(env.step)(s, a)
                b = env.backend
                phys = {"qpos": b.qpos(s.data), "qvel": s.data.qvel, "mocap": b.mocap_pos(s.data)}
                return s, (s.obs, a, phys)

            s, (obs, acts, phys) = jax.lax.scan(body, s, (actions, use))
            return obs, acts, phys, s

        self.episode = jax.jit(episode)
        self._reset_c = jax.jit(jax.vmap(c_env.reset))

    def reset(self, keys):
        s = self._reset_c(keys)
        if self.env.physics == "c":
            return s
        d0 = self.env.backend._data0
        n = keys.shape[0]
        data = jax.tree.map(lambda x: jnp.broadcast_to(jnp.asarray(x), (n,) + np.shape(x)), d0)
        data = data.replace(qpos=s.data.qpos, qvel=s.data.qvel, mocap_pos=s.data.mocap_pos)
        return s.replace(data=data)

    def run(self, keys, actions=None, full=False):
        """A whole episode: (observations [T, B, 2, obs], actions [T, B, 8], final state); the
        first ``len(actions)`` steps take ``actions`` [t, B, 8], the others the controller's.
        ``full``: (observation dicts, actions, physics (qpos, qvel, mocap) [T, B, ...], final
        state) instead."""
        T, n = self.env.episode_length, keys.shape[0]
        given = np.zeros((T, n, self.env.action_size), np.float32)
        use = np.zeros(T, bool)
        if actions is not None:
            given[:len(actions)] = actions
            use[:len(actions)] = True
        obs, acts, phys, s = self.episode(self.reset(keys), jnp.asarray(given),
                                          jnp.asarray(use))
        obs, acts, phys = jax.tree.map(np.asarray, (obs, acts, phys))
        if full:
            return obs, acts, phys, s
        return obs["observation"], acts, s


def _object_deviation(c_obs, m_obs) -> dict:
    """Deviation of the object between two observation sequences [T, B, 2, obs]."""
    comps = []
    for name in ("object_pos", "object_rel_pos"):
        a, b = _LAY[name]
        comps.append(np.abs(c_obs[..., a:b] - m_obs[..., a:b]).max(axis=(0, 2, 3)))  # [B]
    per_env_comp = np.maximum(*comps)
    a, b = _LAY["object_pos"]
    dist = np.linalg.norm(c_obs[..., a:b] - m_obs[..., a:b], axis=-1).max(axis=(0, 2))  # [B]
    return {"div_test_mm": 1e3 * float(per_env_comp[:TEST_EPISODES].max()),
            "div_mean_mm": 1e3 * float(dist.mean()),
            "div_max_mm": 1e3 * float(dist.max())}


def _engine_run(task, engine, cand, keys, actions, base, base_c, cache_dir, log):
    """(short-horizon observations [T, B, 2, obs], stats) of one engine side, from the cache
    when an equal side was measured before."""
    side = cand.side(engine)
    path = None
    if cache_dir is not None:
        tag = side.replace("/", "__")
        path = os.path.join(cache_dir, f"{task}_{engine}_{tag}_{keys.shape[0]}.npz")
        if os.path.exists(path):
            z = np.load(path)
            stats = json.loads(str(z["stats"]))
            log(f"{task} {cand.name} {engine}: side {side} from {path}")
            return z["short"], dict(stats, cached=True)
    t0 = time.time()
    env = make_env(task, engine, cand)
    unchanged = engine == "c" and side == "none/rollout"
    r = base if unchanged else Runner(env, base_c)
    short = r.run(keys, actions)[0][:SHORT_STEPS]
    _, _, s = r.run(keys)
    succ = np.asarray(s.metrics["success"])
    stats = {"success": float(succ.mean()), "successes": int(succ.sum()),
             "goal_distance": float(np.asarray(s.metrics["goal_distance"]).mean()),
             "physics_ok": float(np.asarray(s.metrics["physics_ok"]).mean()),
             "success_per_episode": succ.astype(int).tolist(),
             "seconds": round(time.time() - t0, 1), "traces": r.traces, "side": side}
    if path is not None:
        os.makedirs(cache_dir, exist_ok=True)
        np.savez(path, short=short, stats=json.dumps(stats))
    return short, stats


def measure(task: str, cand: Candidate, episodes: int = 32, engines=("c", "mjx"),
            cache_dir: str | None = None, log=print) -> dict:
    """One candidate on one task: divergence and scripted success per engine (see the module
    doc). Returns a dict with per-engine entries ``c`` / ``mjx`` (success, successes,
    goal_distance, physics_ok, seconds, traces, side) and the divergence entries. With
    ``cache_dir``, each engine side's result is stored there and reused by any candidate with
    the same side (e.g. the C-only candidates reuse the baseline's MJX run)."""
    base_c = mjx_envs.make(task, physics="c")
    base = Runner(base_c, base_c)
    keys = episode_keys(episodes)
    actions = base.run(keys)[1][:SHORT_STEPS]  # closed loop on the unchanged C engine
    out = {"task": task, "candidate": cand.name, "doc": cand.doc, "episodes": episodes}
    short = {}
    for engine in engines:
        short[engine], out[engine] = _engine_run(task, engine, cand, keys, actions, base,
                                                 base_c, cache_dir, log)
        st = out[engine]
        log(f"{task} {cand.name} {engine}: success {st['success']:.3f} "
            f"({st['successes']}/{episodes}), goal distance {st['goal_distance'] * 100:.1f} cm, "
            f"{st['seconds']} s")
    if len(engines) == 2:
        out.update(_object_deviation(short["c"], short["mjx"]))
        log(f"{task} {cand.name}: divergence {out['div_test_mm']:.1f} mm (test episodes), "
            f"mean {out['div_mean_mm']:.1f} mm, max {out['div_max_mm']:.1f} mm")
    return out


# -- one forward pass at identical states (collision functions, solver) -----------------------

def grasp_states(task: str, episodes: int = 8, seed: int = 0, **overrides) -> dict:
    """States of the scripted controller's episodes on the unchanged C engine (the env's config
    `overrides`) where both grippers hold the object (`scripted.holding`): qpos, qvel, and the
    targets and finger servo targets of the next control step, float32 [N, ...]."""
    env = mjx_envs.make(task, physics="c", **overrides)
    obs, acts, phys, _ = Runner(env, env).run(jax.random.split(jax.random.PRNGKey(seed),
                                                               episodes), full=True)
    hold = np.asarray(scripted.holding(jax.tree.map(jnp.asarray, obs))).all(-1)[:-1]
    ctrl = np.asarray(jax.vmap(env._finger_ctrl)(acts.reshape(-1, 2, 4)[..., 3]))
    ctrl = ctrl.reshape(acts.shape[:2] + (-1,))
    out = {"qpos": phys["qpos"][:-1][hold], "qvel": phys["qvel"][:-1][hold],
           "mocap": phys["mocap"][1:][hold], "ctrl": ctrl[1:][hold]}
    return {k: v.astype(np.float32) for k, v in out.items()}


def _object_dofs(m: mujoco.MjModel, task: str) -> slice:
    j = m.joint(registry.OBJECTS[task][0]).id
    a = int(m.jnt_dofadr[j])
    return slice(a, a + 6)


def forward_gap(task: str, cand: Candidate, states: dict, chunk: int = 32) -> dict:
    """One forward pass (zero warmstart) at each of ``states`` on both engines with the
    candidate's model edit: finger contacts per state on each engine (C: ``ncon`` of
    ``mj_forward``; MJX: contacts with ``dist < includemargin``), and the difference of the
    object's linear (m/s^2) and angular (rad/s^2) acceleration (mean and 95th percentile)."""
    env_c = make_env(task, "c", cand)
    m_c = env_c.mj_model
    mjx_cand = cand if "mjx" in cand.edit_engines else dataclasses.replace(cand, edit=None)
    m_m = copy.copy(mjx_envs.make(task, physics="c").mj_model)
    if mjx_cand.edit is not None:
        mjx_cand.edit(m_m)
    dofs = _object_dofs(m_c, task)
    fingers = _finger_geoms(m_c)
    n = states["qpos"].shape[0]
    acc_c = np.empty((n, 6))
    con_c = np.empty(n)
    d = mujoco.MjData(m_c)
    for i in range(n):
        mujoco.mj_resetData(m_c, d)
        d.qpos[:], d.qvel[:] = states["qpos"][i], states["qvel"][i]
        d.mocap_pos[:2] = states["mocap"][i]
        d.ctrl[:] = states["ctrl"][i]
        mujoco.mj_forward(m_c, d)
        acc_c[i] = d.qacc[dofs]
        g = np.stack([d.contact.geom1[:d.ncon], d.contact.geom2[:d.ncon]], -1)
        con_c[i] = np.isin(g, fingers).any(-1).sum()
    mjx = backends.import_mjx()
    mm = mjx.put_model(model_lib.mjx_model(m_m))
    d0 = mjx.make_data(mm)

    @jax.jit
    def fwd(qpos, qvel, mocap, ctrl):
        def one(q, v, mc, c):
            dd = d0.replace(qpos=q, qvel=v, mocap_pos=d0.mocap_pos.at[:2].set(mc), ctrl=c)
            dd = mjx.forward(mm, dd)
            con = dd._impl.contact
            act = con.dist < con.includemargin
            fing = jnp.isin(con.geom, jnp.asarray(fingers)).any(-1)
            return dd.qacc[dofs], jnp.sum(act & fing)
        return jax.vmap(one)(qpos, qvel, mocap, ctrl)

    acc_m, con_m = [], []
    t0 = time.time()
    for a in range(0, n, chunk):
        sl = slice(a, a + chunk)
        args = [states[k][sl] for k in ("qpos", "qvel", "mocap", "ctrl")]
        pad = chunk - args[0].shape[0]
        args = [np.concatenate([x, np.repeat(x[-1:], pad, 0)]) if pad else x for x in args]
        am, cm = jax.device_get(fwd(*args))
        acc_m.append(am[:chunk - pad])
        con_m.append(cm[:chunk - pad])
    acc_m, con_m = np.concatenate(acc_m), np.concatenate(con_m)
    dl = np.linalg.norm(acc_c[:, :3] - acc_m[:, :3], axis=-1)
    da = np.linalg.norm(acc_c[:, 3:] - acc_m[:, 3:], axis=-1)
    return {"task": task, "candidate": cand.name, "states": int(n),
            "finger_contacts_c": float(con_c.mean()), "finger_contacts_mjx": float(con_m.mean()),
            "dacc_lin_mean": float(dl.mean()), "dacc_lin_p95": float(np.percentile(dl, 95)),
            "dacc_ang_mean": float(da.mean()), "dacc_ang_p95": float(np.percentile(da, 95)),
            "acc_lin_c_mean": float(np.linalg.norm(acc_c[:, :3], axis=-1).mean()),
            "seconds": round(time.time() - t0, 1)}


# -- store, table, command line ---------------------------------------------------------------

def load_store(path: str) -> list[dict]:
    if path and os.path.exists(path):
        with open(path) as f:
            return json.load(f)["rows"]
    return []


def save_store(path: str, rows: list[dict]) -> None:
    """Rows keyed by (task, candidate, episodes): a new row replaces an old one."""
    old = {(r["task"], r["candidate"], r["episodes"]): r for r in load_store(path)}
    for r in rows:
        old[(r["task"], r["candidate"], r["episodes"])] = r
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as f:
        json.dump({"rows": list(old.values())}, f, indent=1)


def forward_store(store: str) -> str:
    """Where ``--forward`` rows go: ``forward.json`` beside the store."""
    return os.path.join(os.path.dirname(os.path.abspath(store)), "forward.json")


def format_table(rows: list[dict], tasks=TASKS) -> str:
    """Markdown: one line per candidate; per task the divergence (test episodes / mean over
    all episodes, mm) and the scripted success on C and on MJX."""
    by = {(r["task"], r["candidate"]): r for r in rows}
    names = list(dict.fromkeys(r["candidate"] for r in rows))
    order = list(CANDIDATES)
    names.sort(key=lambda n: (n.count("+"), [order.index(p) if p in order else 99
                                             for p in n.split("+")]))
    tasks = [t for t in tasks if any(r["task"] == t for r in rows)]
    head = "| candidate | " + " | ".join(
        f"{t}: divergence mm (test / mean) | {t}: success C / MJX" for t in tasks) + " |"
    lines = [head, "|---" * (1 + 2 * len(tasks)) + "|"]
    for n in names:
        cells = [n]
        for t in tasks:
            r = by.get((t, n))
            if r is None:
                cells += ["", ""]
                continue
            div = (f"{r['div_test_mm']:.0f} / {r['div_mean_mm']:.0f}" if "div_test_mm" in r
                   else "")
            succ = " / ".join(f"{r[e]['success']:.2f}" if e in r else "-" for e in ("c", "mjx"))
            cells += [div, succ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_forward_table(rows: list[dict]) -> str:
    """Markdown of `forward_gap` rows: one line per (task, candidate)."""
    lines = ["| task | candidate | grasped states | finger contacts C / MJX | object acc. "
             "difference m/s^2 (mean / p95) | angular rad/s^2 (mean / p95) |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['task']} | {r['candidate']} | {r['states']} | "
                     f"{r['finger_contacts_c']:.1f} / {r['finger_contacts_mjx']:.1f} | "
                     f"{r['dacc_lin_mean']:.2f} / {r['dacc_lin_p95']:.2f} | "
                     f"{r['dacc_ang_mean']:.1f} / {r['dacc_ang_p95']:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description="Measure, per candidate cause of the MJX/C disagreement, the short-horizon "
                    "object divergence and the scripted controller's success on both engines "
                    "(experiments/engine_parity/parity.py).")
    p.add_argument("--tasks", default="pickup,pot", help="comma list of " + ",".join(TASKS))
    p.add_argument("--candidates", default="",
                   help="comma list of: " + ",".join(CANDIDATES) + " (a+b combines two)")
    p.add_argument("--episodes", type=int, default=32,
                   help="fixed episodes per task (the MJX batch; keep <= 32 on a CPU)")
    p.add_argument("--engines", default="c,mjx", help="c,mjx (both: divergence too), c or mjx")
    p.add_argument("--store", default="", help="JSON file the rows are merged into "
                   "(--forward rows: forward.json beside it)")
    p.add_argument("--cache", default="", help="folder of per-engine results reused by "
                   "candidates that change one engine only")
    p.add_argument("--forward", action="store_true",
                   help="instead: one forward pass at the scripted controller's grasped states "
                        "on both engines (finger contacts, object acceleration difference)")
    p.add_argument("--table", action="store_true", help="print the store's Markdown table "
                   "(after measuring, if candidates are given)")
    args = p.parse_args(argv)
    tasks = [t for t in args.tasks.split(",") if t]
    cands = [c for c in args.candidates.split(",") if c]
    engines = tuple(e for e in args.engines.split(",") if e)
    bad = ([t for t in tasks if t not in TASKS] + [e for e in engines if e not in ("c", "mjx")]
           + [p for c in cands for p in c.split("+") if p not in CANDIDATES])
    if bad:
        p.error(f"unknown task, candidate or engine: {', '.join(bad)}")
    if not cands and not args.table:
        p.error("give --candidates (and/or --table)")
    if not 1 <= args.episodes <= 256:
        p.error("--episodes must be in [1, 256]")
    # MJX programs have no host callbacks: JAX's persistent cache lets a rerun skip the compile
    jax.config.update("jax_compilation_cache_dir", os.environ.get(
        "DADDPG_JAX_CACHE", os.path.expanduser("~/.cache/daddpg_jax_jit")))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    rows = []
    if args.forward:
        for task in tasks:
            states = grasp_states(task)
            for name in cands:
                row = forward_gap(task, candidate(name), states)
                print(json.dumps(row))
                rows.append(row)
        if args.store:
            path = forward_store(args.store)
            keep = {(r["task"], r["candidate"]): r for r in load_store(path) + rows}
            with open(path, "w") as f:
                json.dump({"rows": list(keep.values())}, f, indent=1)
        return 0
    for task in tasks:
        for name in cands:
            rows.append(measure(task, candidate(name), args.episodes, engines,
                                args.cache or None))
            if args.store:
                save_store(args.store, rows)
    if args.table:
        print(format_table(load_store(args.store) if args.store else rows))
        if args.store and os.path.exists(forward_store(args.store)):
            print()
            print(format_forward_table(load_store(forward_store(args.store))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
