"""The markdown table of experiments/limits_match.py's rows (docs/DEPLOYMENT.md, "Training under
the robot's limits"): one line per JSON row under the given directories, in the order given.

    python experiments/limits_table.py docs/results/limits/paired/pickup_*.json
"""

from __future__ import annotations

import argparse
import json
import sys

from mjx_envs import limit_rules

RULES = ("workspace", "speed", "clearance", "finger")
"""the safety layer's rules, whose interventions the per-episode column counts (a missed
deadline's hold, ``stop`` / ``late``, is listed but not counted)"""

HEADER = ("| run | trained under | train test success (best) | limits | `daddpg-evaluate "
          "--limits` | robot client (counted) | robot − evaluate [paired 95 %] | solved by one "
          "side only (evaluate / robot) | robot-client interventions per episode |\n"
          "|---|---|---|---|---|---|---|---|---|")


def trained_under(row: dict) -> str:
    """The limits a run was trained under, by their max step and clearance (none: plain), and
    its intervention penalty when it had one."""
    if not row.get("trained_limits"):
        return "no limits"
    lim = limit_rules.describe(row["trained_limits"])
    pen = row.get("intervention_penalty") or 0.0
    text = f"max step {lim['max_step'] * 1e3:.1f} mm, clearance {lim['min_clearance'] * 1e2:.0f} cm"
    return text + (f", intervention penalty {pen:g}" if pen else "")


def line(row: dict) -> str:
    n = row["robot_client_episodes_counted"]
    counts = row.get("robot_client_interventions") or {}
    per = sum(v for k, v in counts.items() if k in RULES) / max(1, n)
    rules = ", ".join(f"{k} {v:,}" for k, v in sorted(counts.items())) or "none"
    limits = row["limits"] + ("" if row.get("speed_scale", 1) == 1 else
                              f" x {row['speed_scale']:g}")
    if row.get("paired"):
        lo, hi = row["paired_ci95"]
        c = row["paired_counts"]
        diff = f"{row['paired_difference']:+.3f} [{lo:+.3f}, {hi:+.3f}]"
        one = f"{c['second_only']} / {c['first_only']}"
    else:
        diff, one = f"{row['difference']:+.3f} (unpaired)", "—"
    return (f"| {row['run']} | {trained_under(row)} | {row['train_best_test_success']:.2f} | "
            f"{limits} | {row['evaluate_limits_success']:.3f} | "
            f"{row['robot_client_success']:.3f} ({n}) | {diff} | {one} | "
            f"{per:.2f} ({rules}) |")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("rows", nargs="+", help="JSON rows written by limits_match.py")
    args = p.parse_args(argv)
    print(HEADER)
    for path in args.rows:
        with open(path) as f:
            print(line(json.load(f)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
