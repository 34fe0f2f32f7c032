"""python screencaps.py OUT.json TASK [TASK...]: forward pass at grasped states, the scripted
controller over 32 fixed episodes on both engines, and the 10-step divergence, with capsule pads."""
import json, sys
import numpy as np
sys.path.insert(0, __import__("os").path.dirname(__import__("os").path.abspath(__file__)))
import caps
caps.patch(**caps.DEFAULT)
from daddpg_jax.analysis import engine_parity as ep

ep._finger_geoms = lambda m: np.array([i for i in range(m.ngeom) if "_finger" in (m.geom(i).name or "")])
OUT = sys.argv[1]
out = {}
for task in sys.argv[2:]:
    st = ep.grasp_states(task)
    f = ep.forward_gap(task, ep.candidate("baseline"), st)
    print("forward", task, {k: f[k] for k in ("states", "finger_contacts_c", "finger_contacts_mjx", "dacc_lin_mean", "dacc_lin_p95")}, flush=True)
    r = ep.measure(task, ep.candidate("baseline"), episodes=32)
    out[task] = dict(forward=f, c=r["c"]["success"], mjx=r["mjx"]["success"], div_test=r["div_test_mm"], div_mean=r["div_mean_mm"])
    print("RESULT", task, out[task]["c"], out[task]["mjx"], out[task]["div_test"], out[task]["div_mean"], flush=True)
    json.dump(out, open(OUT, "w"), indent=1, default=str)
