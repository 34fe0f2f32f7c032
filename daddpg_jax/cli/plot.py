r"""Learning curves of one or more runs: test success vs env steps, test success vs wall clock,
and the arm-contact rate, as three panels (PNG).

Examples
  python experiments/plot.py runs/reach_s0 --out reach.png
  python experiments/plot.py runs/reach_daddpg_s{0,1,2} runs/reach_single_s{0,1,2} --out cmp.png
  python experiments/plot.py runs/a runs/b runs/c --labels daddpg daddpg single --band std \
      --out x.png

Runs that share a label form one group (e.g. seeds): the plot shows the group's mean and a band
(min-max over its runs by default, or mean +- one std with --band std). Runs are aligned by
epoch; x values are the mean env steps / wall clock of that epoch over the group's runs.
Without --labels a run's label is task/algo from its config.json (so seeds group together).

--max-wall / --max-env-steps cut every run to the epochs that ended within that budget, so runs
of different lengths compare at one budget; --table writes one CSV row per run (the columns of
reproduce.py's final.csv, computed over the kept epochs), e.g.

  python experiments/plot.py runs/push_daddpg_s0 runs/push_ddpg_s0 --max-wall 720 \
      --table push_12min.csv --out push_12min.png

--summary writes one CSV row per group (label): the mean and standard deviation over its runs
of the final, last-5 and best test success, env steps to 0.5 / 0.9 and the arm-contact rate
(last 5 tests and whole run), also printed, e.g. to compare variants over seeds:

  python experiments/plot.py runs/push_daddpg_s{0,1,2} runs/push_ddpg_s{0,1,2} \
      --max-env-steps 80000 --summary push_80k.csv --out push_80k.png
"""

from __future__ import annotations

import argparse
import csv
import os
import sys

from daddpg_jax.analysis.plotting import (
    group_summary,
    plot_runs,
    read_metrics,
    repeated_seeds,
    run_config,
    run_label,
    summary_columns,
    truncate,
)


def _write_table(path: str, table: list) -> None:
    """One row per run (run, label, metrics rows, config): final.csv's columns + run."""
    # lazy: analysis.reproduce imports JAX (the runner); only --table needs it
    from daddpg_jax.analysis.reproduce import FINAL_COLUMNS, Experiment, final_row

    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=(*FINAL_COLUMNS, "run"))
        w.writeheader()
        for run, label, rows, cfg in table:
            exp = Experiment(label, str(cfg.get("algo", "?")), str(cfg.get("her", "?")))
            row = final_row(str(cfg.get("task", "?")), exp, int(cfg.get("seed", 0)), rows)
            w.writerow(dict(row, run=run))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="daddpg-plot", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="+", metavar="RUN_DIR",
                   help="run directories (or metrics.csv files)")
    p.add_argument("--out", required=True, metavar="FILE.png", help="output image")
    p.add_argument("--labels", nargs="+", default=None,
                   help="one label per RUN_DIR; runs with the same label are one group")
    p.add_argument("--band", choices=["minmax", "std"], default="minmax",
                   help="band around each group's mean: min-max over runs (default) or +-1 std")
    p.add_argument("--title", default="", help="figure title")
    p.add_argument("--max-wall", type=float, default=None, metavar="SECONDS",
                   help="keep only the epochs that ended within this wall clock (s) of each run")
    p.add_argument("--max-env-steps", type=float, default=None, metavar="N",
                   help="keep only the epochs that ended within N env steps of each run")
    p.add_argument("--table", default=None, metavar="FILE.csv",
                   help="also write one row per run: final/best success, env steps and wall "
                        "clock to 0.5 and 0.9, arm-contact rate (final.csv's columns + run)")
    p.add_argument("--summary", default=None, metavar="FILE.csv",
                   help="also write one row per label: mean and std over its runs of the final, "
                        "last-5 and best test success, env steps to 0.5/0.9 and the arm-contact "
                        "rate (last 5 tests, whole run)")
    args = p.parse_args(argv)
    if args.labels is not None and len(args.labels) != len(args.runs):
        p.error(f"--labels: got {len(args.labels)} labels for {len(args.runs)} runs")
    for name in ("max_wall", "max_env_steps"):
        v = getattr(args, name)
        if v is not None and not v > 0:
            p.error(f"--{name.replace('_', '-')} must be > 0, got {v}")

    groups: dict = {}
    paths: dict = {}
    table = []
    for i, run in enumerate(args.runs):
        try:
            rows = read_metrics(run)
        except (FileNotFoundError, ValueError) as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        rows = truncate(rows, args.max_wall, args.max_env_steps)
        if not rows:
            print(f"error: {run}: no epoch ended within the --max-wall/--max-env-steps budget",
                  file=sys.stderr)
            return 2
        label = args.labels[i] if args.labels else run_label(run)
        groups.setdefault(label, []).append(rows)
        paths.setdefault(label, []).append(run)
        table.append((run, label, rows, run_config(run)))
    for msg in repeated_seeds(paths):
        print(f"warning: {msg}", file=sys.stderr)
    for label, runs in groups.items():
        lengths = sorted({len(r) for r in runs})
        if len(lengths) > 1:
            print(f"warning: group {label!r}: runs have {', '.join(map(str, lengths))} epochs; "
                  f"after epoch {lengths[0]} its mean is over fewer runs (open circles)",
                  file=sys.stderr)
    out = plot_runs(groups, args.out, title=args.title, band=args.band)
    if args.table:
        _write_table(args.table, table)
        print(f"wrote {os.path.abspath(args.table)}")
    if args.summary:
        rows_out = group_summary(groups)
        with open(args.summary, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=summary_columns())
            w.writeheader()
            w.writerows(rows_out)
        for r in rows_out:
            print(f"{r['label']}: last-5 test success {r['last_test_success_mean']:.2f} "
                  f"± {r['last_test_success_std']:.2f}, last-5 arm contact "
                  f"{r['last_arm_contact_rate_mean']:.2f} ± {r['last_arm_contact_rate_std']:.2f} "
                  f"(mean ± std over {r['runs']} run(s))")
        print(f"wrote {os.path.abspath(args.summary)}")
    for label, runs in groups.items():
        last = [float(r[-1]["test_success_rate"]) for r in runs]
        finals = ", ".join(f"{v:.2f}" for v in last)
        print(f"{label}: {len(runs)} run(s), final test success {finals}")
    print(f"wrote {os.path.abspath(out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
