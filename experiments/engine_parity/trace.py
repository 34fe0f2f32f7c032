"""Closed-loop trajectories of one checkpoint on both engines, the same fresh episodes, kept for
offline analysis (where and when the engines' outcomes part): per engine the joint positions,
mocap targets, object centres, grip points and each episode's success / fault.

    python experiments/engine_parity/trace.py RUN OUT.npz [--step N] [--episodes 300] [--seed 9090]

Run it alone on a CPU (MJX in chunks of 32); ~4 min for 300 pot episodes on the 2-core VM."""

from __future__ import annotations

import argparse
import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

import numpy as np  # noqa: E402

from daddpg_jax.analysis import evaluation  # noqa: E402

KEYS = ("qpos", "mocap", "object", "grip", "success", "physics_fault")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run")
    p.add_argument("out")
    p.add_argument("--step", type=int, default=None, help="checkpoint (default: the best)")
    p.add_argument("--episodes", type=int, default=300)
    p.add_argument("--seed", type=int, default=9090)
    a = p.parse_args(argv)
    arrays = {}
    for physics in ("c", "mjx"):
        pol = evaluation.load_policy(a.run, step=a.step, best=a.step is None, physics=physics)
        summary, traj = evaluation.evaluate(pol, a.episodes, a.seed)
        print(physics, f"{summary['success_rate']:.3f}", flush=True)
        arrays.update({f"{physics}_{k}": np.asarray(traj[k]) for k in KEYS})
    np.savez_compressed(a.out, **arrays)
    return 0


if __name__ == "__main__":
    sys.exit(main())
