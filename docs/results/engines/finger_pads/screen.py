import json, sys, time
import numpy as np
import spheres
spheres.patch(r=0.006, xs=(-0.01, 0.01), zs=(0.005, 0.025, 0.045, 0.065))
from daddpg_jax.analysis import engine_parity as ep

ep._finger_geoms = lambda m: np.array([i for i in range(m.ngeom) if "_finger" in (m.geom(i).name or "")])
out = {}
for task in sys.argv[1:]:
    st = ep.grasp_states(task)
    f = ep.forward_gap(task, ep.candidate("baseline"), st)
    print("forward", task, {k: f[k] for k in ("states", "finger_contacts_c", "finger_contacts_mjx", "dacc_lin_mean", "dacc_lin_p95")}, flush=True)
    r = ep.measure(task, ep.candidate("baseline"), episodes=32)
    out[task] = dict(forward=f, c=r["c"]["success"], mjx=r["mjx"]["success"], div_test=r["div_test_mm"], div_mean=r["div_mean_mm"])
    print("RESULT", task, out[task]["c"], out[task]["mjx"], out[task]["div_test"], out[task]["div_mean"], flush=True)
json.dump(out, open("screen_" + "_".join(sys.argv[1:]) + ".json", "w"), indent=1, default=str)
