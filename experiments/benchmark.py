"""Measure env throughput (physics and control steps/s, compile time) per task, engine and size.

Prints a table and writes JSON. Small sizes on CPU by default; pass --sizes for GPU sizes.

Example:  python experiments/benchmark.py --tasks reach --physics c mjx --sizes 1 64 256
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", nargs="+", default=["reach"], help="tasks to measure (reach, push, pickup, pot)")
    p.add_argument("--physics", nargs="+", default=["c", "mjx"], choices=["c", "mjx"],
                   help="physics engines to measure")
    p.add_argument("--sizes", nargs="+", type=int, default=[1, 64, 256], help="num_envs values")
    p.add_argument("--steps", type=int, default=50, help="control steps per timed run (one episode)")
    p.add_argument("--repeats", type=int, default=3, help="timed runs per point (median reported)")
    p.add_argument("--out", default="benchmark.json", help="JSON file for the results")
    args = p.parse_args(argv)

    import mjx_envs
    from daddpg_jax.benchmark import env_throughput, machine_description

    machine = machine_description()
    print(f"machine: {machine}")
    hdr = f"{'task':8s} {'engine':6s} {'envs':>6s} {'control/s':>12s} {'physics/s':>12s} {'compile s':>10s}"
    print(hdr)
    print("-" * len(hdr))
    rows = []
    for task in args.tasks:
        for physics in args.physics:
            env = mjx_envs.make(task, physics=physics)
            for n in args.sizes:
                r = env_throughput(env, n, n_steps=args.steps, repeats=args.repeats)
                rows.append(r)
                print(f"{task:8s} {physics:6s} {n:6d} {r['control_steps_per_s']:12,.0f} "
                      f"{r['physics_steps_per_s']:12,.0f} {r['compile_s']:10.1f}", flush=True)
    out = {"machine": machine, "command": " ".join([os.path.basename(sys.executable)] + sys.argv),
           "time": time.strftime("%Y-%m-%d %H:%M:%S"), "results": rows}
    with open(args.out, "w") as f:
        json.dump(out, f, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
