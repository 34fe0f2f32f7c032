"""Side by side on one machine: Stable-Baselines3 DDPG + HerReplayBuffer (through the Gymnasium
adapter) vs this project's trainer (``single`` and ``daddpg``), each capped in wall time.

    python experiments/sb3/compare_sb3.py --task reach --time-budget 600 --out runs/compare_sb3

Every method is trained in its own fresh Python process (so each pays its own start-up and
compilation), evaluated every --eval-every env steps on --eval-episodes deterministic episodes
from fixed seeds, and stopped when its training wall clock passes --time-budget (or, unless
--no-stop-at-target, as soon as it reaches --target test success). The report gives wall clock
and env steps to the target (or the best success reached) as a Markdown table and JSON.

Clocks. Ours: the runner's ``wall_time`` (from the first ``train_epoch`` call; includes the
compilation, the per-epoch evaluation and checkpoint writes). SB3: time inside ``model.learn``
with the clock paused during evaluations (evaluation is not charged to SB3). Neither counts
process start-up, imports or env construction.

SB3 settings follow the HER practice used by our trainer wherever SB3 has the knob: MLP
3 x 256 for actor and critic, Adam lr 1e-3, batch 256, gamma 0.98, Gaussian action noise 0.2,
HER future with n_sampled_goal 4, observation normalization (VecNormalize, clip 5), and the same
replay ratio (0.4 updates of 256 samples per env step: 20 gradient steps after every 50-step
episode). SB3 updates its target networks after every gradient step (tau 0.005, SB3's default)
and has no random-action probability or action L2 penalty. torch runs with one intra-op thread
(--torch-threads), and our trainer with XLA's CPU runtime on one thread
(XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"): on a busy
2-core machine more threads were much slower for both (docs/BENCHMARKS.md,
"Stable-Baselines3 side by side"); the methods single_mt / daddpg_mt run ours with XLA's
defaults.

Outputs in --out: results.json, results.md, ours_<algo>/ (a normal run directory) and
sb3_ddpg_her/metrics.csv (same columns as ours for env_steps, wall_time and the test rates), so
``experiments/plot.py OUT/ours_single OUT/ours_daddpg OUT/sb3_ddpg_her --out cmp.png`` plots all.
The harness is experiments/sb3/harness.py.
"""

from __future__ import annotations

import argparse
import os
import sys

from mjx_envs.registry import TASKS
from mjx_envs.settings import DEFAULT_TASK

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from experiments.sb3.harness import (  # noqa: E402
    DEFAULT_METHODS,
    METHODS,
    compare,
    run_worker,
)


def build_parser():
    p = argparse.ArgumentParser(prog="compare_sb3.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default=DEFAULT_TASK, choices=TASKS)
    p.add_argument("--time-budget", type=float, default=600.0, metavar="SECONDS",
                   help="training wall clock cap per method (default 600)")
    p.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                   help=f"comma-separated subset of {','.join(METHODS)} (default: "
                        f"{','.join(DEFAULT_METHODS)}); *_mt = ours with XLA's default "
                        "multi-threaded CPU runtime instead of one thread")
    p.add_argument("--target", type=float, default=0.9, help="test success to reach (default 0.9)")
    p.add_argument("--no-stop-at-target", action="store_true",
                   help="keep training until the time budget even after reaching --target")
    p.add_argument("--eval-episodes", type=int, default=100, help="fixed evaluation episodes (100)")
    p.add_argument("--eval-every", type=int, default=2000,
                   help="SB3: env steps between evaluations (default 2000 = one epoch of ours "
                        "on reach)")
    p.add_argument("--eval-seed", type=int, default=12345, help="seed of the evaluation episodes")
    p.add_argument("--seed", type=int, default=0, help="training seed")
    p.add_argument("--sb3-gradient-steps", type=int, default=20,
                   help="SB3 gradient steps after each 50-step episode (20 = our replay ratio)")
    p.add_argument("--num-envs", type=int, default=None, metavar="N",
                   help="parallel envs for every method (default: ours the preset's 2, SB3 one "
                        "env); with N, SB3 steps N envs in a DummyVecEnv and makes "
                        "--updates-per-cycle gradient steps after every 50 steps of all of them, "
                        "the same schedule as ours, and is evaluated once per epoch of ours")
    p.add_argument("--updates-per-cycle", type=int, default=None, metavar="U",
                   help="gradient updates per cycle (N envs x 50 steps) for every method "
                        "(default: the preset's 40); only with --num-envs for SB3")
    p.add_argument("--cycles-per-epoch", type=int, default=None, metavar="C",
                   help="ours: cycles between evaluations (default: the preset's, 20 on reach)")
    p.add_argument("--torch-threads", type=int, default=1,
                   help="torch intra-op threads for SB3 (default 1: on a busy 2-core machine two "
                        "OpenMP threads made a 256x256 matmul much slower than one; "
                        "docs/BENCHMARKS.md)")
    p.add_argument("--out", default="runs/compare_sb3", help="output directory")
    p.add_argument("--worker", choices=METHODS, default=None, help=argparse.SUPPRESS)
    return p



def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    if args.worker:
        run_worker(args)
        return 0
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    for flag in ("num_envs", "updates_per_cycle", "cycles_per_epoch"):
        v = getattr(args, flag)
        if v is not None and v < 1:
            print(f"error: --{flag.replace('_', '-')} must be >= 1, got {v}", file=sys.stderr)
            return 2
    bad = [m for m in methods if m not in METHODS]
    if bad:
        print(f"error: unknown method(s) {bad}; choose from {METHODS}", file=sys.stderr)
        return 2
    return compare(args, methods, argv)


if __name__ == "__main__":
    sys.exit(main())
