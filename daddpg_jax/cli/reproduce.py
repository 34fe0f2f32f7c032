"""Reproduce the paper's experiments: learning curves per task over seeds, and the cooperation
ablations (daddpg vs maddpg vs ddpg vs single vs daddpg without HER).

Every run is capped by an env-step budget (--env-steps) and a wall-clock budget
(--budget-minutes, per run, compile included) and is resumable: run the same command again to
continue runs that stopped on the clock, with a larger budget to extend them.

Examples
  python experiments/reproduce.py --task reach --seeds 3 --ablations --budget-minutes 5
  python experiments/reproduce.py --task push --seeds 3 --env-steps 1000000 --budget-minutes 60
  python experiments/reproduce.py --task reach --algo daddpg single --seeds 2

Writes OUT/<task>/: final.csv (one row per run: final and best test success, env steps and
wall clock to 0.5 and 0.9 success, arm-contact rates), curves.png, ablations.png, summary.json,
and runs/<label>_s<seed>/ (each a full run directory: metrics.csv, checkpoints, ...).
"""

from __future__ import annotations

import argparse
import os
import sys

from daddpg_jax.algo.config import TrainConfig
from mjx_envs import registry, schema
from mjx_envs.registry import TASKS


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="daddpg-reproduce", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", required=True, choices=TASKS,
                   help="task to run")
    p.add_argument("--seeds", type=int, default=3, help="seeds of the main variant (default 3)")
    p.add_argument("--first-seed", type=int, default=0,
                   help="first seed (default 0): runs seeds FIRST..FIRST+SEEDS-1, e.g. to add "
                        "seeds to a set in another output directory or on another machine")
    p.add_argument("--algo", nargs="+", default=None,
                   choices=["daddpg", "maddpg", "ddpg", "single"],
                   help="main variant(s) to run over the seeds (default daddpg)")
    p.add_argument("--ablations", action="store_true",
                   help="also run maddpg, ddpg, single and daddpg with HER off (1 seed each)")
    p.add_argument("--env-steps", type=int, default=200_000,
                   help="env-step budget per run (rounded up to whole epochs)")
    p.add_argument("--budget-minutes", type=float, default=30.0,
                   help="wall-clock budget per run, minutes (compile included)")
    p.add_argument("--num-envs", type=int, default=None, help="parallel envs (default: preset)")
    p.add_argument("--out", default="results", help="output directory (default results/)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", default=[],
                   help="override a training field for every run (see run.py --help)")
    p.add_argument("--env", action="append", metavar="KEY=VALUE", default=[],
                   help="override an env field for every run (see run.py --help)")
    args = p.parse_args(argv)
    if args.seeds < 1:
        p.error("--seeds must be >= 1")
    if args.first_seed < 0:
        p.error("--first-seed must be >= 0")
    try:
        overrides = schema.parse_overrides(TrainConfig, args.set, "--set")
        env_over = schema.parse_overrides(type(registry.default_config(args.task)), args.env,
                                          "--env")
    except schema.ConfigError as e:
        p.error(str(e))
    # lazy: imports JAX, and --help and argument errors stay JAX-free
    from daddpg_jax.analysis.reproduce import run_set

    summary = run_set(args.task, args.out, seeds=args.seeds, algos=args.algo,
                      ablations=args.ablations, env_steps=args.env_steps,
                      budget_minutes=args.budget_minutes, num_envs=args.num_envs,
                      overrides=overrides, env_overrides=env_over, first_seed=args.first_seed)
    print(f"\n{'label':14s} {'seed':>4s} {'env steps':>10s} {'wall s':>8s} {'final':>6s} "
          f"{'best':>6s} {'steps→0.9':>10s} {'contact':>8s}")
    for r in summary["final"]:
        print(f"{r['label']:14s} {r['seed']:4d} {r['env_steps']:10,d} {r['wall_time']:8.0f} "
              f"{r['final_test_success']:6.2f} {r['best_test_success']:6.2f} "
              f"{r['env_steps_to_0.9']:10.0f} {r['final_arm_contact_rate']:8.2f}")
    print(f"wrote {os.path.join(args.out, args.task)}/final.csv, curves.png, summary.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
