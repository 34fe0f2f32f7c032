"""One control step from the very same state on both engines: a trained policy plays MJX closed
loop; at every control step, MJX's state before the step (qpos, qvel, act, warm start) and the
ctrl/mocap it applied are set into the C engine's data, the C engine takes the same control
step, and the object's position and velocity after it are compared with MJX's. Per control
step: the median and largest one-step difference; for the worst states, each engine's contacts
after the step; per contact pair, how often the engines' point counts differ at the very same
positions (every state before a control step).
A one-step difference that stays at rounding size while whole episodes part (open_loop.py) means
the engines amplify small differences; a large one at some step means they resolve that
step's contacts differently.

    python experiments/engine_parity/step_probe.py RUN --episodes 32 --seed 9090 [--steps 12] \
        [--json OUT.json] [--no-warmstart] [--c-edit CANDIDATE] [--physics-version N] \
        [--pads KIND] [--save-states OUT.npz]

``--save-states``: the worst states (MJX's state before the step, its ctrl/mocap, and its
object after the step) to an .npz, the record a test replays (tests/data/c_newton_stop_*.npz).

Run it alone on a CPU (MJX, one chunk of at most 32)."""

from __future__ import annotations

import argparse
import copy
import json
import os
import sys
from collections import Counter

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import jax  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from daddpg_jax.algo import acting  # noqa: E402
from daddpg_jax.analysis import evaluation  # noqa: E402
from experiments.engine_parity import eval_probe, pads  # noqa: E402


def _record(s, a, s2):
    d, d2 = s.data, s2.data
    c = d2.contact
    return dict(qpos=d.qpos, qvel=d.qvel, act=d.act, warm=d.qacc_warmstart, time=d.time,
                ctrl=d2.ctrl, mocap=d2.mocap_pos, qpos2=d2.qpos, qvel2=d2.qvel,
                cdist=c.dist, cgeom=c.geom, cpos=c.pos, cframe=c.frame[..., 0, :])


def _edit(m: mujoco.MjModel, edit: str | None) -> mujoco.MjModel:
    """A copy of ``m`` with eval_probe.py's candidate ``edit`` (None: unchanged)."""
    m = copy.copy(m)
    if edit is not None:
        eval_probe.CANDIDATES[edit](m)
    return m


def _free_object(m: mujoco.MjModel) -> tuple[int, int]:
    """(qpos address, dof address) of the scene's free joint (the object)."""
    free = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    if len(free) != 1:
        raise SystemExit(f"expected one free joint, found {len(free)}")
    return int(m.jnt_qposadr[free[0]]), int(m.jnt_dofadr[free[0]])


def _c_step(m, d, rec, t, i, n_sub, warm: bool):
    mujoco.mj_resetData(m, d)
    d.qpos[:] = rec["qpos"][t, i]
    d.qvel[:] = rec["qvel"][t, i]
    if m.na:
        d.act[:] = rec["act"][t, i]
    if warm:
        d.qacc_warmstart[:] = rec["warm"][t, i]
    d.ctrl[:] = rec["ctrl"][t, i]
    d.mocap_pos[:] = rec["mocap"][t, i]
    contacts = None
    for k in range(n_sub):
        mujoco.mj_step(m, d)
        if k == n_sub - 1:
            contacts = [(m.geom(int(c.geom1)).name, m.geom(int(c.geom2)).name,
                         round(float(c.dist) * 1e3, 2)) for c in d.contact[:d.ncon]]
    return d.qpos.copy(), d.qvel.copy(), contacts


def _mjx_contacts(m, rec, t, i):
    dist = rec["cdist"][t, i]
    return [(m.geom(int(g[0])).name, m.geom(int(g[1])).name, round(float(x) * 1e3, 2))
            for x, g in zip(dist, rec["cgeom"][t, i]) if x < 0]


