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
import os
import sys

from daddpg_jax.algo.config import DEVICES, HER_MODES, PHYSICS, TrainConfig, guess_device
from daddpg_jax.algo.resolve import field_help, resolve_config
from daddpg_jax.algo.variants import ALGOS, VARIANTS
from daddpg_jax.running import distributed, tracking
from mjx_envs import registry, schema, settings
from mjx_envs.schema import ConfigError


def build_parser(device: str | None = None):
    # --help and argument errors stay JAX-free: the device JAX would pick, guessed from what is
    # installed (the run itself asks JAX: resolve -> build_config)
    device = device or guess_device()
    p = argparse.ArgumentParser(
        prog="daddpg-train", description=__doc__, epilog=field_help(device),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", choices=settings.TASKS, default=None,
                   help="task to train (default reach; taken from config.json with --resume "
                        "or --config)")
    p.add_argument("--task-module", default=None, metavar="MODULE",
                   help="module that registers a task defined outside this package (recorded "
                        "in config.json as task_module; docs/TASKS.md, 'Adding a task')")
    p.add_argument("--num-envs", type=int, default=None,
                   help="parallel environments; the task preset scales batch size and updates "
                        "per cycle with it (default: the preset's: 2 on a CPU, 4096 on an "
                        "accelerator)")
    p.add_argument("--device", choices=DEVICES, default=None,
                   help=f"device whose preset to use (default: the one JAX runs on, {device})")
    p.add_argument("--epochs", type=int, default=None,
                   help="total epochs (an epoch = n_cycles cycles + evaluation); with --resume "
                        "the run continues until this many epochs are done (default: preset)")
    p.add_argument("--seed", type=int, default=None, help="training seed (default 0)")
    p.add_argument("--algo", choices=ALGOS, default=None,
                   help="; ".join(f"{v.name}: {v.doc}" for v in VARIANTS.values()))
    p.add_argument("--her", choices=HER_MODES, default=None,
                   help="hindsight relabelling strategy (future uses k=4: 80%% relabelled)")
    p.add_argument("--physics", choices=PHYSICS, default=None,
                   help="physics engine: auto = MJX on an accelerator, MuJoCo C engine on CPU")
    p.add_argument("--out", default=None,
                   help="run directory (default runs/<task>_<algo>_s<seed>_<time>); must be "
                        "new or empty unless --force")
    p.add_argument("--force", action="store_true",
                   help="with --out: delete the run already in that directory (its config.json, "
                        "metrics.csv, learning_curve.png, checkpoints*) and start a new one "
                        "(refused for a directory that holds no run)")
    p.add_argument("--resume", metavar="RUN_DIR", default=None,
                   help="continue the run in RUN_DIR from its newest readable checkpoint (its "
                        "config.json is reused; --epochs may raise the total; a run stopped "
                        "before its first checkpoint starts again from epoch 0)")
    p.add_argument("--config", metavar="CONFIG_JSON", default=None,
                   help="start a new run from a recorded configuration (RUN/config.json or "
                        "RUN): its training fields and env overrides; flags given with it "
                        "override them")
    p.add_argument("--save-buffer", action="store_true",
                   help="store the replay buffer in checkpoints (large; makes --resume "
                        "bit-exact)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", default=[],
                   help="override any training field (listed below); repeatable")
    p.add_argument("--env", action="append", metavar="KEY=VALUE", default=[],
                   help="override any env field of the task (listed below); repeatable")
    p.add_argument("--robust", action="store_true",
                   help="train with the robust preset: per-episode observation noise, "
                        "dropout, bias, action latency and physics randomization "
                        "(daddpg_jax.algo.config.ROBUST_ENV; test episodes stay nominal), and "
                        "each arm's last action in its observation (ROBUST_OBS: "
                        "action_history=1, kept in test episodes and exports); --env overrides "
                        "single fields; docs/ENVIRONMENTS.md")
    p.add_argument("--demos", type=int, default=None, metavar="N",
                   help="play N episodes of the task's scripted controller at the start and "
                        "train on them beside the replay, with a behaviour-cloning term (push, "
                        "pickup, pot; not in the paper; same as --set n_demos=N; default 0 = "
                        "off; docs/TRAINING.md#demonstrations)")
    p.add_argument("--time-budget", type=float, default=None, metavar="SECONDS",
                   help="stop after the epoch during which this much wall time has passed")
    p.add_argument("--stop-at-success", type=float, default=None, metavar="RATE",
                   help="stop after the first epoch whose test success rate is at least RATE "
                        "(e.g. 0.9: time-to-target benchmarks)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar, only one line per epoch (the default when stderr is "
                        "not a terminal)")
    p.add_argument("--no-tensorboard", action="store_true",
                   help="do not write TensorBoard event files (RUN_DIR/tensorboard; default: "
                        "every metrics.csv column against env steps, and the config as text)")
    p.add_argument("--wandb", nargs="?", const="daddpg-jax", default=None, metavar="PROJECT",
                   help="also log to Weights & Biases, project PROJECT (default daddpg-jax); "
                        "needs the optional extra: pip install 'daddpg-jax[wandb]'; "
                        "WANDB_MODE=offline logs to RUN_DIR/wandb without an account")
    p.add_argument("--video-every", type=int, default=0, metavar="N",
                   help="every N epochs, render test episodes to RUN_DIR/videos/epoch_N.mp4 "
                        "and to TensorBoard (needs MUJOCO_GL=egl and imageio; without a "
                        "renderer: one warning, training goes on; default 0 = never)")
    p.add_argument("--debug", action="store_true",
                   help="show the traceback of an unexpected error (default: one line)")
    _add_distributed_flags(p)
    return p


