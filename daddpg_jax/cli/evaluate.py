"""Evaluate a trained run: success rate (95% Wilson interval), arm-contact rate, final goal
distance per arm, over N deterministic episodes from fixed seeds; optionally a video.

Examples
  python experiments/evaluate.py runs/reach_s0                # latest checkpoint, 100 episodes
  python experiments/evaluate.py runs/reach_s0 --step 2 --episodes 500 --seed 7 --json
  MUJOCO_GL=egl python experiments/evaluate.py runs/reach_s0 --video reach.mp4
  python experiments/evaluate.py runs/push_s0 --perturb obs_noise=0,0.005,0.01,0.02 \
      --perturb latency=0,1,2 --perturb obs_dropout=0,0.1 --out runs/push_s0/perturbation

  python experiments/evaluate.py runs/pickup_s0 --best --seed 2024 --episodes 64 \
      --physics c,mjx --divergence runs/pickup_s0/engines

The default seed is the run's eval_seed, so with the default 100 episodes the success rate
equals the test_success_rate that metrics.csv logged for that checkpoint's epoch.
--physics c,mjx evaluates the checkpoint on both engines over the same episodes: success per
engine (95% Wilson interval), final goal distances, arm-contact and physics-fault rates, and the
success difference with its paired 95% Newcombe interval; --divergence OUT writes
OUT/divergence.csv and .png: per control step, how far the object centres and grip points of
the two engines' closed-loop trajectories are apart.
MJX on a CPU runs the episodes in chunks (--chunk, default 32) under a watchdog (--watchdog,
default 120 s per chunk after compilation): a chunk that makes no progress is started again
once, then the evaluation stops with one line (exit code 3). Results do not depend on the chunk
size (every episode keeps its reset key).
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

os.environ.setdefault("MUJOCO_GL", "egl")   # before MuJoCo is first imported (below)

from daddpg_jax.analysis import engines, evaluation, perturbation  # noqa: E402
from mjx_envs.schema import ConfigError  # noqa: E402
from mjx_envs.settings import PHYSICS, PHYSICS_VERSION  # noqa: E402


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
    p.add_argument("--physics", default=None, metavar="ENGINE[,ENGINE]",
                   help=f"physics engine ({', '.join(PHYSICS)}; default: the run's), or two "
                        "engines to compare over the same episodes, e.g. c,mjx")
    p.add_argument("--physics-version", type=int, default=None, metavar="N",
                   help="simulate physics version N (1 to the current one, "
                        "mjx_envs.settings.PHYSICS_VERSION) instead of the one the run was "
                        "trained on (default, recorded in its config.json); e.g. an older run "
                        "on today's physics")
    p.add_argument("--divergence", metavar="OUT_DIR", default=None,
                   help="with two engines: write OUT_DIR/divergence.csv and .png (object and "
                        "grip-point distances between the engines per control step)")
    p.add_argument("--chunk", type=int, default=None, metavar="N",
                   help=f"episodes per batch (default: {evaluation.MJX_CPU_CHUNK} for MJX on a "
                        "CPU, else all at once); results do not depend on it")
    p.add_argument("--watchdog", type=float, default=None, metavar="SECONDS",
                   help=f"seconds a chunk may run (after compiling) before it is started again "
                        f"once, then the run stops (default: {evaluation.WATCHDOG_SECONDS:g} "
                        "for MJX on a CPU, else none; 0: none)")
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


def _check_args(args) -> tuple | str:
    """The engines to use, or a one-line error."""
    if args.episodes < 1:
        return "--episodes must be >= 1"
    if args.chunk is not None and args.chunk < 1:
        return "--chunk must be >= 1"
    if args.watchdog is not None and args.watchdog < 0:
        return "--watchdog must be >= 0 (0: none)"
    if args.perturb and not args.out:
        return "--perturb needs --out DIR"
    if args.perturb and args.video:
        return "--perturb and --video exclude each other"
    try:
        names = (None,) if args.physics is None else engines.parse_engines(args.physics)
    except ConfigError as e:
        return str(e)
    if len(names) > 1 and (args.perturb or args.video):
        return "--perturb and --video take one engine, not a comparison"
    if args.physics_version is not None and not 1 <= args.physics_version <= PHYSICS_VERSION:
        return f"--physics-version must be in [1, {PHYSICS_VERSION}], got {args.physics_version}"
    if args.divergence and len(names) < 2:
        return "--divergence needs two engines, e.g. --physics c,mjx"
    return names


def _print_result(summary: dict, args, text: str) -> None:
    if args.json == "-":
        print(json.dumps(summary, indent=2))
        return
    print(text)
    if args.video:
        print(f"video: {summary['video']} ({min(args.video_episodes, args.episodes)} episodes)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(summary, f, indent=2)
        print(f"json: {os.path.abspath(args.json)}")


def _compare(policies: dict, args, opts: dict) -> int:
    def report(name, s):
        if args.json != "-":
            print(f"{name}: success {s['success_rate']:.3f} ({s['eval_seconds']:.0f} s)",
                  flush=True)

    summary, text = engines.compare_report(policies, args.episodes, args.seed,
                                           divergence_dir=args.divergence, report=report, **opts)
    _print_result(summary, args, text)
    return 0


def _evaluate_one(policy, args, opts: dict) -> int:
    if args.perturb:   # a bad grid is a ConfigError: one line, exit 2 (main)
        grid = perturbation.parse_grid(policy.cfg.task, args.perturb)
        paths = perturbation.run_grid(policy, grid, args.episodes, args.seed, args.out,
                                      log=lambda line: print(line, flush=True), **opts)
        print("wrote " + ", ".join(paths.values()))
        return 0
    summary, traj = evaluation.evaluate(policy, args.episodes, args.seed, **opts)
    if args.video:
        try:
            note = evaluation.add_video(summary, policy, traj, args.video, args.video_episodes,
                                        args.width, args.height)
        except evaluation.RenderUnavailable as e:
            print(f"error: {e}", file=sys.stderr)
            return 1
        if note:
            print(note, file=sys.stderr)
    _print_result(summary, args, evaluation.format_summary(summary))
    return 0


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    names = _check_args(args)
    if isinstance(names, str):
        print(f"error: {names}", file=sys.stderr)
        return 2
    try:
        policies = {name: evaluation.load_policy(args.run_dir, args.step, physics=name,
                                                 best=args.best,
                                                 physics_version=args.physics_version)
                    for name in names}
    except evaluation.NoCheckpointError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    opts = dict(chunk="auto" if args.chunk is None else args.chunk,
                watchdog="auto" if args.watchdog is None else (args.watchdog or None))
    try:
        if len(policies) > 1:
            return _compare(policies, args, opts)
        return _evaluate_one(next(iter(policies.values())), args, opts)
    except ConfigError as e:   # e.g. sizes that cannot fit in memory, refused before allocating
        print(f"error: {e}", file=sys.stderr)
        return 2
    except evaluation.EngineHang as e:
        # the hung engine thread cannot be stopped, and interpreter shutdown could wait on it
        print(f"error: {e}; try a smaller --chunk or --physics c", file=sys.stderr, flush=True)
        sys.stdout.flush()
        os._exit(3)


if __name__ == "__main__":
    sys.exit(main())
