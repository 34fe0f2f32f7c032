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
import textwrap
import time

from daddpg_jax.algo.config import (
    DEVICES,
    HER_MODES,
    PHYSICS,
    TrainConfig,
    build_config,
    preset,
    preset_env,
    robust_env,
)
from daddpg_jax.algo.variants import ALGOS, VARIANTS
from mjx_envs import schema, settings
from mjx_envs.schema import ConfigError

# flags that are also TrainConfig fields: flag attribute -> field
_FIELD_FLAGS = ("algo", "her", "physics", "seed")


def help_epilog(device: str) -> str:
    """The field listing of --help: every training field with its value for each task at the
    default num_envs on `device`, and every env field with each task's value."""
    tasks = settings.TASKS
    cfgs = {t: build_config(t, device=device) for t in tasks}
    envs = {t: settings.task_config(t, **preset_env(t)) for t in tasks}
    head = " | ".join(tasks)
    out = [f"training fields for --set KEY=VALUE (value for {head} at the default --num-envs "
           f"on {device}; meaning):"]
    out += _field_lines(TrainConfig, cfgs)
    out += ["", f"env fields for --env KEY=VALUE (value for {head} in a new run, with the "
            "task's training preset; '-' where a task lacks the field; meaning):"]
    # the task config class with the most fields holds every other task's (e.g. pickup's)
    out += _field_lines(max((type(e) for e in envs.values()), key=lambda c: len(schema.fields(c))),
                        envs)
    return "\n".join(out)


def _field_lines(cls, objs: dict) -> list:
    docs = schema.docs(cls)
    lines = []
    for name in schema.fields(cls):
        vals = [schema.describe_value(getattr(o, name)) if hasattr(o, name) else "-"
                for o in objs.values()]
        shown = vals[0] if len(set(vals)) == 1 else " | ".join(vals)
        lines.append(textwrap.fill(f"{name} ({shown}): {docs[name]}", width=100,
                                   initial_indent="  ", subsequent_indent="      ",
                                   break_on_hyphens=False, break_long_words=False))
    return lines


def build_parser(device: str | None = None):
    from daddpg_jax.algo.config import guess_device

    # --help and argument errors stay JAX-free: the device JAX would pick, guessed from what is
    # installed (the run itself asks JAX: resolve -> build_config)
    device = device or guess_device()
    p = argparse.ArgumentParser(
        prog="daddpg-train", description=__doc__, epilog=help_epilog(device),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", choices=settings.TASKS, default=None,
                   help="task to train (default reach; taken from config.json with --resume "
                        "or --config)")
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
    from daddpg_jax.running.distributed import DEFAULT_TIMEOUT

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
    g.add_argument("--distributed-timeout", type=float, default=DEFAULT_TIMEOUT,
                   metavar="SECONDS",
                   help="give up joining the job after this long, with an error "
                        f"(default {DEFAULT_TIMEOUT:g})")


def join_job(argv=None):
    """Joins a multi-process job when the flags or the cluster's variables ask for one (before
    anything else uses JAX); returns its Layout or None. Exits 2 with one line on failure."""
    from daddpg_jax.running import distributed

    pre = argparse.ArgumentParser(add_help=False)
    _add_distributed_flags(pre)
    args, _ = pre.parse_known_args(argv)
    try:
        return distributed.join(args.coordinator, args.num_processes, args.process_id,
                                timeout=args.distributed_timeout)
    except distributed.DistributedError as e:
        print(f"daddpg-train: error: {e}", file=sys.stderr, flush=True)
        sys.exit(2)


def _recorded(path: str):
    """(TrainConfig, env overrides) of a config.json (or of a run directory holding one)."""
    from daddpg_jax.running import checkpoint as ckpt

    run_dir = path if os.path.isdir(path) else os.path.dirname(os.path.abspath(path))
    if not os.path.exists(os.path.join(run_dir, "config.json")):
        raise ConfigError(f"{path}: no config.json there")
    try:
        cfg, payload = ckpt.load_config(run_dir)
    except ckpt.ConfigFileError as e:
        raise ConfigError(str(e)) from None
    return cfg, dict(payload.get("env_overrides", {}))


def _check_out(path: str, force: bool) -> None:
    """A new run's directory: new, empty, or (with force) a run to replace; else ConfigError."""
    if os.path.exists(path) and not os.path.isdir(path):
        raise ConfigError(f"--out {path}: is a file, not a directory")
    parent = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise ConfigError(f"--out {path}: {parent} is a file, not a directory")
    from daddpg_jax.running import checkpoint as ckpt

    if ckpt.is_empty_run_dir(path):
        return
    if not force:
        what = "a run" if ckpt.is_run_dir(path) else "other files"
        raise ConfigError(f"--out {path}: directory is not empty (it holds {what}); continue "
                          f"a run with --resume {path}, replace it with --force, or choose "
                          "another --out")
    if not ckpt.is_run_dir(path):
        raise ConfigError(f"--out {path}: --force replaces only a run (a directory with the "
                          "config.json of a run), and it holds other files")


