"""Markdown rows of the MJX -> C table from `mjx_to_c.sh` outputs: per output folder, the run's
training line (test success of its best epoch, env steps, wall clock) and, per checkpoint (the
best, the first at 0.5), each engine's success, the paired C - MJX interval with its counts and
whether it lies within +-0.10.

    python experiments/engine_parity/mjx_to_c_rows.py OUT [OUT ...]
"""

from __future__ import annotations

import csv
import json
import os
import re
import sys

from daddpg_jax.running.cross_check import PART_TOLERANCE as BAR


def inside(lo: float, hi: float, bar: float = BAR) -> bool:
    """whether the interval (lo, hi) lies within ±bar, the agreement the rows check"""
    return -bar <= lo and hi <= bar


def row(out: str, name: str) -> str | None:
    path = os.path.join(out, f"{name}.json")
    if not os.path.exists(path):
        return None
    d = json.load(open(path))
    c, m, diff = d["engines"]["c"], d["engines"]["mjx"], d["difference"]
    lo, hi = diff["ci95"]
    p = diff["paired"]
    within = "yes" if inside(lo, hi) else (
        "**no** (C below)" if diff["value"] < 0 else "**no** (C above)")
    label = "best" if d["best"] else "first ≥ 0.5"
    return (f"| {label} (epoch {d['checkpoint']}) | {c['success_rate']:.3f} ({c['successes']}/"
            f"{d['episodes']}) | {m['success_rate']:.3f} ({m['successes']}/{d['episodes']}) | "
            f"**{diff['value']:+.3f} ({lo:+.3f} to {hi:+.3f})**; both {p['both']}, C only "
            f"{p['first_only']}, MJX only {p['second_only']} | {within} | "
            f"{c['physics_fault_episodes']} / {m['physics_fault_episodes']} |")


def training(out: str) -> str:
    rows = list(csv.DictReader(open(os.path.join(out, "run", "metrics.csv"))))
    best = max(rows, key=lambda r: float(r["test_success_rate"]))
    log = open(os.path.join(out, "train.log")).read()
    wall = re.findall(r"env steps, (\d+) s, test success", log)
    faults = max(float(r.get("train_physics_fault_rate") or 0) for r in rows)
    return (f"{float(best['test_success_rate']):.2f} at {int(best['env_steps']):,} env steps "
            f"(epoch {best['epoch']}), {wall[-1] if wall else '?'} s; largest training "
            f"physics-fault rate of an epoch {faults:.2f}")


def main(argv=None) -> int:
    for out in (sys.argv[1:] if argv is None else argv):
        print(f"{out}: {training(out)}")
        for name in ("best", "first_0.5"):
            r = row(out, name)
            if r:
                print(r)
    return 0


if __name__ == "__main__":
    sys.exit(main())