def pair_counts(env, m, rec) -> dict:
    """Per contact pair, over every recorded state before a control step (MJX's, set into both
    engines: the same positions): the states where either engine has a contact, those where the
    engines' point counts differ, and the mean count on each."""
    be = env.backend                      # the MJX backend of the run's env
    mjx = be._mjx

    def forward(q):
        c = mjx.forward(be.model, be._data0.replace(qpos=q))._impl.contact
        return c.dist, c.geom

    q = rec["qpos"].reshape((-1,) + rec["qpos"].shape[2:]).astype(np.float32)
    dist, geom = (np.asarray(x) for x in jax.jit(jax.vmap(forward))(q))
    d = mujoco.MjData(m)
    name = lambda g: m.geom(int(g)).name  # noqa: E731
    table: dict = {}
    for k in range(len(q)):
        d.qpos[:] = q[k]
        mujoco.mj_forward(m, d)
        c_n, c_d = Counter(), Counter()
        for c in d.contact[:d.ncon]:
            if c.dist < 0:
                c_n[name(c.geom1), name(c.geom2)] += 1
                c_d[name(c.geom1), name(c.geom2)] -= 1e3 * float(c.dist)
        m_n, m_d = Counter(), Counter()
        for x, g in zip(dist[k], geom[k]):
            if x < 0:
                m_n[name(g[0]), name(g[1])] += 1
                m_d[name(g[0]), name(g[1])] -= 1e3 * float(x)
        for pair in set(c_n) | set(m_n):
            row = table.setdefault("-".join(pair), dict(states=0, differ=0, c=0, mjx=0,
                                                        c_depth=0.0, mjx_depth=0.0,
                                                        c_deepest=0.0, mjx_deepest=0.0))
            row["states"] += 1
            row["differ"] += c_n[pair] != m_n[pair]
            row["c"] += c_n[pair]
            row["mjx"] += m_n[pair]
            row["c_depth"] += c_d[pair]
            row["mjx_depth"] += m_d[pair]
            row["c_deepest"] = max(row["c_deepest"], c_d[pair] / max(c_n[pair], 1))
            row["mjx_deepest"] = max(row["mjx_deepest"], m_d[pair] / max(m_n[pair], 1))
    for row in table.values():
        for k in ("c", "mjx", "c_depth", "mjx_depth"):
            row[k] = round(row[k] / row["states"], 2)
    return dict(sorted(table.items(), key=lambda kv: -kv[1]["differ"]))