def _add_distributed_flags(p) -> None:
    g = p.add_argument_group(
        "multi-process training (docs/SCALING.md; every process runs the same command, only "
        "--process-id differs; without these flags the cluster's variables are used when they "
        "show more than one process, e.g. SLURM's srun)")
    g.add_argument("--coordinator", metavar="HOST:PORT", default=None,
                   help="address of process 0, which runs the job's coordinator")
    g.add_argument("--num-processes", type=int, default=None, metavar="N",
                   help="number of processes in the job")
    g.add_argument("--process-id", type=int, default=None, metavar="I",
                   help="this process's id, 0 .. N-1 (process 0 writes the run's files)")
    g.add_argument("--distributed-timeout", type=float, default=distributed.DEFAULT_TIMEOUT,
                   metavar="SECONDS",
                   help="give up joining the job after this long, with an error "
                        f"(default {distributed.DEFAULT_TIMEOUT:g})")


def join_job(argv=None):
    """Joins a multi-process job when the flags or the cluster's variables ask for one (before
    anything else uses JAX); returns its Layout or None. Exits 2 with one line on failure."""
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    _add_distributed_flags(pre)
    args, _ = pre.parse_known_args(argv)
    try:
        return distributed.join(args.coordinator, args.num_processes, args.process_id,
                                timeout=args.distributed_timeout)
    except distributed.DistributedError as e:
        print(f"daddpg-train: error: {e}", file=sys.stderr, flush=True)
        sys.exit(2)


def resolve(args, parser=None, check_out: bool = True):
    """(TrainConfig, env overrides, run dir) from the parsed flags; errors are ConfigError.
    check_out=False leaves a new run's directory unchecked (main claims it: run_dirs.claim_new)."""
    # lazy: these import JAX, and --help and argument errors stay JAX-free
    from daddpg_jax.running import run_dirs
    from daddpg_jax.running.runner import check_physics_backend

    cfg, env_over = resolve_config(args, run_dirs.recorded)
    run_dir = run_dirs.resumed(args.resume, args.out) if args.resume else None
    check_physics_backend(cfg.physics, cfg.num_envs)
    if run_dir is None:
        run_dir = args.out or run_dirs.default_name(cfg)
        if check_out:
            run_dirs.check_out(run_dir, args.force)
    return cfg, env_over, run_dir




