"""At the loaded state where the engines' object accelerations differ most (pick-up, 6 x the
bar's weight, after 8 control steps of the C engine's hold trajectory; 8 grasped states), each
grasp contact's position, depth, force, aref and D on both engines, and the other constraints.

    python experiments/engine_parity/efc_compare.py

Recorded at git 71b10df (docs/results/engines/unique_points/README.md); prints only.
"""

from __future__ import annotations

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

TASK, LOAD, STATES, STEPS = "pickup", 6.0, 8, 8


def widest_state(m, st, f, n_sub, dofs):
    """(difference, state, C data, MJX data) of the state with the largest |d acc_lin|."""
    mjx = backends.import_mjx()
    mm = mjx.put_model(model_lib.mjx_model(m))
    d0 = mjx.make_data(mm)
    fwd = jax.jit(lambda dd: mjx.forward(mm, dd))
    best, d = None, mujoco.MjData(m)
    for i in range(STATES):
        pt.set_c_state(m, d, st, i, f)
        for _ in range(STEPS * n_sub):
            mujoco.mj_step(m, d)
        dc = mujoco.MjData(m)
        dc.qpos[:], dc.qvel[:], dc.mocap_pos[:] = d.qpos, d.qvel, d.mocap_pos
        dc.ctrl[:], dc.xfrc_applied[:] = d.ctrl, f
        mujoco.mj_forward(m, dc)
        as32 = lambda x: jnp.asarray(x, jnp.float32)
        dm = fwd(d0.replace(qpos=as32(d.qpos), qvel=as32(d.qvel), mocap_pos=as32(d.mocap_pos),
                            ctrl=as32(d.ctrl), xfrc_applied=as32(f)))
        diff = np.linalg.norm(dc.qacc[dofs][:3] - np.asarray(dm.qacc[dofs][:3]))
        if best is None or diff > best[0]:
            best = (diff, i, dc, dm)
    return best


def main() -> int:
    np.set_printoptions(precision=4, suppress=True, linewidth=160)
    env = mjx_envs.make(TASK, physics="c")
    m, n_sub = env.mj_model, env.config.n_substeps
    st = pt.sample_states(TASK, 32)
    _, f = pt.down_force(m, TASK, LOAD)
    dofs = ep._object_dofs(m, TASK)
    diff, i, dc, dm = widest_state(m, st, f, n_sub, dofs)
    print("state", i, "dlin", diff, "qacc obj C", dc.qacc[dofs], "MJX", np.asarray(dm.qacc[dofs]))
    print("C efc types", np.bincount(dc.efc_type, minlength=8), "nefc", dc.nefc)
    imp = dm._impl
    et = np.asarray(imp.efc_type)
    print("MJX efc types", np.bincount(et, minlength=8), len(et))
    pg = {(int(m.pair_geom1[i]), int(m.pair_geom2[i])) for i in range(m.npair)
          if m.pair_friction[i][0] > 1.0}
    print("C contacts:")
    for k in range(dc.ncon):
        c = dc.contact[k]
        if (c.geom1, c.geom2) in pg:
            s = slice(c.efc_address, c.efc_address + c.dim)
            print("  pos", c.pos, f"d {c.dist:.4f}", "force", dc.efc_force[s], "R", dc.efc_R[s],
                  "aref", dc.efc_aref[s], "D", dc.efc_D[s])
    print("MJX contacts:")
    con = imp.contact
    geom, dist, ea, dim = (np.asarray(x) for x in (con.geom, con.dist, con.efc_address, con.dim))
    force, efc_d, aref = (np.asarray(x) for x in (imp.efc_force, imp.efc_D, imp.efc_aref))
    for k in range(len(dist)):
        if tuple(geom[k]) in pg and dist[k] < 0:
            s = slice(ea[k], ea[k] + dim[k])
            print("  pos", np.asarray(con.pos[k]), f"d {dist[k]:.4f}", "force", force[s], "aref",
                  aref[s], "D", efc_d[s])
    print("C other constraints (type, force):",
          [(int(t), round(float(x), 3)) for t, x in zip(dc.efc_type, dc.efc_force) if t < 3][:20])
    print("MJX other:", [(int(t), round(float(x), 3)) for t, x in zip(et, force) if t < 3][:20])
    return 0


if __name__ == "__main__":
    sys.exit(main())
