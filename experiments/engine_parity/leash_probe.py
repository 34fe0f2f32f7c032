"""Leash probe (no retraining): one checkpoint on each engine with every gripper target kept
within L metres of the measured tool centre point, per axis, before the robot's rules. A target
that runs ahead of a blocked gripper pulls it through the weld into what blocks it; the leash
bounds that pull and so how deep the fingers press into the object. The same fresh episodes on
each engine, paired (C - MJX, Newcombe 95 % interval).

    LEASH=0.05 python experiments/engine_parity/leash_probe.py RUN OUT.json [STEP|best]

Environment: LEASH (metres, 0: off), ENGINES (default c,mjx), EPISODES (default 300); seed
9090. OUT.json gets one entry per (leash, checkpoint), merged into an existing file. Output:
docs/results/engines/dr/leash_pickup_s3.json (docs/MJX_VS_C.md, "Randomized grasp physics")."""

from __future__ import annotations

import json
import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import jax.numpy as jnp  # noqa: E402

from experiments.engine_parity import probe_tools as pt  # noqa: E402
from mjx_envs import core  # noqa: E402


def leashed_limits(leash: float):
    """`DualArmEnv.limit_targets` that first clips the targets to the measured TCP +- `leash`
    per axis (the step itself is the env's own)."""
    limit_targets = core.DualArmEnv.limit_targets

    def limit(self, state, current, target):
        grip = state.obs["observation"][..., 0:3]
        return limit_targets(self, state, current, jnp.clip(target, grip - leash, grip + leash))
    return limit


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) not in (2, 3):
        print(__doc__)
        return 2
    run, out = argv[0], argv[1]
    step = None if len(argv) < 3 or argv[2] == "best" else int(argv[2])
    leash = float(os.environ.get("LEASH", "0"))
    if leash > 0:
        # this process only, before any compile
        core.DualArmEnv.limit_targets = leashed_limits(leash)
    engines = tuple(e for e in os.environ.get("ENGINES", "c,mjx").split(",") if e)
    res = pt.evaluate_engines(run, None, engines, int(os.environ.get("EPISODES", "300")), 9090,
                              label=f"leash {leash}", step=step)
    row = pt.paired(res)
    print(row, flush=True)
    done = json.load(open(out)) if os.path.exists(out) else {}
    done[f"leash_{leash}_{argv[2] if len(argv) > 2 else 'best'}"] = row
    with open(out, "w") as fh:
        json.dump(done, fh, indent=1, default=float)
    return 0


if __name__ == "__main__":
    sys.exit(main())
