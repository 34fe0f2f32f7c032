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
    from daddpg_jax.algo.config import current_device

    device = device or current_device()
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
    p.add_argument("--no-progress", action="store_true", help="disable the progress bar")
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
    cfg, payload = ckpt.load_config(run_dir)
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
    if not os.path.isdir(path) or not os.listdir(path):
        return
    from daddpg_jax.running import checkpoint as ckpt

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

    check_physics_backend(cfg.physics, cfg.num_envs, cfg.n_test_episodes)
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
        _check_out(path, args.force)
        return path

    return distributed.on_primary(check, run_dir, errors=(ConfigError,))


class Progress:
    """The progress bar: ticks once per cycle (train success, env steps/s) and, in long cycles
    (>= 200 updates), 10 times during the updates."""

    def __init__(self, cfg: TrainConfig, episode_length: int, show: bool = True):
        from tqdm import tqdm

        self.cfg = cfg
        # show=False (processes other than 0 of a multi-process job): the same callbacks are
        # compiled into every process's program, and draw nothing
        self.bar = tqdm(total=cfg.n_epochs * cfg.n_cycles, unit="cycle", dynamic_ncols=True,
                        desc=f"{cfg.task}/{cfg.algo}", disable=not show)
        self.steps_per_cycle = cfg.num_envs * episode_length
        self.update_tick = cfg.n_batches // 10 if cfg.n_batches >= 200 else 0
        self.t_last = time.perf_counter()
        self.partial = 0.0   # fraction of the current cycle already shown by update ticks

    def cycle(self, m):
        now = time.perf_counter()
        sps = self.steps_per_cycle / max(now - self.t_last, 1e-9)
        self.t_last = now
        self.bar.update(max(1.0 - self.partial, 0.0))
        self.partial = 0.0
        self.bar.set_postfix(train_success=f"{float(m['success']):.2f}", steps_s=f"{sps:,.0f}",
                             refresh=False)

    def updates(self, n):
        inc = self.update_tick / self.cfg.n_batches
        if self.partial + inc < 1.0:
            self.partial += inc
            self.bar.update(inc)

    def epoch(self, row, msg):
        self.bar.n = row["epoch"] * self.cfg.n_cycles
        self.bar.refresh()
        self.bar.write(msg)

    def close(self):
        self.bar.close()


def _epoch_line(row) -> str:
    return (f"epoch {row['epoch']:4d}  env_steps {row['env_steps']:>10,}  "
            f"test_success {row['test_success_rate']:.3f}  "
            f"arm_contact {row['test_arm_contact_rate']:.3f}  "
            f"critic_loss {row['critic_loss']:.4f}  {row['env_steps_per_s']:,.0f} steps/s")


def main(argv=None):
    layout = join_job(argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.stop_at_success is not None and not 0.0 <= args.stop_at_success <= 1.0:
        parser.error(f"--stop-at-success must be in [0, 1], got {args.stop_at_success}")
    try:
        cfg, env_over, run_dir = resolve(args, parser, check_out=False)
        if not args.resume:
            run_dir = _new_run_dir(args, run_dir)
    except ConfigError as e:
        parser.error(str(e))

    from daddpg_jax.running.distributed import DistributedError
    from daddpg_jax.running.runner import CheckpointError, NonFiniteLoss, RunDirError, train

    primary = layout is None or layout.process_id == 0
    if primary:
        _print_header(cfg, run_dir)
    T = settings.task_config(cfg.task, **env_over).episode_length
    bar = None if args.no_progress else Progress(cfg, T, show=primary)

    def on_epoch(row):
        if bar is None:
            print(_epoch_line(row), flush=True)
        else:
            bar.epoch(row, _epoch_line(row))

    try:
        res = train(cfg, run_dir, env_overrides=env_over, resume=bool(args.resume),
                    progress=bar.cycle if bar else None, on_epoch=on_epoch,
                    command=" ".join(sys.argv), time_budget_s=args.time_budget,
                    stop_at_success=args.stop_at_success,
                    update_progress=bar.updates if bar and bar.update_tick else None,
                    update_tick=bar.update_tick if bar else 0, force=args.force)
    except NonFiniteLoss as e:
        print(f"error: {e}", file=sys.stderr)
        return 3
    except (RunDirError, CheckpointError, DistributedError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\ninterrupted; resume with: daddpg-train --resume {run_dir}", file=sys.stderr)
        return 130
    except Exception as e:   # noqa: BLE001  (one line unless --debug)
        if args.debug:
            raise
        print(f"error: {type(e).__name__}: {e} (rerun with --debug for the traceback; "
              f"resume with: daddpg-train --resume {run_dir})", file=sys.stderr)
        return 1
    finally:
        if bar is not None:
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
