"""Robustness over seeds: the perturbation grids of several runs (``daddpg-evaluate RUN
--perturb ... --out DIR``) summarized per group of runs (for example plain and randomized
training, 3 seeds each).

    python experiments/robustness.py --group plain=runs/p_s0/perturbation,runs/p_s1/perturbation \\
        --group robust=runs/r_s0/perturbation,runs/r_s1/perturbation \\
        --at obs_noise=0.01 --at latency=1 --at obs_dropout=0 --out docs/results/robustness/push

writes OUT/robustness.csv (one row per group and grid point: mean and std of the success rate
over the group's runs and each run's value), OUT/robustness.json (the same, plus the rows at
the --at point) and OUT/robustness.png (mean success ± std against each perturbation, the
others at the --at point's values, or their first ones where --at leaves them out; one line per
group). Every run of a group must have been evaluated on the same grid.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys

SUMMARY_COLUMNS = ("group", "runs", "success_mean", "success_std", "success_min",
                   "success_per_run", "arm_contact_mean")
"""columns of robustness.csv after the grid's keys (success_per_run: the runs' rates, '/')"""


def read_grid(path: str) -> tuple[list[str], list[dict]]:
    """(grid keys, rows) of one perturbation.json (or of the directory holding it)."""
    if os.path.isdir(path):
        path = os.path.join(path, "perturbation.json")
    if not os.path.exists(path):
        raise FileNotFoundError(f"{path}: no perturbation.json (run daddpg-evaluate --perturb)")
    with open(path) as f:
        data = json.load(f)
    return list(data["grid"]), data["rows"]


def _key(row: dict, keys: list[str]) -> tuple:
    return tuple(float(row[k]) for k in keys)


def summarize(groups: dict[str, list[str]]) -> tuple[list[str], list[dict]]:
    """(grid keys, one summary row per group and grid point) from {group: [grid paths]}.
    The std is the population std over the group's runs (0 for one run)."""
    keys, out = None, []
    for name, paths in groups.items():
        if not paths:
            raise ValueError(f"group {name!r}: no runs")
        grids = [read_grid(p) for p in paths]
        for p, (k, _) in zip(paths, grids, strict=True):
            if keys is None:
                keys = k
            if k != keys:
                raise ValueError(f"{p}: grid keys {k} differ from {keys}")
        points = [_key(r, keys) for r in grids[0][1]]
        by_run = []
        for p, (_, rows) in zip(paths, grids, strict=True):
            table = {_key(r, keys): r for r in rows}
            if sorted(table) != sorted(points):
                raise ValueError(f"{p}: its grid points differ from {paths[0]}'s")
            by_run.append(table)
        for point in points:
            vals = [float(t[point]["success_rate"]) for t in by_run]
            contact = [float(t[point]["arm_contact_rate"]) for t in by_run]
            mean = sum(vals) / len(vals)
            std = math.sqrt(sum((v - mean) ** 2 for v in vals) / len(vals))
            out.append(dict(zip(keys, point, strict=True), group=name, runs=len(vals),
                            success_mean=mean, success_std=std, success_min=min(vals),
                            success_per_run="/".join(f"{v:.2f}" for v in vals),
                            arm_contact_mean=sum(contact) / len(contact)))
    return keys, out


def rows_at(rows: list[dict], at: dict[str, float]) -> list[dict]:
    """The summary rows whose grid values match `at` (within 1e-9)."""
    return [r for r in rows if all(abs(float(r[k]) - v) < 1e-9 for k, v in at.items())]


def plot(keys: list[str], rows: list[dict], at: dict[str, float], path: str,
         title: str = "") -> str:
    """Mean success ± std against each grid key, one line per group; the other keys at `at`'s
    values (or at the first value of the grid)."""
    import matplotlib  # lazy: loads only when a figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after the backend is chosen

    groups = list(dict.fromkeys(r["group"] for r in rows))
    first = {k: float(rows[0][k]) for k in keys}
    fig, axes = plt.subplots(1, len(keys), figsize=(3.8 * len(keys), 3.3), squeeze=False)
    for ax, key in zip(axes[0], keys, strict=True):
        others = {k: at.get(k, first[k]) for k in keys if k != key}
        for g in groups:
            sel = rows_at([r for r in rows if r["group"] == g], others)
            sel.sort(key=lambda r: float(r[key]))
            ax.errorbar([float(r[key]) for r in sel], [r["success_mean"] for r in sel],
                        yerr=[r["success_std"] for r in sel], marker="o", capsize=3, label=g)
        ax.set_xlabel(key)
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
        ax.set_title(", ".join(f"{k}={v:g}" for k, v in others.items()), fontsize=8)
    axes[0][0].set_ylabel("test success (mean ± std over runs)")
    axes[0][-1].legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _parse_group(item: str) -> tuple[str, list[str]]:
    name, sep, paths = item.partition("=")
    if not sep or not name.strip() or not paths.strip():
        raise ValueError(f"--group {item!r}: expected NAME=DIR1,DIR2,...")
    return name.strip(), [p.strip() for p in paths.split(",") if p.strip()]


def _parse_at(items: list[str]) -> dict[str, float]:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--at {item!r}: expected KEY=NUMBER") from None
        if not sep:
            raise ValueError(f"--at {item!r}: expected KEY=NUMBER")
    return out


def build_parser():
    p = argparse.ArgumentParser(prog="robustness.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--group", action="append", required=True, metavar="NAME=DIR1,DIR2,...",
                   help="a group of runs' perturbation outputs (directories holding "
                        "perturbation.json, or the files); repeatable, one line per group")
    p.add_argument("--at", action="append", default=[], metavar="KEY=VALUE",
                   help="the grid point to report (and at which the plot holds the other "
                        "keys); repeatable; default: the grid's first values")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="directory for robustness.csv/.json/.png")
    p.add_argument("--title", default="", help="title of the plot")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        groups = dict(_parse_group(g) for g in args.group)
        at = _parse_at(args.at)
        keys, rows = summarize(groups)
        unknown = set(at) - set(keys)
        if unknown:
            raise ValueError(f"--at: {sorted(unknown)} not in the grid {keys}")
    except (ValueError, FileNotFoundError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "robustness.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=[*keys, *SUMMARY_COLUMNS])
        w.writeheader()
        w.writerows(rows)
    sel = rows_at(rows, at) if at else []
    with open(os.path.join(args.out, "robustness.json"), "w") as f:
        json.dump(dict(groups=groups, grid=keys, at=at, at_rows=sel, rows=rows), f, indent=2)
    plot(keys, rows, at, os.path.join(args.out, "robustness.png"), args.title)
    for r in sel:
        print(f"{r['group']:>12}  " + "  ".join(f"{k}={r[k]:g}" for k in keys)
              + f"  success {r['success_mean']:.2f} ± {r['success_std']:.2f}"
                f" ({r['success_per_run']})")
    print(f"wrote {args.out}/robustness.csv, .json, .png")
    return 0