def compact(rows: list, worst: list) -> list:
    """``rows`` with the contact lists kept only in the ``worst`` ones (the JSON's size)."""
    keep = {(r["t"], r["episode"]) for r in worst}
    return [r if (r["t"], r["episode"]) in keep
            else {k: v for k, v in r.items() if not k.endswith("_contacts")} for r in rows]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run")
    p.add_argument("--episodes", type=int, default=32)
    p.add_argument("--seed", type=int, default=9090)
    p.add_argument("--step", type=int, default=None)
    p.add_argument("--steps", type=int, default=12, help="control steps compared")
    p.add_argument("--worst", type=int, default=4, help="states whose contacts are listed")
    p.add_argument("--no-warmstart", action="store_true",
                   help="start the C engine's solver cold instead of from MJX's warm start")
    p.add_argument("--physics-version", type=int, default=None,
                   help="simulate this physics version instead of the run's")
    p.add_argument("--pads", default=None,
                   help="a pad kind of pads.py on both engines (probes only)")
    p.add_argument("--c-edit", choices=sorted(k for k, v in eval_probe.CANDIDATES.items() if v),
                   default=None, help="the C engine's model changed as eval_probe.py's candidate")
    p.add_argument("--json", default=None)
    p.add_argument("--save-states", default=None, help="the worst states to this .npz")
    a = p.parse_args(argv)
    if a.pads:
        pads.patch(a.pads)
    pol = evaluation.load_policy(a.run, step=a.step, best=a.step is None, physics="mjx",
                                 physics_version=a.physics_version)
    env, act = pol.env, pol.act
    keys = np.asarray(acting.episode_keys(jax.random.PRNGKey(a.seed), a.episodes))

    def actors(s, _):
        return act(pol.params, s.obs["observation"], s.obs["desired_goal"])

    fn = jax.jit(lambda k: acting.rollout(env, actors, k, length=a.steps, record=_record)[1])
    rec = {k: np.asarray(v, np.float64) for k, v in jax.device_get(fn(keys)).items()}
    m = _edit(env.mj_model, a.c_edit)
    d = mujoco.MjData(m)
    qa, va = _free_object(m)
    rows = []
    for t in range(a.steps):
        for i in range(a.episodes):
            q, v, cc = _c_step(m, d, rec, t, i, env.backend.n_substeps, not a.no_warmstart)
            dp = float(np.linalg.norm(q[qa:qa + 3] - rec["qpos2"][t, i, qa:qa + 3]))
            dv = float(np.linalg.norm(v[va:va + 3] - rec["qvel2"][t, i, va:va + 3]))
            dw = float(np.linalg.norm(v[va + 3:va + 6] - rec["qvel2"][t, i, va + 3:va + 6]))
            rows.append(dict(t=t, episode=i, dpos_mm=1e3 * dp, dvel_mm_s=1e3 * dv,
                             dang_rad_s=dw, c_contacts=cc,
                             mjx_contacts=_mjx_contacts(m, rec, t, i)))
    per_step = []
    for t in range(a.steps):
        r = [x for x in rows if x["t"] == t]
        dp = np.array([x["dpos_mm"] for x in r])
        dv = np.array([x["dvel_mm_s"] for x in r])
        per_step.append(dict(t=t, dpos_mm_median=float(np.median(dp)), dpos_mm_max=float(dp.max()),
                             dvel_mm_s_median=float(np.median(dv)),
                             dvel_mm_s_max=float(dv.max()),
                             touching=int(sum(bool(x["c_contacts"]) for x in r))))
        print(json.dumps(per_step[-1]), flush=True)
    counts = pair_counts(env, m, rec)
    print("contact points per pair at the same positions (states: either touches; differ: "
          "the counts differ; mean points C / MJX; mean summed depth of the penetrating "
          "points, mm):")
    for pair, row in counts.items():
        print(f"  {pair:32s} states {row['states']:4d} differ {row['differ']:4d} "
              f"C {row['c']:.2f} MJX {row['mjx']:.2f}; summed depth mm C {row['c_depth']:.2f} "
              f"MJX {row['mjx_depth']:.2f}")
    worst = sorted(rows, key=lambda x: -x["dvel_mm_s"])[:a.worst]
    for x in worst:
        print(f"t={x['t']} ep={x['episode']} dpos {x['dpos_mm']:.3f} mm dvel "
              f"{x['dvel_mm_s']:.1f} mm/s dang {x['dang_rad_s']:.3f} rad/s")
        print("  C:  ", x["c_contacts"])
        print("  MJX:", x["mjx_contacts"])
    if a.save_states:
        idx = [(x["t"], x["episode"]) for x in worst]
        np.savez_compressed(
            a.save_states, task=getattr(env, "task_name", ""),
            physics_version=int(env.config.physics_version), n_substeps=env.backend.n_substeps,
            t=np.array([t for t, _ in idx]), episode=np.array([i for _, i in idx]),
            dvel_mm_s=np.array([x["dvel_mm_s"] for x in worst]),
            qa=qa, va=va, warmstart=not a.no_warmstart,
            **{k: np.stack([rec[k][t, i] for t, i in idx])
               for k in ("qpos", "qvel", "act", "warm", "ctrl", "mocap", "qpos2", "qvel2")})
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(dict(run=a.run, step=a.step, seed=a.seed, warmstart=not a.no_warmstart,
                           c_edit=a.c_edit, physics_version=a.physics_version, pads=a.pads,
                           per_step=per_step, pair_counts=counts,
                           rows=compact(rows, worst)), fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
