"""Forward pass on both engines at identical loaded states: the C engine's hold-test trajectory
(bar pulled by L x weight) sampled every 4 control steps; bar linear acceleration and the grasp
contacts' total friction force per engine."""
import os, sys, json, time
import jax, jax.numpy as jnp, mujoco, numpy as np
import mjx_envs
from mjx_envs import registry, settings
from mjx_envs.physics import backends
from daddpg_jax.analysis import engine_parity as ep
TASK = sys.argv[1]; L = float(sys.argv[2]); OUT = sys.argv[3]
env = mjx_envs.make(TASK, physics="c"); m = env.mj_model; n_sub = env.config.n_substeps
for k, v in [a.split("=") for a in sys.argv[4:]]:
    if k == "cone": m.opt.cone = int(v)
    elif k == "iters": m.opt.iterations = int(v); m.opt.ls_iterations = int(v); m.opt.tolerance = 1e-12
st = ep.grasp_states(TASK); idx = np.linspace(0, st["qpos"].shape[0]-1, 32).astype(int)
st = {k: v[idx] for k, v in st.items()}
body = m.body(registry.OBJECTS[TASK][1]).id
f = np.zeros((m.nbody, 6)); f[body, 2] = -L * float(m.body_subtreemass[body]) * 9.81
dofs = ep._object_dofs(m, TASK)
S = {"qpos": [], "qvel": [], "mocap": [], "ctrl": []}; acc_c = []; cnt_c = []
PG = {(int(m.pair_geom1[i]), int(m.pair_geom2[i])) for i in range(m.npair) if m.pair_friction[i][0] > 1.0}
PGA = jnp.asarray(sorted(PG))
d = mujoco.MjData(m)
for i in range(32):
    mujoco.mj_resetData(m, d)
    d.qpos[:], d.qvel[:] = st["qpos"][i], st["qvel"][i]; d.mocap_pos[:2] = st["mocap"][i]; d.ctrl[:] = st["ctrl"][i]; d.xfrc_applied[:] = f
    mujoco.mj_forward(m, d)
    for t in range(16 * n_sub):
        if t % (4 * n_sub) == 0:
            dd = mujoco.MjData(m); dd.qpos[:], dd.qvel[:] = d.qpos, d.qvel; dd.mocap_pos[:] = d.mocap_pos; dd.ctrl[:] = d.ctrl; dd.xfrc_applied[:] = f
            mujoco.mj_forward(m, dd)
            S["qpos"].append(d.qpos.copy()); S["qvel"].append(d.qvel.copy()); S["mocap"].append(d.mocap_pos[:2].copy()); S["ctrl"].append(d.ctrl.copy())
            acc_c.append(dd.qacc[dofs].copy())
            g = np.stack([dd.contact.geom1[:dd.ncon], dd.contact.geom2[:dd.ncon]], -1)
            cnt_c.append(int(sum((int(a), int(b)) in PG for a, b in g)))
        mujoco.mj_step(m, d)
S = {k: np.asarray(v, np.float32) for k, v in S.items()}; acc_c = np.asarray(acc_c)
mjx = backends.import_mjx(); mm = mjx.put_model(m); d0 = mjx.make_data(mm)
fj = jnp.asarray(f, jnp.float32)
@jax.jit
def fwd(q, v, mc, c):
    def one(q, v, mc, c):
        dd = d0.replace(qpos=q, qvel=v, mocap_pos=d0.mocap_pos.at[:2].set(mc), ctrl=c, xfrc_applied=fj)
        dd = mjx.forward(mm, dd); con = dd._impl.contact
        isg = (con.geom[:, None, :] == PGA[None]).all(-1).any(-1)
        return dd.qacc[dofs], jnp.sum(isg & (con.dist < con.includemargin))
    return jax.vmap(one)(q, v, mc, c)
acc_m = []; cnt_m = []
for a in range(0, len(acc_c), 32):
    am, cm = fwd(*[S[k][a:a+32] for k in ("qpos", "qvel", "mocap", "ctrl")])
    acc_m.append(np.asarray(am)); cnt_m.append(np.asarray(cm))
acc_m = np.concatenate(acc_m); cnt_m = np.concatenate(cnt_m); cnt_c = np.asarray(cnt_c)
t = np.arange(len(acc_c)) % 4  # sample index within the episode: 0, 4, 8, 12 control steps
out = {}
for s in range(4):
    sel = t == s
    out[str(4 * s)] = dict(az_c=float(acc_c[sel, 2].mean()), az_mjx=float(acc_m[sel, 2].mean()),
                           dlin=float(np.linalg.norm(acc_c[sel, :3] - acc_m[sel, :3], axis=-1).mean()),
                           grasp_points_c=float(cnt_c[sel].mean()), grasp_points_mjx=float(cnt_m[sel].mean()),
                           states_c_fewer=float((cnt_c[sel] < cnt_m[sel]).mean()))
    print(TASK, L, sys.argv[4:], "step", 4 * s, out[str(4 * s)], flush=True)
json.dump(out, open(OUT, "w"), indent=1)
