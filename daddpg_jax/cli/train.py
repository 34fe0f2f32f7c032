"""Train two cooperating UR3 arms with DADDPG + HER (or a baseline variant).

Examples
  daddpg-train --task reach                          # the task's preset for this device
  daddpg-train --task reach --num-envs 2048          # the accelerator-sized run
  daddpg-train --task push --algo maddpg --her final --out runs/push_maddpg
  daddpg-train --resume runs/push_maddpg --epochs 200   # continue to 200 epochs
  daddpg-train --task push --out runs/push_maddpg --force   # replace that run
  daddpg-train --config runs/push_maddpg/config.json --seed 1   # rerun a recorded config
  daddpg-train --task reach --set gamma=0.95 --set hidden=64,64 --env team_scale=0.5
  daddpg-train --task pickup --demos 100             # + 100 scripted demonstrations
  daddpg-train --task push --robust                  # randomized physics, noisy late obs
  daddpg-train --task push --out runs/p --coordinator node0:12345 --num-processes 2 \
      --process-id 0                                 # one of 2 processes (docs/SCALING.md)
(`python experiments/run.py ...` is the same command.)

Outputs in RUN_DIR: config.json, metrics.csv, learning_curve.png, checkpoints/{epoch},
checkpoints_best/{epoch} (the best test success). --out must be new or empty (else --resume or
--force); a resume falls back to the newest readable checkpoint (docs/RELIABILITY.md).
The per-task preset (docs/TRAINING.md) depends on --num-envs and the device: batch size and
updates per cycle scale with num_envs so that the replay ratio stays near the HER baselines';
on an accelerator it also picks MJX physics and cycles per epoch. --set overrides any field.
"""

from __future__ import annotations

import argparse
import sys

from daddpg_jax.algo.config import guess_device
from daddpg_jax.algo.resolve import add_flags, check_flags, field_help, resolve_config
from daddpg_jax.running import distributed, tracking
from mjx_envs import registry
from mjx_envs.schema import ConfigError
from mjx_envs.settings import ENGINES