def _loggers(args, run_dir: str) -> list:
    """The experiment trackers the flags ask for: TensorBoard unless --no-tensorboard, W&B with
    --wandb (ConfigError when wandb is not installed)."""
    out = [] if args.no_tensorboard else [tracking.TensorBoardLogger(run_dir)]
    if args.wandb:
        out.append(tracking.WandbLogger(run_dir, project=args.wandb))
    return out


def import_task_module(argv) -> None:
    """Imports --task-module before the parser is built, so that --task lists its task."""
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    pre.add_argument("--task-module", default=None)
    try:
        registry.import_task_module(pre.parse_known_args(argv)[0].task_module)
    except ValueError as e:
        print(f"daddpg-train: error: --task-module: {e}", file=sys.stderr)
        raise SystemExit(2) from None


def main(argv=None):
    layout = join_job(argv)
    import_task_module(argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.stop_at_success is not None and not 0.0 <= args.stop_at_success <= 1.0:
        parser.error(f"--stop-at-success must be in [0, 1], got {args.stop_at_success}")
    if args.video_every < 0:
        parser.error(f"--video-every must be >= 0, got {args.video_every}")
    try:
        schema.parse_overrides(TrainConfig, args.set, "--set")   # JAX-free: before the device
        cfg, env_over, run_dir = resolve(args, parser, check_out=False)
        loggers = _loggers(args, run_dir)
        # lazy: imports JAX, and --help and argument errors stay JAX-free
        from daddpg_jax.running import run_dirs

        if not args.resume:
            run_dir = run_dirs.claim_new(run_dir, args.force)
        elif layout is None or layout.process_id == 0:
            run_dirs.lock(run_dir)
    except ConfigError as e:
        parser.error(str(e))
    try:
        return _run(args, layout, cfg, env_over, run_dir, loggers)
    finally:
        if layout is None or layout.process_id == 0:
            run_dirs.unlock(run_dir)


def _run(args, layout, cfg, env_over, run_dir, loggers) -> int:
    """Trains with the resolved flags; the exit code."""
    # lazy: --help and argument errors stay JAX-free
    from daddpg_jax.analysis import evaluation, plotting
    from daddpg_jax.running import runner
    from daddpg_jax.running.distributed import DistributedError
    from daddpg_jax.running.progress import Progress
    from daddpg_jax.running.runner import (
        CheckpointError,
        CheckpointSaveError,
        NonFiniteLoss,
        RunDirError,
        RunOptions,
    )

    primary = layout is None or layout.process_id == 0
    if primary:
        _print_header(cfg, run_dir)
    T = settings.task_config(cfg.task, **env_over).episode_length
    # every process of a multi-process job compiles the same per-cycle callback
    bar = Progress(cfg, T, show=primary, live=not args.no_progress,
                   same_program=layout is not None)
    opts = RunOptions(run_dir, env_overrides=env_over, resume=bool(args.resume),
                      force=args.force, hooks=bar, loggers=loggers,
                      plot=plotting.plot_learning_curve, video=evaluation.train_video,
                      video_every=args.video_every, time_budget_s=args.time_budget,
                      stop_at_success=args.stop_at_success, command=" ".join(sys.argv))
    try:
        res = runner.train(cfg, opts)
    except NonFiniteLoss as e:
        print(f"error: {e}", file=sys.stderr)
        return 3
    except CheckpointSaveError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except (RunDirError, CheckpointError, DistributedError, ConfigError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
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
        print(res.summary())
    return 0


def _print_header(cfg: TrainConfig, run_dir: str) -> None:
    print(f"run dir: {os.path.abspath(run_dir)}")
    print(f"task {cfg.task}, algo {cfg.algo}, her {cfg.her}, num_envs {cfg.num_envs}, batch "
          f"{cfg.batch_size} x {cfg.n_batches} updates/cycle, {cfg.n_cycles} cycles/epoch, "
          f"{cfg.n_epochs} epochs", flush=True)
    if cfg.n_demos > 0:
        print(f"demonstrations: {cfg.n_demos} scripted episodes (not counted in env steps), "
              f"{cfg.demo_batch} demo transitions per update, bc_weight {cfg.bc_weight}, "
              f"q_filter {cfg.q_filter}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
