"""Eval-time probe: RUN on both engines with scene changes (no retraining).
python probe.py RUN OUT.json CAND [CAND ...]"""
import json, sys, time, os
from daddpg_jax.analysis import evaluation
from mjx_envs.physics.backends import import_mjx

R, OUT = sys.argv[1], sys.argv[2]
GRASP = ("pot_handle", "neck")
CANDS = {
    "nominal": ({}, {}),
    "impratio_5": (dict(impratio=5.0), {}),
    "impratio_10": (dict(impratio=10.0), {}),
    "grasp_solimp_soft": ({}, dict(solimp=(0.9, 0.95, 0.001))),
    "grasp_solref_0.03": ({}, dict(solref=(0.03, 1.0))),
    "impratio_5_solimp_soft": (dict(impratio=5.0), dict(solimp=(0.9, 0.95, 0.001))),
}
out = json.load(open(OUT)) if os.path.exists(OUT) else {}
for name in sys.argv[3:]:
    opt, pair = CANDS[name]
    res = {}
    for eng in ("c", "mjx"):
        t0 = time.time()
        pol = evaluation.load_policy(R, best=True, physics=eng)
        m = pol.env.mj_model
        for k, v in opt.items():
            setattr(m.opt, k, v)
        for i in range(m.npair):
            g = {m.geom(int(m.pair_geom1[i])).name, m.geom(int(m.pair_geom2[i])).name}
            if any(any(s in n for s in GRASP) for n in g):
                for k, v in pair.items():
                    getattr(m, f"pair_{k}")[i][:len(v)] = v
        if eng == "mjx":
            mjx = import_mjx()
            pol.env.backend.model = mjx.put_model(m)
            pol.env.backend._data0 = mjx.make_data(pol.env.backend.model)
        s, tr = evaluation.evaluate(pol, episodes=320, seed=2024)
        res[eng] = tr["success"].astype(bool)
        print(name, eng, float(res[eng].mean()), f"{time.time()-t0:.0f}s", flush=True)
    c, mj = res["c"], res["mjx"]
    out[name] = dict(c=float(c.mean()), mjx=float(mj.mean()), c_only=int((c & ~mj).sum()),
                     mjx_only=int((mj & ~c).sum()))
    print(name, out[name], flush=True)
    json.dump(out, open(OUT, "w"), indent=1)
