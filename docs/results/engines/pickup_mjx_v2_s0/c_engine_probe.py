"""Eval-time probe on the C engine alone: the MJX-trained pick-up checkpoint with one change of
the C engine's options or of the finger-neck pairs at a time (no retraining). Which change lets
the C engine hold the grasps that MJX holds?

    python docs/results/engines/pickup_mjx_v2_s0/c_engine_probe.py RUN

Writes c_engine_probe.json (candidate -> success over 320 episodes of seed 2024) in the working
directory."""

import json
import sys

import mujoco

from daddpg_jax.analysis import evaluation


def neck_pairs(m):
    """Indices of the contact pairs between a finger and a bar neck."""
    for i in range(m.npair):
        names = {m.geom(int(m.pair_geom1[i])).name, m.geom(int(m.pair_geom2[i])).name}
        if (any(n.startswith("bar_neck") for n in names)
                and any(n.endswith(("finger1", "finger2")) for n in names)):
            yield i


def options(**kw):
    def change(m):
        for k, v in kw.items():
            setattr(m.opt, k, v)
    return change


def neck(**kw):
    def change(m):
        for i in neck_pairs(m):
            for k, v in kw.items():
                getattr(m, f"pair_{k}")[i][:len(v)] = v
    return change


def more_iterations(m):
    m.opt.iterations *= 4
    m.opt.ls_iterations *= 4


CANDIDATES = {
    "nominal": lambda m: None,
    "iterations_x4": more_iterations,
    "pyramidal": options(cone=mujoco.mjtCone.mjCONE_PYRAMIDAL),
    "cg_solver": options(solver=mujoco.mjtSolver.mjSOL_CG),
    "neck_solref_0.04": neck(solref=(0.04, 1.0)),
    "neck_solimp_soft": neck(solimp=(0.9, 0.95, 0.001)),
    "neck_friction_2.0": neck(friction=(2.0, 2.0, 0.01, 0.0001, 0.0001)),
}

if __name__ == "__main__":
    run = sys.argv[1]
    out = {}
    for name, change in CANDIDATES.items():
        policy = evaluation.load_policy(run, best=True, physics="c")
        change(policy.env.mj_model)   # the C backend steps this model (host side)
        summary, _ = evaluation.evaluate(policy, episodes=320, seed=2024)
        out[name] = summary["success_rate"]
        print(name, round(summary["success_rate"], 3), flush=True)
    with open("c_engine_probe.json", "w") as f:
        json.dump(out, f, indent=1)
