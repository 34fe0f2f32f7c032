import json
import sys

import mujoco

from daddpg_jax.analysis import evaluation

R = sys.argv[1]
def pairs(m, names):
    for i in range(m.npair):
        g = {m.geom(int(m.pair_geom1[i])).name, m.geom(int(m.pair_geom2[i])).name}
        if any(n.startswith(names) for n in g) and any(n.endswith(("finger1","finger2")) for n in g):
            yield i
def opt(**kw):
    def f(m):
        for k, v in kw.items(): setattr(m.opt, k, v)
    return f
def pair(**kw):
    def f(m):
        for i in pairs(m, ("bar_neck",)):
            for k, v in kw.items(): getattr(m, f"pair_{k}")[i][:len(v)] = v
    return f
C = {"nominal": lambda m: None,
     "iterations_x4": lambda m: (setattr(m.opt, "iterations", m.opt.iterations * 4), setattr(m.opt, "ls_iterations", m.opt.ls_iterations * 4)),
     "pyramidal": opt(cone=mujoco.mjtCone.mjCONE_PYRAMIDAL),
     "cg_solver": opt(solver=mujoco.mjtSolver.mjSOL_CG),
     "neck_solref_0.04": pair(solref=(0.04, 1.0)),
     "neck_solimp_soft": pair(solimp=(0.9, 0.95, 0.001)),
     "neck_friction_2.0": pair(friction=(2.0, 2.0, 0.01, 0.0001, 0.0001)),
}
out = {}
print("opt", end=" ")
for name, f in C.items():
    pol = evaluation.load_policy(R, best=True, physics="c")
    if name == "nominal":
        m = pol.env.mj_model; print(m.opt.iterations, m.opt.ls_iterations, m.opt.tolerance, m.opt.solver, m.opt.cone, m.opt.impratio, m.opt.noslip_iterations, flush=True)
    f(pol.env.mj_model)
    s, _ = evaluation.evaluate(pol, episodes=320, seed=2024)
    out[name] = s["success_rate"]; print(name, round(s["success_rate"], 3), flush=True)
json.dump(out, open("c_probe.json", "w"), indent=1)
