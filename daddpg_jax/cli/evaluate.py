"""Evaluate a trained run: success rate (95% Wilson interval), arm-contact rate, final goal
distance per arm, over N deterministic episodes from fixed seeds; optionally a video, two
physics engines over the same episodes (--physics c,mjx), or a grid of perturbations
(--perturb). Details: docs/TOOLS.md, "Evaluating a checkpoint".

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
Exit codes: 0 done; 1 no GL context for --video; 2 bad arguments, no checkpoint, or sizes that
do not fit in memory; 3 an MJX chunk made no progress twice (--watchdog).
"""

from __future__ import annotations

import argparse
import json
import os
import sys

os.environ.setdefault("MUJOCO_GL", "egl")   # before MuJoCo is first imported (below)

from daddpg_jax.algo import resolve  # noqa: E402
from daddpg_jax.analysis import engines, evaluation, perturbation  # noqa: E402
from daddpg_jax.running import run_dirs  # noqa: E402
from mjx_envs import episode_starts  # noqa: E402
from mjx_envs.randomize import OBJECT_FIELDS  # noqa: E402
from mjx_envs.schema import ConfigError  # noqa: E402
from mjx_envs.settings import PHYSICS, RANDOMIZATION_FIELDS  # noqa: E402


def build_parser():
    p = argparse.ArgumentParser(prog="daddpg-evaluate", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add = p.add_argument
    add("run_dir", metavar="RUN_DIR", help="run directory written by experiments/run.py")
    add("--step", type=int, default=None, help="checkpoint (epoch) to load (default: the latest)")
    add("--best", action="store_true",
        help="load the run's best checkpoint (checkpoints_best/: the epoch of its best test "
             "success) instead of the latest; evaluate it with another --seed than the run's "
             "eval_seed to avoid measuring on the episodes that chose it")
    add("--episodes", type=int, default=100, help="evaluation episodes (default 100)")
    add("--seed", type=int, default=None,
        help="seed of the evaluation episodes (default: the run's eval_seed)")
    add("--physics", default=None, metavar="ENGINE[,ENGINE]",
        help=f"physics engine ({', '.join(PHYSICS)}; default: the run's), or two engines to "
             "compare over the same episodes, e.g. c,mjx (success per engine, and their "
             "difference with its paired 95%% Newcombe interval)")
    add("--physics-version", type=int, default=None, metavar="N",
        help="simulate physics version N (1 to mjx_envs.settings.LATEST_PHYSICS_VERSION; "
             "the current one: PHYSICS_VERSION) instead of the one the run was trained on "
             "(default, recorded in its config.json); e.g. an older run on today's physics")
    add("--limits", metavar="FILE", default=None,
        help="evaluate through a robot limits file's rules (daddpg-robot-client --limits): "
             "every action passes its workspace boxes, speed cap, arm clearance and finger "
             "range, as the robot client's safety layer applies them")
    add("--speed-scale", type=float, default=None, metavar="S",
        help="with --limits: its max_speed x S, S in (0, 1] (default 1)")
    add("--divergence", metavar="OUT_DIR", default=None,
        help="with two engines: write OUT_DIR/divergence.csv and .png (object and grip-point "
             "distances between the engines' closed-loop trajectories per control step)")
    add("--chunk", type=int, default=None, metavar="N",
        help=f"episodes per batch (default: {evaluation.MJX_CPU_CHUNK} for MJX on a CPU, else "
             "all at once); results do not depend on it (every episode keeps its reset key)")
    add("--watchdog", type=float, default=None, metavar="SECONDS",
        help=f"seconds a chunk may run (after compiling) before it is started again once, then "
             f"the run stops with exit code 3 (default: {evaluation.WATCHDOG_SECONDS:g} for MJX "
             "on a CPU, else none; 0: none)")
    add("--video", metavar="OUT.mp4", default=None,
        help="render the first --video-episodes episodes one after another (headless: "
             "MUJOCO_GL=egl; mp4 through imageio-ffmpeg, else a GIF beside the path)")
    add("--video-episodes", type=int, default=3, help="episodes in the video (default 3)")
    add("--width", type=int, default=480, help="video width (default 480)")
    add("--height", type=int, default=360, help="video height (default 360)")
    add("--perturb", action="append", default=[], metavar="KEY=V1,V2,...",
        help="evaluate over a grid of perturbations, the product of the values given "
             "(repeatable; one key each): obs_noise (std, m), obs_dropout (probability per "
             "step), obs_bias (m), obs_period (steps), latency (steps), and the physics "
             f"randomization fields at exact values: {', '.join(OBJECT_FIELDS)} (object tasks), "
             f"{', '.join(f for f in RANDOMIZATION_FIELDS if f not in OBJECT_FIELDS)} "
             "(mjx_envs/perturb.py, mjx_envs/randomize.py); needs --out")
    add("--out", metavar="DIR", default=None,
        help="with --perturb: directory for perturbation.csv and .json (one row per grid "
             "point) and perturbation.png (success against each perturbation)")
    add("--save-starts", metavar="FILE.npz", default=None,
        help="one engine: write the episodes' goals and initial states, with the success of "
             "each, for daddpg-robot-client --starts FILE (the same episodes on the robot "
             "side, paired with these)")
    add("--json", nargs="?", const="-", default=None, metavar="PATH",
        help="write the results as JSON to PATH (or to stdout without PATH, instead of the "
             "text summary)")
    return p


def _print_result(summary: dict, args, text: str) -> None:
    if args.json == "-":
        print(json.dumps(summary, indent=2))
        return
    print(text)
    if args.video:
        print(f"video: {summary['video']} ({min(args.video_episodes, args.episodes)} episodes)")
    if summary.get("starts"):
        print(f"starts: {summary['starts']} (daddpg-robot-client --starts)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(summary, f, indent=2)
        print(f"json: {os.path.abspath(args.json)}")


def _run(policies: dict, args, opts: dict) -> int:
    """Compares two engines, evaluates the --perturb grid, or evaluates one engine (a video)."""
    if len(policies) > 1:
        def report(name, s):
            if args.json != "-":
                print(f"{name}: success {s['success_rate']:.3f} ({s['eval_seconds']:.0f} s)",
                      flush=True)

        summary, text = engines.compare_report(policies, args.episodes, args.seed,
                                               divergence_dir=args.divergence, report=report,
                                               **opts)
        _print_result(summary, args, text)
        return 0
    policy = next(iter(policies.values()))
    if args.perturb:   # a bad grid is a ConfigError: one line, exit 2 (main)
        paths = perturbation.run_items(policy, args.perturb, args.episodes, args.seed, args.out,
                                       log=lambda line: print(line, flush=True), **opts)
        print("wrote " + ", ".join(paths.values()))
        return 0
    summary, traj = evaluation.evaluate(policy, args.episodes, args.seed, **opts)
    if args.save_starts:
        summary["starts"] = episode_starts.save(
            args.save_starts, summary["task"], traj["goal"], traj["qpos"][:, 0],
            traj["success"], **{k: summary[k] for k in STARTS_META})
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


STARTS_META = ("seed", "episodes", "run_dir", "checkpoint", "best", "physics",
               "physics_version")
"""the evaluation's fields that --save-starts records in the file"""


def _limits(args) -> tuple | None:
    """The ``robot_limits`` env setting of --limits / --speed-scale (None without --limits)."""
    if args.limits is None:
        if args.speed_scale is not None:
            raise ConfigError("--speed-scale needs --limits")
        return None
    cfg, env_over = run_dirs.recorded(args.run_dir)
    return resolve.limits_values(args.limits, args.speed_scale, cfg.task, env_over)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        names = engines.check_request(args.physics, args.episodes, args.chunk, args.watchdog,
                                      args.perturb, args.out, args.video, args.physics_version,
                                      args.divergence)
        limits = _limits(args)
        if args.save_starts and (len(names) > 1 or args.perturb):
            raise ConfigError("--save-starts takes one --physics engine and no --perturb")
        policies = {name: evaluation.load_policy(args.run_dir, args.step, physics=name,
                                                 best=args.best,
                                                 physics_version=args.physics_version,
                                                 robot_limits=limits)
                    for name in names}
        return _run(policies, args, evaluation.chunk_options(args.chunk, args.watchdog))
    except (ConfigError, evaluation.NoCheckpointError) as e:
        # ConfigError also for sizes that cannot fit in memory, refused before allocating
        print(f"error: {e}", file=sys.stderr)
        return 2
    except evaluation.EngineHang as e:
        # the hung engine thread cannot be stopped, and interpreter shutdown could wait on it
        print(f"error: {e}; try a smaller --chunk or --physics c", file=sys.stderr, flush=True)
        sys.stdout.flush()
        os._exit(3)


if __name__ == "__main__":
    sys.exit(main())
