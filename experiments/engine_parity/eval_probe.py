"""Eval-time probes (no retraining): a trained run's best checkpoint on each engine with one
change of the grasp pairs or solver options at a time, or with finger pads (pads.py). 320
episodes of seed 2024; with both engines, the paired outcomes and the Newcombe 95% interval of
the difference.

    python experiments/engine_parity/eval_probe.py [--pads KIND] [--engines c] [--episodes N] \
        [--seed S] [--step N] RUN OUT.json [CANDIDATE ...]

OUT.json gets one entry per candidate (merged into an existing file). Recorded outputs:
docs/results/engines/pickup_mjx_v2_s0/c_engine_probe.json (--engines c, the neck_* and solver
candidates), pot_v2_s0/handle_probe.json (handle_*), finger_pads/impratio_probe_*.json
(impratio_*, grasp_*), finger_pads/ps_*.json (--pads spheres) and
grasp_hold/eval_recessed_*.json (--pads recessed; OUT_M, HOLD_HI, SETTLE from the environment).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import mujoco  # noqa: E402

from experiments.engine_parity import pads  # noqa: E402
from experiments.engine_parity import probe_tools as pt  # noqa: E402

SOFT = dict(solimp=(0.9, 0.95, 0.001))


def _neck(**fields):   # finger-to-bar-neck pairs
    return pt.pair_fields(words=("bar_neck",), min_friction=None, finger=True, **fields)


def _handle(**fields):   # every pair with a pot handle
    return pt.pair_fields(words=("pot_handle",), min_friction=None, **fields)


def _body(**fields):   # every finger pair with the pot's body
    return pt.pair_fields(words=("pot_body",), min_friction=None, finger=True, **fields)


def _grasp(**fields):   # every pair with a pot handle or a bar neck
    return pt.pair_fields(min_friction=None, **fields)


def _more_iterations(m):
    m.opt.iterations *= 4
    m.opt.ls_iterations *= 4


def _cold_start(m):
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_WARMSTART)


CANDIDATES = {
    "nominal": None,
    # solver options
    "iterations_x4": _more_iterations,
    "pyramidal": pt.options(cone=mujoco.mjtCone.mjCONE_PYRAMIDAL),
    "cg_solver": pt.options(solver=mujoco.mjtSolver.mjSOL_CG),
    "cold_start": _cold_start,   # no warm start (a C-engine Newton stop: MJX_VS_C.md, version 5)
    "converged": pt.options(tolerance=0.0, iterations=100, ls_iterations=50),
    "tol0_it30": pt.options(tolerance=0.0, iterations=30, ls_iterations=30),
    "ls_it50": pt.options(ls_iterations=50),
    "mjx_ls_it50": pt.mjx_ls_iterations(50),   # versions 6+: MJX's line search as the C engine's
    "iterations_50": pt.options(iterations=50),   # Newton iterations (both engines)
    "ls_it15": pt.options(ls_iterations=15),   # version 6's C engine back to the scenes' 15
    "ls_it25": pt.options(ls_iterations=25),
    "impratio_5": pt.options(impratio=5.0),
    "impratio_10": pt.options(impratio=10.0),
    "impratio_5_solimp_soft": pt.chain(pt.options(impratio=5.0), _grasp(**SOFT)),
    # the grasp pairs
    "grasp_solimp_soft": _grasp(**SOFT),
    "grasp_solref_0.03": _grasp(solref=(0.03, 1.0)),
    "grasp_solref_0.025": _grasp(solref=(0.025, 1.0)),
    "grasp_solref_0.015": _grasp(solref=(0.015, 1.0)),
    # every finger pair (grasp and blocker: the pot's body, the bar's middle and caps)
    "fingers_solref_0.015": pt.pair_fields(words=("pot_", "bar_"), min_friction=None,
                                           finger=True, solref=(0.015, 1.0)),
    "fingers_solref_0.0175": pt.pair_fields(words=("pot_", "bar_"), min_friction=None,
                                            finger=True, solref=(0.0175, 1.0)),
    "neck_solref_0.04": _neck(solref=(0.04, 1.0)),
    "neck_solimp_soft": _neck(**SOFT),
    "neck_solimp_0.97_0.995": _neck(solimp=(0.97, 0.995, 0.001)),
    "neck_solimp_0.96_0.99": _neck(solimp=(0.96, 0.99, 0.001)),
    "neck_friction_2.0": _neck(friction=(2.0, 2.0, 0.01, 0.0001, 0.0001)),
    "handle_solref_0.04": _handle(solref=(0.04, 1.0)),
    "handle_solimp_soft": _handle(**SOFT),
    "handle_friction_1.0": _handle(friction=(1.0, 1.0, 0.01, 0.0001, 0.0001)),
    "handle_friction_1.3": _handle(friction=(1.3, 1.3, 0.01, 0.0001, 0.0001)),
    "handle_solimp_0.92_0.97": _handle(solimp=(0.92, 0.97, 0.001)),
    "handle_solimp_hard": _handle(solimp=(0.95, 0.99, 0.001)),
    "handle_solimp_0.93_0.98": _handle(solimp=(0.93, 0.98, 0.001)),
    "handle_solimp_0.92_0.98": _handle(solimp=(0.92, 0.98, 0.001)),
    "handle_solimp_0.92_0.975": _handle(solimp=(0.92, 0.975, 0.001)),
    # the finger-pot body pairs (blockers; solimp 0.95 0.99 in the scene)
    "body_solimp_soft": _body(**SOFT),
    "body_solimp_0.97_0.995": _body(solimp=(0.97, 0.995, 0.001)),
    "body_solref_0.01": _body(solref=(0.01, 1.0)),
}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run")
    p.add_argument("out")
    p.add_argument("candidates", nargs="*", help="of: " + ", ".join(CANDIDATES) + " (nominal)")
    p.add_argument("--pads", choices=pads.PADS, help="finger pads in every model (this process)")
    p.add_argument("--engines", default="c,mjx")
    p.add_argument("--episodes", type=int, default=320)
    p.add_argument("--seed", type=int, default=2024)
    p.add_argument("--step", type=int, default=None, help="this checkpoint instead of the best")
    args = p.parse_args(argv)
    if any(c not in CANDIDATES for c in args.candidates):
        p.error("unknown candidate; one of " + ", ".join(CANDIDATES))
    if args.pads:
        pads.patch(args.pads)
    engines = tuple(e for e in args.engines.split(",") if e)
    out = json.load(open(args.out)) if os.path.exists(args.out) else {}
    for name in args.candidates or ["nominal"]:
        res = pt.evaluate_engines(args.run, CANDIDATES[name], engines, args.episodes, args.seed,
                                  label=name, step=args.step)
        out[name] = pt.paired(res)
        print(name, out[name], flush=True)
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())
