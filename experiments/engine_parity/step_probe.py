"""One control step from the very same state on both engines: a trained policy plays MJX closed
loop; at every control step, MJX's state before the step (qpos, qvel, act, warm start) and the
ctrl/mocap it applied are set into the C engine's data, the C engine takes the same control
step, and the object's position and velocity after it are compared with MJX's. Per control
step: the median and largest one-step difference; for the worst states, each engine's contacts.
A one-step difference that stays at rounding size while whole episodes part (open_loop.py) means
the engines amplify small differences; a large one at some step means they resolve that
step's contacts differently.

    python experiments/engine_parity/step_probe.py RUN --episodes 32 --seed 9090 [--steps 12] \
        [--json OUT.json] [--no-warmstart] [--c-edit cold|converged|cg] [--physics-version N]

Run it alone on a CPU (MJX, one chunk of at most 32)."""

from __future__ import annotations

import argparse
import copy
import json
import sys

import jax
import mujoco
import numpy as np

from daddpg_jax.algo import acting
from daddpg_jax.analysis import evaluation


def _record(s, a, s2):
    d, d2 = s.data, s2.data
    c = d2.contact
    return dict(qpos=d.qpos, qvel=d.qvel, act=d.act, warm=d.qacc_warmstart, time=d.time,
                ctrl=d2.ctrl, mocap=d2.mocap_pos, qpos2=d2.qpos, qvel2=d2.qvel,
                cdist=c.dist, cgeom=c.geom, cpos=c.pos, cframe=c.frame[..., 0, :])


C_EDITS = {
    "cold": dict(disableflags=int(mujoco.mjtDisableBit.mjDSBL_WARMSTART)),
    "converged": dict(tolerance=0.0, iterations=100, ls_iterations=50),
    "cg": dict(solver=int(mujoco.mjtSolver.mjSOL_CG), iterations=100),
}
"""C engine solver options tried against a Newton solve that stops early: no warm start, a
solve run to its iteration limit, and the conjugate-gradient solver"""


def _edit(m: mujoco.MjModel, edit: str | None) -> mujoco.MjModel:
    m = copy.copy(m)
    for k, v in C_EDITS.get(edit, {}).items():
        setattr(m.opt, k, getattr(m.opt, k) | v if k == "disableflags" else v)
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
    p.add_argument("--c-edit", choices=sorted(C_EDITS), default=None,
                   help="the C engine's solver options changed as named (C_EDITS)")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
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
    worst = sorted(rows, key=lambda x: -x["dvel_mm_s"])[:a.worst]
    for x in worst:
        print(f"t={x['t']} ep={x['episode']} dpos {x['dpos_mm']:.3f} mm dvel "
              f"{x['dvel_mm_s']:.1f} mm/s dang {x['dang_rad_s']:.3f} rad/s")
        print("  C:  ", x["c_contacts"])
        print("  MJX:", x["mjx_contacts"])
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(dict(run=a.run, step=a.step, seed=a.seed, warmstart=not a.no_warmstart,
                           c_edit=a.c_edit, physics_version=a.physics_version,
                           per_step=per_step, rows=rows), fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
