"""python screen_dense.py OUT.json TASK...: a dense grid of small sphere pads (r 4 mm, 4 x 9 per
finger, touching) on the grasp pairs: one forward pass at the grasped states and the scripted
controller over the 32 fixed episodes on both engines, with the 10-step divergence."""
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "finger_pads"))
import spheres  # noqa: E402

spheres.patch(r=0.004, xs=(-0.012, -0.004, 0.004, 0.012), zs=tuple(0.001 + 0.008 * k for k in range(9)))
from daddpg_jax.analysis import engine_parity as ep  # noqa: E402

ep._finger_geoms = lambda m: np.array([i for i in range(m.ngeom) if "_finger" in (m.geom(i).name or "")])
out = {}
for task in sys.argv[2:]:
    st = ep.grasp_states(task)
    f = ep.forward_gap(task, ep.candidate("baseline"), st)
    print("forward", task, {k: f[k] for k in ("states", "finger_contacts_c", "finger_contacts_mjx",
                                              "dacc_lin_mean", "dacc_lin_p95")}, flush=True)
    r = ep.measure(task, ep.candidate("baseline"), episodes=32)
    out[task] = dict(forward=f, c=r["c"]["success"], mjx=r["mjx"]["success"],
                     div_test=r["div_test_mm"], div_mean=r["div_mean_mm"])
    print("RESULT", task, out[task]["c"], out[task]["mjx"], out[task]["div_test"], out[task]["div_mean"], flush=True)
    json.dump(out, open(sys.argv[1], "w"), indent=1, default=str)
