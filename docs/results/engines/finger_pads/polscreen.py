"""python polscreen.py RUN OUT.json [episodes]: RUN on both engines with sphere finger pads."""
import json, sys, time
import spheres
spheres.patch(r=0.006, xs=(-0.01, 0.01), zs=(0.005, 0.025, 0.045, 0.065))
from daddpg_jax.analysis import evaluation

R, OUT = sys.argv[1], sys.argv[2]
n = int(sys.argv[3]) if len(sys.argv) > 3 else 320
res = {}
for eng in ("c", "mjx"):
    t0 = time.time()
    pol = evaluation.load_policy(R, best=True, physics=eng)
    assert pol.env.mj_model.npair > 20, pol.env.mj_model.npair
    s, tr = evaluation.evaluate(pol, episodes=n, seed=2024)
    res[eng] = tr["success"].astype(bool)
    print(eng, float(res[eng].mean()), f"{time.time()-t0:.0f}s", flush=True)
c, mj = res["c"], res["mjx"]
out = dict(c=float(c.mean()), mjx=float(mj.mean()), c_only=int((c & ~mj).sum()), mjx_only=int((mj & ~c).sum()))
print(out, flush=True)
json.dump(out, open(OUT, "w"), indent=1)
