import sys, time, json
import jax, jax.numpy as jnp, mujoco, numpy as np
import mjx_envs
from daddpg_jax.analysis import engine_parity as ep
from mjx_envs.physics import backends
TASK = sys.argv[1] if len(sys.argv) > 1 else "pickup"
env = mjx_envs.make(TASK, physics="c"); m = env.mj_model
st = ep.grasp_states(TASK, episodes=4)
n = st["qpos"].shape[0]; idx = np.linspace(0, n-1, 32).astype(int)
st = {k: v[idx] for k, v in st.items()}
grasp_pairs = [i for i in range(m.npair) if m.pair_friction[i][0] > 1.0]
pg = {(int(m.pair_geom1[i]), int(m.pair_geom2[i])): i for i in grasp_pairs}
d = mujoco.MjData(m)
C = []
for i in range(32):
    mujoco.mj_resetData(m, d)
    d.qpos[:], d.qvel[:] = st["qpos"][i], st["qvel"][i]; d.mocap_pos[:2] = st["mocap"][i]; d.ctrl[:] = st["ctrl"][i]
    mujoco.mj_forward(m, d)
    rows = []
    for k in range(d.ncon):
        c = d.contact[k]; key = (int(c.geom1), int(c.geom2))
        if key in pg or key[::-1] in pg:
            f = np.zeros(6); mujoco.mj_contactForce(m, d, k, f)
            rows.append((pg.get(key, pg.get(key[::-1])), float(c.dist), c.pos.copy(), f[0], c.frame[:3].copy()*(1 if key in pg else -1)))
    C.append(rows)
mjx = backends.import_mjx()
import os
if os.environ.get("UNIQ"):
    import uniq; uniq.install()
mm = mjx.put_model(m); d0 = mjx.make_data(mm)
@jax.jit
def fwd(q, v, mc, ct):
    def one(q, v, mc, ct):
        dd = d0.replace(qpos=q, qvel=v, mocap_pos=d0.mocap_pos.at[:2].set(mc), ctrl=ct)
        dd = mjx.forward(mm, dd)
        con = dd._impl.contact
        return con.geom, con.dist, con.pos, con.includemargin, con.frame, dd._impl.efc_force if hasattr(dd._impl,'efc_force') else dd.efc_force, con.efc_address
    return jax.vmap(one)(q, v, mc, ct)
t=time.time(); G, D, P, IM, FR, EF, EA = jax.device_get(fwd(st["qpos"], st["qvel"], st["mocap"], st["ctrl"])); print("mjx", time.time()-t)
tot_c=tot_m=0; fc=fm=0
for i in range(32):
    mrows = []
    for k in range(G.shape[1]):
        key = (int(G[i,k,0]), int(G[i,k,1]))
        if (key in pg or key[::-1] in pg) and D[i,k] < IM[i,k]:
            mrows.append((pg.get(key, pg.get(key[::-1])), float(D[i,k]), P[i,k], float(EF[i, EA[i,k]]), FR[i,k,0]*(1 if key in pg else -1)))
    tot_c += len(C[i]); tot_m += len(mrows)
    fc += sum(r[3] for r in C[i]); fm += sum(r[3] for r in mrows)
    if i < 6:
        print(f"state {i}")
        for pi in grasp_pairs:
            cc = [r for r in C[i] if r[0]==pi]; mc_ = [r for r in mrows if r[0]==pi]
            if not cc and not mc_: continue
            print(f"  pair {pi}: C {len(cc)} MJX {len(mc_)}")
            for r in cc: print("     C  d=%.4f pos=%s fn=%.2f n=%s" % (r[1], np.round(r[2],4), r[3], np.round(r[4],3)))
            for r in mc_: print("     M  d=%.4f pos=%s fn=%.2f n=%s" % (r[1], np.round(r[2],4), r[3], np.round(r[4],3)))
print("mean grasp contacts C %.2f MJX %.2f; mean total normal force C %.1f MJX %.1f" % (tot_c/32, tot_m/32, fc/32, fm/32))
from collections import Counter
cnt = Counter()
for i in range(32):
    mrows = []
    for k in range(G.shape[1]):
        key = (int(G[i,k,0]), int(G[i,k,1]))
        if (key in pg or key[::-1] in pg) and D[i,k] < IM[i,k]:
            mrows.append(pg.get(key, pg.get(key[::-1])))
            
    for pi in grasp_pairs:
        cnt[(sum(r[0]==pi for r in C[i]), mrows.count(pi))] += 1
print("(C points, MJX points) per grasp pair:", sorted(cnt.items()))
