"""Forward pass on both engines at identical loaded states: the C engine's hold-test trajectory
(object pulled down by LOAD x its weight; hold.py) sampled every 4 control steps over 16; the
object's linear acceleration and the grasp contact points per engine at each sample step.

    python experiments/engine_parity/loaded_forward.py TASK LOAD OUT.json [cone=N] [iters=N] \
        [pads=KIND]

pads=KIND: the grasp pairs of pads.py's kind KIND (e.g. meshf, meshneck; both engines).

Recorded at git 71b10df (physics version 3 as shipped):
docs/results/engines/unique_points/lf_pickup6.json, lf_pickup6_it100.json (iters=100).
"""

from __future__ import annotations

import json
import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

import mjx_envs  # noqa: E402
from experiments.engine_parity import parity as ep  # noqa: E402
from experiments.engine_parity import probe_tools as pt  # noqa: E402
from mjx_envs import model as model_lib  # noqa: E402
from mjx_envs.physics import backends  # noqa: E402

N, EVERY, STEPS = 32, 4, 16   # states; sample every EVERY of STEPS control steps


def c_trajectory(m, st, f, n_sub, dofs, pg):
    """The sampled states, the object's acceleration and the grasp contact points per grasp pair
    (`pg`, sorted) there (C)."""
    samples = {k: [] for k in pt.STATE_KEYS}
    acc, count = [], []
    d = mujoco.MjData(m)
    for i in range(N):
        pt.set_c_state(m, d, st, i, f)
        for t in range(STEPS * n_sub):
            if t % (EVERY * n_sub) == 0:
                dd = mujoco.MjData(m)
                dd.qpos[:], dd.qvel[:], dd.mocap_pos[:] = d.qpos, d.qvel, d.mocap_pos
                dd.ctrl[:], dd.xfrc_applied[:] = d.ctrl, f
                mujoco.mj_forward(m, dd)
                for k, v in zip(pt.STATE_KEYS, (d.qpos, d.qvel, d.mocap_pos[:2], d.ctrl)):
                    samples[k].append(v.copy())
                acc.append(dd.qacc[dofs].copy())
                g = [(int(a), int(b)) for a, b in zip(dd.contact.geom1[:dd.ncon],
                                                      dd.contact.geom2[:dd.ncon])]
                # an engine may swap a pair's geoms by their types
                count.append([sum(c in (p, p[::-1]) for c in g) for p in sorted(pg)])
            mujoco.mj_step(m, d)
    return ({k: np.asarray(v, np.float32) for k, v in samples.items()}, np.asarray(acc),
            np.asarray(count))


def mjx_forward(m, samples, f, dofs, pg):
    mjx = backends.import_mjx()
    mm = mjx.put_model(model_lib.mjx_model(m))
    d0 = mjx.make_data(mm)
    pga, fj = jnp.asarray(sorted(pg)), jnp.asarray(f, jnp.float32)

    @jax.jit
    def fwd(q, v, mc, c):
        def one(q, v, mc, c):
            dd = mjx.forward(mm, pt.mjx_state(d0, q, v, mc, c, fj))
            con = dd._impl.contact
            isg = ((con.geom[:, None, :] == pga[None]).all(-1)
                   | (con.geom[:, None, ::-1] == pga[None]).all(-1))   # [contacts, pairs]
            return dd.qacc[dofs], jnp.sum(isg & (con.dist < con.includemargin)[:, None], 0)
        return jax.vmap(one)(q, v, mc, c)

    acc, count = [], []
    for a in range(0, len(samples["qpos"]), 32):
        am, cm = fwd(*[samples[k][a:a + 32] for k in pt.STATE_KEYS])
        acc.append(np.asarray(am))
        count.append(np.asarray(cm))
    return np.concatenate(acc), np.concatenate(count)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 3:
        print(__doc__)
        return 2
    task, load, out_path = argv[0], float(argv[1]), argv[2]
    env = mjx_envs.make(task, physics="c")
    m, n_sub = env.mj_model, env.config.n_substeps
    for k, v in (a.split("=") for a in argv[3:]):
        if k == "pads":
            from experiments.engine_parity import pads
            m = pads.like(v, f"scene_{task}.xml", m)   # MJX routes *_mjxbox's meshes itself
        elif k == "cone":
            m.opt.cone = int(v)
        elif k == "iters":
            m.opt.iterations = m.opt.ls_iterations = int(v)
            m.opt.tolerance = 1e-12
    st = pt.sample_states(task, N)
    _, f = pt.down_force(m, task, load)
    dofs = ep._object_dofs(m, task)
    pg = {(int(m.pair_geom1[i]), int(m.pair_geom2[i])) for i in range(m.npair)
          if m.pair_friction[i][0] > 1.0}
    samples, acc_c, cnt_c = c_trajectory(m, st, f, n_sub, dofs, pg)
    acc_m, cnt_m = mjx_forward(m, samples, f, dofs, pg)
    t = np.arange(len(acc_c)) % (STEPS // EVERY)   # the sample's index within its episode
    out = {}
    pairs = (cnt_c, cnt_m)
    cnt_c, cnt_m = cnt_c.sum(-1), cnt_m.sum(-1)
    for s in range(STEPS // EVERY):
        sel = t == s
        pc, pm = pairs[0][sel].ravel(), pairs[1][sel].ravel()
        touch = (pc > 0) | (pm > 0)
        out[str(EVERY * s)] = dict(
            az_c=float(acc_c[sel, 2].mean()), az_mjx=float(acc_m[sel, 2].mean()),
            dlin=float(np.linalg.norm(acc_c[sel, :3] - acc_m[sel, :3], axis=-1).mean()),
            grasp_points_c=float(cnt_c[sel].mean()), grasp_points_mjx=float(cnt_m[sel].mean()),
            states_c_fewer=float((cnt_c[sel] < cnt_m[sel]).mean()),
            states_c_more=float((cnt_c[sel] > cnt_m[sel]).mean()),
            pairs_same_points=float((pc == pm)[touch].mean()),   # of the pairs touching
            pairs_c_m={f"{a},{b}": int(((pc == a) & (pm == b) & touch).sum())
                       for a, b in sorted(set(zip(pc[touch].tolist(), pm[touch].tolist())))})
        print(task, load, argv[3:], "step", EVERY * s, out[str(EVERY * s)], flush=True)
    with open(out_path, "w") as fh:
        json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
