"""Evaluate a trained run: success rate (95% Wilson interval), arm-contact rate, final goal
distance per arm, over N deterministic episodes from fixed seeds; optionally a video.

Examples
  python experiments/evaluate.py runs/reach_s0                # latest checkpoint, 100 episodes
  python experiments/evaluate.py runs/reach_s0 --step 2 --episodes 500 --seed 7 --json
  MUJOCO_GL=egl python experiments/evaluate.py runs/reach_s0 --video reach.mp4
  python experiments/evaluate.py runs/push_s0 --perturb obs_noise=0,0.005,0.01,0.02 \
      --perturb latency=0,1,2 --perturb obs_dropout=0,0.1 --out runs/push_s0/perturbation

The default seed is the run's eval_seed, so with the default 100 episodes the success rate
equals the test_success_rate that metrics.csv logged for that checkpoint's epoch.
--perturb evaluates over a grid of observation/action perturbations and physics randomization
fields at exact values (the product of the values given; mjx_envs/perturb.py,
mjx_envs/randomize.py): OUT/perturbation.csv and .json (one row per
grid point) and OUT/perturbation.png (success against each perturbation).
Video: headless MuJoCo rendering (MUJOCO_GL=egl; Debian/Ubuntu packages libegl1 libegl-mesa0
libgl1-mesa-dri), mp4 through imageio-ffmpeg, else a GIF beside the requested path.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from mjx_envs.settings import PHYSICS

os.environ.setdefault("MUJOCO_GL", "egl")


def build_parser():
    p = argparse.ArgumentParser(prog="daddpg-evaluate", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", metavar="RUN_DIR", help="run directory written by experiments/run.py")
    p.add_argument("--step", type=int, default=None,
                   help="checkpoint (epoch) to load (default: the latest)")
    p.add_argument("--best", action="store_true",
                   help="load the run's best checkpoint (checkpoints_best/: the epoch of its "
                        "best test success) instead of the latest; evaluate it with another "
                        "--seed than the run's eval_seed to avoid measuring on the episodes "
                        "that chose it")
    p.add_argument("--episodes", type=int, default=100, help="evaluation episodes (default 100)")
    p.add_argument("--seed", type=int, default=None,
                   help="seed of the evaluation episodes (default: the run's eval_seed)")
    p.add_argument("--physics", choices=PHYSICS, default=None,
                   help="physics engine (default: the run's)")
    p.add_argument("--video", metavar="OUT.mp4", default=None,
                   help="render the first --video-episodes episodes one after another")
    p.add_argument("--video-episodes", type=int, default=3,
                   help="episodes in the video (default 3)")
    p.add_argument("--width", type=int, default=480, help="video width (default 480)")
    p.add_argument("--height", type=int, default=360, help="video height (default 360)")
    p.add_argument("--perturb", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="evaluate over a grid of perturbations (repeatable; one key each): "
                        "obs_noise (std, m), obs_dropout (probability per step), obs_bias (m), "
                        "obs_period (steps), latency (steps), and the physics randomization "
                        "fields at exact values: object_mass, object_size, object_friction, "
                        "table_height (object tasks), base_offset, base_yaw, finger_force, "
                        "action_scale (mjx_envs/randomize.py); needs --out")
    p.add_argument("--out", metavar="DIR", default=None,
                   help="with --perturb: directory for perturbation.csv/.json/.png")
    p.add_argument("--json", nargs="?", const="-", default=None, metavar="PATH",
                   help="write the results as JSON to PATH (or to stdout without PATH, instead "
                        "of the text summary)")
    return p


def _perturbation_grid(policy, args) -> int:
    from daddpg_jax.analysis import perturbation
    from mjx_envs.schema import ConfigError

    try:
        grid = perturbation.parse_grid(policy.cfg.task, args.perturb)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    n = len(perturbation.grid_points(grid))
    done = []

    def report(row):
        done.append(row)
        point = ", ".join(f"{k}={row[k]}" for k in grid)
        print(f"[{len(done)}/{n}] {point}: success {row['success_rate']:.3f}", flush=True)

    rows = perturbation.evaluate_grid(policy, grid, args.episodes, args.seed, report=report)
    meta = dict(run_dir=os.path.abspath(policy.run_dir), checkpoint=policy.step,
                best=policy.best,
                task=policy.cfg.task, algo=policy.cfg.algo,
                title=f"{policy.cfg.task} / {os.path.basename(os.path.abspath(policy.run_dir))}"
                      f" / {'best ' if policy.best else ''}checkpoint {policy.step}")
    paths = perturbation.write_outputs(rows, grid, args.out, meta)
    print("wrote " + ", ".join(paths.values()))
    return 0


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.episodes < 1:
        print("error: --episodes must be >= 1", file=sys.stderr)
        return 2
    if args.perturb and not args.out:
        print("error: --perturb needs --out DIR", file=sys.stderr)
        return 2
    if args.perturb and args.video:
        print("error: --perturb and --video exclude each other", file=sys.stderr)
        return 2

    from daddpg_jax.analysis import evaluation

    try:
        policy = evaluation.load_policy(args.run_dir, args.step, physics=args.physics,
                                        best=args.best)
    except evaluation.NoCheckpointError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    from daddpg_jax.running.runner import check_physics_backend
    from mjx_envs.schema import ConfigError

    try:   # MJX on a CPU hangs at large batches: refuse before compiling
        check_physics_backend(policy.env.physics, 1, args.episodes)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:   # sizes that cannot fit in memory are refused before allocating (ConfigError)
        if args.perturb:
            return _perturbation_grid(policy, args)
        summary, traj = evaluation.evaluate(policy, args.episodes, args.seed)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.video:
        try:
            written = evaluation.write_video(policy, traj, args.video, args.video_episodes,
                                             args.width, args.height)
        except evaluation.RenderUnavailable as e:
            print(f"error: {e}", file=sys.stderr)
            return 1
        if written != args.video:
            print(f"note: no mp4 writer (pip install imageio-ffmpeg); wrote a GIF: {written}",
                  file=sys.stderr)
        summary["video"] = os.path.abspath(written)
    if args.json == "-":
        print(json.dumps(summary, indent=2))
    else:
        print(evaluation.format_summary(summary))
        if args.video:
            print(f"video: {summary['video']} ({min(args.video_episodes, args.episodes)} episodes)")
        if args.json:
            with open(args.json, "w") as f:
                json.dump(summary, f, indent=2)
            print(f"json: {os.path.abspath(args.json)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
