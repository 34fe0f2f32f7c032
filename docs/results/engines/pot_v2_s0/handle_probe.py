"""Eval-time probe: the C-trained pot policy on both engines with the finger-handle pairs
changed (no retraining): which change narrows the engines' gap without hurting C?

    python docs/results/engines/pot_v2_s0/handle_probe.py RUN [CANDIDATE ...]

RUN: the pot preset's run directory; writes handle_probe.json in the working directory."""
import json
import sys

from daddpg_jax.analysis import evaluation
from mjx_envs.physics.backends import import_mjx

R = sys.argv[1]
CANDS = {
    "nominal": {},
    "handle_solref_0.04": dict(solref=(0.04, 1.0)),
    "handle_solimp_soft": dict(solimp=(0.9, 0.95, 0.001)),
    "handle_friction_1.0": dict(friction=(1.0, 1.0, 0.01, 0.0001, 0.0001)),
}
names = sys.argv[2:] or list(CANDS)
out = {}
for name in names:
    res = {}
    for eng in ("c", "mjx"):
        pol = evaluation.load_policy(R, best=True, physics=eng)
        m = pol.env.mj_model
        for i in range(m.npair):
            g = {m.geom(int(m.pair_geom1[i])).name, m.geom(int(m.pair_geom2[i])).name}
            if any(n.startswith("pot_handle") for n in g):
                for k, v in CANDS[name].items():
                    getattr(m, f"pair_{k}")[i][:len(v)] = v
        if eng == "mjx":
            mjx = import_mjx()
            pol.env.backend.model = mjx.put_model(m)
            pol.env.backend._data0 = mjx.make_data(pol.env.backend.model)
        s, tr = evaluation.evaluate(pol, episodes=320, seed=2024)
        res[eng] = tr["success"].astype(bool)
    c, mj = res["c"], res["mjx"]
    out[name] = dict(c=float(c.mean()), mjx=float(mj.mean()), c_only=int((c & ~mj).sum()),
                     mjx_only=int((mj & ~c).sum()))
    print(name, out[name], flush=True)
json.dump(out, open("handle_probe.json", "w"), indent=1)
