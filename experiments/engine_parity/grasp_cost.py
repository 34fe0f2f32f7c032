"""The C engine's cost of a grasp-pair collision set-up: mj_step at 64 of the scripted pick-up
controller's grasped states (both grippers holding), 20 control steps each, for the task's model
and for pad kinds of pads.py, run alternately ROUNDS times; reports steps per second (median).

    python experiments/engine_parity/grasp_cost.py TASK KIND [KIND ...]   # pickup meshf_mjxbox

KIND "baseline" is the task's own model. Outputs: docs/results/engines/manifold_search/.
"""

from __future__ import annotations

import os
import sys
import time

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

import mjx_envs  # noqa: E402
from experiments.engine_parity import pads  # noqa: E402
from experiments.engine_parity import probe_tools as pt  # noqa: E402

N, T, ROUNDS = 64, 20, 3


def steps_per_second(m, st, steps) -> float:
    d = mujoco.MjData(m)
    t0 = time.perf_counter()
    for i in range(N):
        pt.set_c_state(m, d, st, i)
        for _ in range(steps):
            mujoco.mj_step(m, d)
    return N * steps / (time.perf_counter() - t0)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 2:
        print(__doc__)
        return 2
    task, kinds = argv[0], argv[1:]
    env = mjx_envs.make(task, physics="c")
    steps = T * env.config.n_substeps
    st = pt.sample_states(task, N, dtype=np.float64)
    models = {k: env.mj_model if k == "baseline" else pads.like(k, f"scene_{task}.xml",
                                                                env.mj_model)
              for k in kinds}
    rates = {k: [] for k in kinds}
    for _ in range(ROUNDS):
        for k, m in models.items():
            rates[k].append(steps_per_second(m, st, steps))
    for k in kinds:
        print(task, k, "mj_step/s median", round(float(np.median(rates[k]))),
              "rounds", [round(r) for r in rates[k]], flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