def resolve(args, parser, check_out: bool = True):
    """(TrainConfig, env overrides, run dir) from the parsed flags; errors are ConfigError.
    check_out=False leaves a new run's directory unchecked (see `_new_run_dir`)."""
    if args.resume and args.config:
        raise ConfigError("--resume and --config exclude each other")
    if args.resume and args.force:
        raise ConfigError("--resume and --force exclude each other (--force deletes the run)")
    if args.force and not args.out:
        raise ConfigError("--force needs --out (the run directory to replace)")
    if args.resume:
        cfg, env_over = _recorded(args.resume)
        for name in ("task", "num_envs", *_FIELD_FLAGS):
            v = getattr(args, name)
            if v is not None and v != getattr(cfg, name):
                raise ConfigError(f"--resume: --{name.replace('_', '-')} differs from the run's "
                                  f"config ({getattr(cfg, name)!r}); start a new run instead")
        if args.robust:
            raise ConfigError("--resume: --robust is decided by the run's config; start a new "
                              "run instead")
        if args.demos is not None and args.demos != cfg.n_demos:
            raise ConfigError(f"--resume: --demos differs from the run's config "
                              f"({cfg.n_demos}); start a new run instead")
        run_dir = args.resume if os.path.isdir(args.resume) else os.path.dirname(
            os.path.abspath(args.resume))
        if args.out and os.path.abspath(args.out) != os.path.abspath(run_dir):
            raise ConfigError("--resume continues the run in its own directory; drop --out")
    elif args.config:
        cfg, env_over = _recorded(args.config)
        if args.task is not None or args.num_envs is not None:
            # a new task or size: that preset's fields replace the recorded ones
            cfg = cfg.replace(**preset(args.task or cfg.task, args.num_envs or cfg.num_envs,
                                       device=args.device))
        run_dir = None
    else:
        task = args.task or "reach"
        cfg, env_over = build_config(task, args.num_envs, device=args.device), preset_env(task)
        run_dir = None
    if args.robust:   # a resume refused --robust above
        env_over.update(robust_env(cfg.task))
    over = {k: getattr(args, k) for k in _FIELD_FLAGS if getattr(args, k) is not None}
    over.update(schema.parse_overrides(TrainConfig, args.set, "--set"))
    if args.epochs is not None:
        over["n_epochs"] = args.epochs
    if args.save_buffer:
        over["save_buffer"] = True
    if args.demos is not None:
        over["n_demos"] = args.demos
    cfg = cfg.replace(**over)
    env_cls = type(settings.default_config(cfg.task))
    env_over.update(schema.parse_overrides(env_cls, args.env, "--env"))
    settings.task_config(cfg.task, **env_over)   # validates the env fields together
    if cfg.n_demos > 0:
        from mjx_envs.tasks import scripted

        if cfg.task not in scripted.POLICIES:
            raise ConfigError(f"--demos: task {cfg.task!r} has no scripted controller "
                              f"(available: {', '.join(sorted(scripted.POLICIES))})")
    from daddpg_jax.running.runner import check_physics_backend

    check_physics_backend(cfg.physics, cfg.num_envs)
    if run_dir is None:
        run_dir = args.out or os.path.join(
            "runs", f"{cfg.task}_{cfg.algo}_s{cfg.seed}_{time.strftime('%Y%m%d-%H%M%S')}")
        if check_out:
            _check_out(run_dir, args.force)
    return cfg, env_over, run_dir


def _new_run_dir(args, run_dir: str) -> str:
    """A new run's directory as process 0 names and checks it, on every process (the default
    name holds the time); ConfigError everywhere when process 0's check fails."""
    from daddpg_jax.running import distributed

    def check(path):
        from daddpg_jax.running import checkpoint as ckpt

        _check_out(path, args.force)
        try:   # held until the process ends: a second run on this --out stops here
            ckpt.lock_run_dir(path)
        except ckpt.RunLockedError as e:
            raise ConfigError(str(e)) from None
        _check_out(path, args.force)   # again, under the lock (two runs started at once)
        return path

    return distributed.on_primary(check, run_dir, errors=(ConfigError,))


def _lock_resumed(run_dir: str) -> None:
    """Takes the lock of a run to resume (held until the process ends); ConfigError when
    another process holds it."""
    from daddpg_jax.running import checkpoint as ckpt

    try:
        ckpt.lock_run_dir(run_dir)
    except ckpt.RunLockedError as e:
        raise ConfigError(str(e)) from None


def _loggers(args, run_dir: str) -> list:
    """The experiment trackers the flags ask for: TensorBoard unless --no-tensorboard, W&B with
    --wandb (ConfigError when wandb is not installed)."""
    from daddpg_jax.running import tracking

    out = [] if args.no_tensorboard else [tracking.TensorBoardLogger(run_dir)]
    if args.wandb:
        out.append(tracking.WandbLogger(run_dir, project=args.wandb))
    return out


def main(argv=None):
    layout = join_job(argv)
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
        if not args.resume:
            run_dir = _new_run_dir(args, run_dir)
        elif layout is None or layout.process_id == 0:
            _lock_resumed(run_dir)
    except ConfigError as e:
        parser.error(str(e))
    try:
        return _run(args, layout, cfg, env_over, run_dir, loggers)
    finally:
        if layout is None or layout.process_id == 0:
            from daddpg_jax.running import checkpoint as ckpt

            ckpt.unlock_run_dir(run_dir)


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
