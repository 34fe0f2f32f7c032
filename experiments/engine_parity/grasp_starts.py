"""The grasped start states (``grasp_start_fraction``) of two physics versions compared: they
are recorded on the C engine whatever engine trains (mjx_envs/tasks/grasp_start.py), so a
version that changes only the C engine (6) still changes what an MJX run trains from.

    python experiments/engine_parity/grasp_starts.py A B [--tasks pickup pot] [--json OUT]

Prints, per task, how many of the recorded states differ (largest |qpos| difference > 1e-6)
and the largest difference. Output: docs/results/engines/v6/grasp_starts_5_6.json.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import numpy as np  # noqa: E402

import mjx_envs  # noqa: E402
from mjx_envs.tasks import grasp_start  # noqa: E402


def states(task: str, version: int) -> grasp_start.GraspStates:
    env = mjx_envs.make(task, physics="c", physics_version=version, grasp_start_fraction=0.5)
    inner = getattr(env, "unwrapped", env)
    return grasp_start.grasp_states(type(inner), inner.config)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("a", type=int)
    p.add_argument("b", type=int)
    p.add_argument("--tasks", nargs="+", default=["pickup", "pot"])
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    out = {}
    for task in args.tasks:
        sa, sb = states(task, args.a), states(task, args.b)
        dq = np.abs(sa.qpos - sb.qpos).max(axis=1)
        out[task] = dict(states=int(dq.size), differ=int((dq > 1e-6).sum()),
                         max_qpos_diff=float(dq.max()), median_qpos_diff=float(np.median(dq)))
        print(task, f"versions {args.a} and {args.b}:", out[task], flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