def build_parser(device: str | None = None):
    # --help and argument errors stay JAX-free: the device JAX would pick, guessed from what is
    # installed (the run itself asks JAX: resolve -> build_config)
    device = device or guess_device()
    p = argparse.ArgumentParser(
        prog="daddpg-train", description=__doc__, epilog=field_help(device),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    add_flags(p, device)   # the flag table: daddpg_jax/algo/resolve.py, FLAGS
    p.add_argument("--cross-check", choices=ENGINES, default=None, metavar="ENGINE",
                   help="at every evaluation also play the best checkpoint so far on ENGINE "
                        "(c or mjx: the engine other than --physics) over the same test "
                        "episodes: metrics.csv test_success_best and cross_success_best "
                        "(TensorBoard cross/*), and a closing warning when the two engines' "
                        "success parts by more than 0.10 (docs/MJX_VS_C.md); recorded in "
                        "config.json, kept by --resume; default off")
    distributed.add_flags(p)
    return p


def _usage_error(message: str):
    print(f"daddpg-train: error: {message}", file=sys.stderr, flush=True)
    raise SystemExit(2)


def prepare(argv=None):
    """Before the parser is built: joins a multi-process job when the flags or the cluster's
    variables ask for one (before anything else uses JAX), and imports --task-module (so that
    --task lists its task). The job's Layout or None; exits 2 with one line on failure."""
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    pre.add_argument("--task-module", default=None)
    try:
        layout = distributed.join_from_argv(argv)
        registry.import_task_module(pre.parse_known_args(argv)[0].task_module)
    except distributed.DistributedError as e:
        _usage_error(str(e))
    except ValueError as e:
        _usage_error(f"--task-module: {e}")
    return layout


def resolve(args, parser=None, check_out: bool = True):
    """(TrainConfig, env overrides, run dir) from the parsed flags; errors are ConfigError.
    check_out=False leaves a new run's directory unchecked (main claims it: run_dirs.claim)."""
    # lazy: these import JAX, and --help and argument errors stay JAX-free
    from daddpg_jax.running import cross_check, run_dirs
    from daddpg_jax.running.runner import check_physics_backend

    cfg, env_over = resolve_config(args, run_dirs.recorded)
    cfg = cross_check.apply_flag(cfg, args.cross_check, resumed=bool(args.resume))
    if args.for_c_engine and cross_check.resolved_physics(cfg.physics) != "mjx":
        raise ConfigError(f"--for-c-engine is a recipe for MJX training; this run trains on "
                          f"the C engine (physics {cfg.physics!r}): add --physics mjx, or leave "
                          "the flag out (a C-trained run needs no recipe to run on the C engine)")
    run_dir = run_dirs.resumed(args.resume, args.out) if args.resume else None
    check_physics_backend(cfg.physics, cfg.num_envs)
    if run_dir is None:
        run_dir = args.out or run_dirs.default_name(cfg)
        if check_out:
            run_dirs.check_out(run_dir, args.force)
    return cfg, env_over, run_dir


def main(argv=None):
    layout = prepare(argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    primary = layout is None or layout.process_id == 0
    try:
        check_flags(args)   # JAX-free: before the device
        from daddpg_jax.running import run_dirs  # lazy: imports JAX (as resolve does)
        cfg, env_over, run_dir = resolve(args, parser, check_out=False)
        loggers = tracking.loggers(run_dir, not args.no_tensorboard, args.wandb)
        run_dir = run_dirs.claim(run_dir, bool(args.resume), args.force, primary)
    except ConfigError as e:
        parser.error(str(e))
    try:
        return _run(args, layout, primary, cfg, env_over, run_dir, loggers)
    finally:
        if primary:
            run_dirs.unlock(run_dir)


def _run(args, layout, primary: bool, cfg, env_over, run_dir, loggers) -> int:
    """Trains with the resolved flags; the exit code. primary: this process writes output."""
    # lazy: --help and argument errors stay JAX-free
    from daddpg_jax.analysis import evaluation, plotting
    from daddpg_jax.running import progress, runner

    if primary:
        print(progress.header(cfg, run_dir), flush=True)
    T = registry.task_config(cfg.task, **env_over).episode_length
    # every process of a multi-process job compiles the same per-cycle callback
    bar = progress.Progress(cfg, T, show=primary, live=not args.no_progress,
                            same_program=layout is not None)
    opts = runner.RunOptions(run_dir, env_overrides=env_over, resume=bool(args.resume),
                             force=args.force, hooks=bar, loggers=loggers,
                             plot=plotting.plot_learning_curve, video=evaluation.train_video,
                             video_every=args.video_every, time_budget_s=args.time_budget,
                             stop_at_success=args.stop_at_success, command=" ".join(sys.argv))
    # the exit code of each known error, the first class that matches
    codes = {runner.NonFiniteLoss: 3, runner.CheckpointSaveError: 1, runner.RunDirError: 2,
             runner.CheckpointError: 2, distributed.DistributedError: 2, ConfigError: 2}
    try:
        res = runner.train(cfg, opts)
    except tuple(codes) as e:
        print(f"error: {e}", file=sys.stderr)
        return next(code for cls, code in codes.items() if isinstance(e, cls))
    except KeyboardInterrupt:
        print(f"\nstopped: interrupted; resume with: daddpg-train --resume {run_dir}",
              file=sys.stderr)
        return 130
    except Exception as e:   # noqa: BLE001  (one line unless --debug)
        if args.debug:
            raise
        print(f"error: {type(e).__name__}: {e} (rerun with --debug for the traceback; "
              f"resume with: daddpg-train --resume {run_dir})", file=sys.stderr)
        return 1
    finally:
        bar.close()
    if primary:
        print(res.summary(), flush=True)
        parted = res.cross_warning()   # --cross-check: the engines part at the best checkpoint
        if parted:
            print(f"warning: {parted}", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
