"""Pads in front of a blocking finger box (probe): the dense sphere grid of screen_dense.py set
OUT_M (m, environment; default 0.001) beyond the finger box's inner face, and the finger box kept in its pair with the neck
or handle at friction 0.05 (a blocker, as with the bar's caps). GRID=dense|coarse, SETTLE (grasp_start.SETTLE_STEPS), HOLD_HI (the upper end of scripted.HOLD_OPENING) in the environment.
python recessed.py OUT.json TASK..."""
import json
import os
import sys

import mujoco
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "finger_pads"))
import spheres  # noqa: E402

OUT_M = float(os.environ.get("OUT_M", "0.001"))
GRIDS = {"dense": (0.004, (-0.012, -0.004, 0.004, 0.012), tuple(0.001 + 0.008 * k for k in range(9))),
         "coarse": (0.006, (-0.01, 0.01), (0.005, 0.025, 0.045, 0.065))}
R, XS, ZS = GRIDS[os.environ.get("GRID", "dense")]


def _edit(spec, **_):
    fingers = {}
    for b in spec.bodies:
        for g in b.geoms:
            if g.name.endswith(("_finger1", "_finger2")):
                fingers[g.name] = (b, g)
    grasp = [p for p in spec.pairs
             if (p.geomname1 in fingers or p.geomname2 in fingers) and p.friction[0] > 1.0]
    for p in grasp:
        fname = p.geomname1 if p.geomname1 in fingers else p.geomname2
        other = p.geomname2 if fname == p.geomname1 else p.geomname1
        body, g = fingers[fname]
        sign = 1.0 if fname.endswith("finger1") else -1.0
        y = sign * (-0.005 - OUT_M + R)
        for i, x in enumerate(XS):
            for j, z in enumerate(ZS):
                nm = f"{fname}_pad{i}{j}"
                if spec.geom(nm) is None:
                    body.add_geom(name=nm, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[R, 0, 0],
                                  pos=[x, y, z], contype=0, conaffinity=0, group=3, density=0.0)
                spec.add_pair(geomname1=nm, geomname2=other, condim=p.condim,
                              friction=list(p.friction), solref=list(p.solref),
                              solimp=list(p.solimp), margin=p.margin, gap=p.gap)
        p.friction = [0.05, 0.05, 0.005, 0.0001, 0.0001]



def patch():
    spheres._edit = _edit
    spheres.patch(r=R)
    if os.environ.get("SETTLE"):    # control steps the grasped-start recorder waits for a hold
        from mjx_envs.tasks import grasp_start
        grasp_start.SETTLE_STEPS = int(os.environ["SETTLE"])
    if os.environ.get("HOLD_HI"):   # the scripted controller's "closed on the object" openings
        from mjx_envs.tasks import scripted
        scripted.HOLD_OPENING = (scripted.HOLD_OPENING[0], float(os.environ["HOLD_HI"]))


def main():
    patch()
    from daddpg_jax.analysis import engine_parity as ep

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


if __name__ == "__main__":
    main()
