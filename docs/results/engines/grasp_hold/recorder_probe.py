"""Why the grasped-start recorder keeps fewer states with the recessed pads (OUT_M=0.001
HOLD_HI=0.024): the recording episodes, the settled step and each finger's force there."""
import os, sys
os.environ.setdefault("OUT_M", "0.001"); os.environ.setdefault("HOLD_HI", "0.024")
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import recessed; recessed.patch()
import jax, numpy as np, mjx_envs
from mjx_envs.tasks import grasp_start as gs
gs.SETTLE_STEPS = int(os.environ.get("SETTLE", gs.SETTLE_STEPS))
env = mjx_envs.make("pickup", physics="c")
keys = jax.random.split(jax.random.PRNGKey(gs.GRASP_SEED), 80)
qpos, qvel, mocap, held = gs._play(env, keys)
step = gs._settled_step(held)
print("settled", (step >= 0).sum())
check = gs.FingerContacts(env.mj_model, env.rules.object_body)
print("fingers map size", len(check.fingers))
mins = []
for b in np.flatnonzero(step >= 0):
    t = step[b]; f = check.forces(qpos[t, b], qvel[t, b], mocap[t, b]); mins.append(min(f.values()))
mins = np.array(mins); print("holds", (mins >= gs.MIN_FINGER_FORCE).sum(), np.percentile(mins, [5, 25, 50]).round(2))
import mujoco
m, d = check.model, check.data
bad = [b for b in np.flatnonzero(step >= 0) if min(check.forces(qpos[step[b], b], qvel[step[b], b], mocap[step[b], b]).values()) < 0.5][:3]
for b in bad:
    t = step[b]
    f = check.forces(qpos[t, b], qvel[t, b], mocap[t, b])
    print("ep", b, "t", t, {k: round(v, 2) for k, v in f.items()})
    print("  contacts:", sorted({(m.geom(int(c.geom1)).name[:14], m.geom(int(c.geom2)).name) for c in d.contact[:d.ncon]}))
    ids = [m.jnt_qposadr[m.joint(n).id] for n in ('l_finger1','l_finger2','r_finger1','r_finger2')]
    print("  openings", np.round(qpos[t, b][ids], 4))
