import sys, json
import jax, jax.numpy as jnp, mujoco, numpy as np
import mjx_envs
from mjx_envs import registry, settings
from mjx_envs.physics import backends
from daddpg_jax.analysis import engine_parity as ep
np.set_printoptions(precision=4, suppress=True, linewidth=160)
TASK = "pickup"; L = 6.0
env = mjx_envs.make(TASK, physics="c"); m = env.mj_model; n_sub = env.config.n_substeps
st = ep.grasp_states(TASK); idx = np.linspace(0, st["qpos"].shape[0]-1, 32).astype(int)
st = {k: v[idx] for k, v in st.items()}
body = m.body(registry.OBJECTS[TASK][1]).id
f = np.zeros((m.nbody, 6)); f[body, 2] = -L * float(m.body_subtreemass[body]) * 9.81
dofs = ep._object_dofs(m, TASK)
mjx = backends.import_mjx(); mm = mjx.put_model(m); d0 = mjx.make_data(mm)
fwd = jax.jit(lambda dd: mjx.forward(mm, dd))
best = None
d = mujoco.MjData(m)
for i in range(8):
    mujoco.mj_resetData(m, d)
    d.qpos[:], d.qvel[:] = st["qpos"][i], st["qvel"][i]; d.mocap_pos[:2] = st["mocap"][i]; d.ctrl[:] = st["ctrl"][i]; d.xfrc_applied[:] = f
    mujoco.mj_forward(m, d)
    for t in range(8 * n_sub): mujoco.mj_step(m, d)
    dc = mujoco.MjData(m); dc.qpos[:], dc.qvel[:] = d.qpos, d.qvel; dc.mocap_pos[:] = d.mocap_pos; dc.ctrl[:] = d.ctrl; dc.xfrc_applied[:] = f
    mujoco.mj_forward(m, dc)
    dm = fwd(d0.replace(qpos=jnp.asarray(d.qpos, jnp.float32), qvel=jnp.asarray(d.qvel, jnp.float32), mocap_pos=jnp.asarray(d.mocap_pos, jnp.float32), ctrl=jnp.asarray(d.ctrl, jnp.float32), xfrc_applied=jnp.asarray(f, jnp.float32)))
    diff = np.linalg.norm(dc.qacc[dofs][:3] - np.asarray(dm.qacc[dofs][:3]))
    if best is None or diff > best[0]:
        best = (diff, i, dc, dm)
diff, i, dc, dm = best
print("state", i, "dlin", diff, "qacc obj C", dc.qacc[dofs], "MJX", np.asarray(dm.qacc[dofs]))
print("C efc types", np.bincount(dc.efc_type, minlength=8), "nefc", dc.nefc)
imp = dm._impl
et = np.asarray(imp.efc_type); print("MJX efc types", np.bincount(et, minlength=8), len(et))
# contact forces per grasp contact
grasp = [i for i in range(m.npair) if m.pair_friction[i][0] > 1.0]
pg = {(int(m.pair_geom1[i]), int(m.pair_geom2[i])) for i in grasp}
print("C contacts:")
for k in range(dc.ncon):
    c = dc.contact[k]
    if (c.geom1, c.geom2) in pg:
        a = c.efc_address
        print("  pos", c.pos, "d %.4f" % c.dist, "force", dc.efc_force[a:a+c.dim], "R", dc.efc_R[a:a+c.dim], "aref", dc.efc_aref[a:a+c.dim], "D", dc.efc_D[a:a+c.dim])
print("MJX contacts:")
con = imp.contact
G = np.asarray(con.geom); D = np.asarray(con.dist); EA = np.asarray(con.efc_address); DIM = np.asarray(con.dim)
F = np.asarray(imp.efc_force); Dd = np.asarray(imp.efc_D); AR = np.asarray(imp.efc_aref)
for k in range(len(D)):
    if tuple(G[k]) in pg and D[k] < 0:
        a = EA[k]
        print("  pos", np.asarray(con.pos[k]), "d %.4f" % D[k], "force", F[a:a+DIM[k]], "aref", AR[a:a+DIM[k]], "D", Dd[a:a+DIM[k]])
print("C other constraints (type, force):", [(int(t), round(float(x), 3)) for t, x in zip(dc.efc_type, dc.efc_force) if t < 3][:20])
print("MJX other:", [(int(t), round(float(x), 3)) for t, x in zip(et, F) if t < 3][:20])
