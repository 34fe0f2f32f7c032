"""Each engine's contact points on the grasp pairs: one forward pass at 32 of the C engine's
grasped states of the scripted controller; per finger-grasp pair, the contact points, depths,
normals and normal forces on both engines (the first 6 states), and the count of (C points, MJX
points) per pair over all 32.

    UNIQ=1 python experiments/engine_parity/manifold.py [TASK]     # default pickup

UNIQ=1: MJX with the unique-points prototype (unique_points.py). docs/MJX_VS_C.md.
"""

from __future__ import annotations

import os
import sys
import time
from collections import Counter

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import jax  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

import mjx_envs  # noqa: E402
from experiments.engine_parity import probe_tools as pt  # noqa: E402
from mjx_envs import model as model_lib  # noqa: E402
from mjx_envs.physics import backends  # noqa: E402

N = 32


def c_contacts(m, st, pg) -> list:
    """Per state: (pair, depth, position, normal force, normal) of each grasp contact (C)."""
    d, out = mujoco.MjData(m), []
    for i in range(N):
        pt.set_c_state(m, d, st, i)
        rows = []
        for k in range(d.ncon):
            c = d.contact[k]
            key = (int(c.geom1), int(c.geom2))
            if key in pg or key[::-1] in pg:
                f = np.zeros(6)
                mujoco.mj_contactForce(m, d, k, f)
                rows.append((pg.get(key, pg.get(key[::-1])), float(c.dist), c.pos.copy(), f[0],
                             c.frame[:3].copy() * (1 if key in pg else -1)))
        out.append(rows)
    return out


def mjx_contacts(m, st, pg) -> list:
    """Per state: the same rows on MJX (contacts with dist < includemargin)."""
    mjx = backends.import_mjx()
    if os.environ.get("UNIQ"):
        from experiments.engine_parity import unique_points
        unique_points.install()
    mm = mjx.put_model(model_lib.mjx_model(m))
    d0 = mjx.make_data(mm)

    @jax.jit
    def fwd(q, v, mc, ct):
        def one(q, v, mc, ct):
            dd = mjx.forward(mm, pt.mjx_state(d0, q, v, mc, ct))
            con = dd._impl.contact
            efc = dd._impl.efc_force if hasattr(dd._impl, "efc_force") else dd.efc_force
            return con.geom, con.dist, con.pos, con.includemargin, con.frame, efc, con.efc_address
        return jax.vmap(one)(q, v, mc, ct)

    t = time.time()
    g, dist, pos, im, fr, ef, ea = jax.device_get(fwd(*[st[k] for k in pt.STATE_KEYS]))
    print("mjx", time.time() - t)
    out = []
    for i in range(N):
        rows = []
        for k in range(g.shape[1]):
            key = (int(g[i, k, 0]), int(g[i, k, 1]))
            if (key in pg or key[::-1] in pg) and dist[i, k] < im[i, k]:
                rows.append((pg.get(key, pg.get(key[::-1])), float(dist[i, k]), pos[i, k],
                             float(ef[i, ea[i, k]]), fr[i, k, 0] * (1 if key in pg else -1)))
        out.append(rows)
    return out


def _print_state(i, grasp_pairs, rows_c, rows_m):
    print(f"state {i}")
    for pi in grasp_pairs:
        cc, mc = [r for r in rows_c if r[0] == pi], [r for r in rows_m if r[0] == pi]
        if cc or mc:
            print(f"  pair {pi}: C {len(cc)} MJX {len(mc)}")
        for tag, rows in (("C", cc), ("M", mc)):
            for r in rows:
                print(f"     {tag}  d={r[1]:.4f} pos={np.round(r[2], 4)} fn={r[3]:.2f} "
                      f"n={np.round(r[4], 3)}")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    task = argv[0] if argv else "pickup"
    m = mjx_envs.make(task, physics="c").mj_model
    st = pt.sample_states(task, N, episodes=4)
    grasp_pairs = [i for i in range(m.npair) if m.pair_friction[i][0] > 1.0]
    pg = {(int(m.pair_geom1[i]), int(m.pair_geom2[i])): i for i in grasp_pairs}
    rows_c, rows_m = c_contacts(m, st, pg), mjx_contacts(m, st, pg)
    for i in range(6):
        _print_state(i, grasp_pairs, rows_c[i], rows_m[i])
    count = [sum(len(r) for r in rows) / N for rows in (rows_c, rows_m)]
    force = [sum(x[3] for r in rows for x in r) / N for rows in (rows_c, rows_m)]
    print(f"mean grasp contacts C {count[0]:.2f} MJX {count[1]:.2f}; mean total normal force "
          f"C {force[0]:.1f} MJX {force[1]:.1f}")
    cnt = Counter()
    for i in range(N):
        for pi in grasp_pairs:
            cnt[(sum(r[0] == pi for r in rows_c[i]), sum(r[0] == pi for r in rows_m[i]))] += 1
    print("(C points, MJX points) per grasp pair:", sorted(cnt.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
