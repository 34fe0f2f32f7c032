"""``daddpg-train``'s flags and the training run's configuration they give: the flag table
(`FLAGS`, one entry per flag: its type, default, choices and help), the task preset or a
recorded run's config merged with the flags' overrides, and the field listing of --help.

JAX-free (``daddpg-train --help`` and argument errors load no JAX): a recorded config is read
through the `load_recorded` function the caller passes (``running.run_dirs.recorded``).
"""

from __future__ import annotations

import textwrap

from daddpg_jax.algo.config import (
    DEVICES,
    HER_MODES,
    PHYSICS,
    TrainConfig,
    build_config,
    for_c_engine_env,
    preset,
    preset_env,
    robust_env,
)
from daddpg_jax.variants import ALGOS, VARIANTS
from mjx_envs import limit_rules, registry, schema, settings
from mjx_envs.schema import ConfigError

FIELD_FLAGS = ("algo", "her", "physics", "seed", "task_module")
"""flags that are also TrainConfig fields (flag attribute = field name)"""

FLAGS = (
    # the training config (resolve_config)
    ("--task", dict(choices=lambda device: registry.TASKS, default=None,
                    help="task to train (default reach; taken from config.json with --resume "
                         "or --config)")),
    ("--task-module", dict(default=None, metavar="MODULE",
                           help="module that registers a task defined outside this package "
                                "(recorded in config.json as task_module; docs/TASKS.md, "
                                "'Adding a task')")),
    ("--num-envs", dict(type=int, default=None,
                        help="parallel environments; the task preset scales batch size and "
                             "updates per cycle with it (default: the preset's: 2 on a CPU, "
                             "4096 on an accelerator)")),
    ("--device", dict(choices=DEVICES, default=None,
                      help=lambda device: "device whose preset to use (default: the one JAX "
                                          f"runs on, {device})")),
    ("--epochs", dict(type=int, default=None,
                      help="total epochs (an epoch = n_cycles cycles + evaluation); with "
                           "--resume the run continues until this many epochs are done "
                           "(default: preset)")),
    ("--seed", dict(type=int, default=None, help="training seed (default 0)")),
    ("--algo", dict(choices=ALGOS, default=None,
                    help="; ".join(f"{v.name}: {v.doc}" for v in VARIANTS.values()))),
    ("--her", dict(choices=HER_MODES, default=None,
                   help="hindsight relabelling strategy (future uses k=4: 80%% relabelled)")),
    ("--physics", dict(choices=PHYSICS, default=None,
                       help="physics engine: auto = MJX on an accelerator, MuJoCo C engine on "
                            "CPU")),
    ("--limits", dict(metavar="FILE", default=None,
                      help="train under a robot limits file (.toml/.json, daddpg-robot-client "
                           "--limits): every env applies its workspace boxes, speed cap, arm "
                           "clearance and finger range to the actions as the robot client's "
                           "safety layer will (mjx_envs/limit_rules.py); the values are "
                           "recorded (env override robot_limits) and kept by --resume")),
    ("--speed-scale", dict(type=float, default=None, metavar="S",
                           help="with --limits: scale the file's max_speed by S in (0, 1] "
                                "(as daddpg-robot-client --speed-scale; default 1)")),
    ("--intervention-penalty", dict(type=float, default=None, metavar="C",
                                    help="with --limits: each step in which the limits change "
                                         "a target costs both arms C in reward, so the policy "
                                         "learns to ask for what the robot will do (fewer "
                                         "safety interventions; env field "
                                         "intervention_penalty; default 0 = off)")),
    # the run directory (cli.train.resolve, running.run_dirs)
    ("--out", dict(default=None,
                   help="run directory (default runs/<task>_<algo>_s<seed>_<time>); must be "
                        "new or empty unless --force")),
    ("--force", dict(action="store_true",
                     help="with --out: delete the run already in that directory (its "
                          "config.json, metrics.csv, learning_curve.png, checkpoints*) and "
                          "start a new one (refused for a directory that holds no run)")),
    ("--resume", dict(metavar="RUN_DIR", default=None,
                      help="continue the run in RUN_DIR from its newest readable checkpoint "
                           "(its config.json is reused; --epochs may raise the total; a run "
                           "stopped before its first checkpoint starts again from epoch 0)")),
    ("--config", dict(metavar="CONFIG_JSON", default=None,
                      help="start a new run from a recorded configuration (RUN/config.json or "
                           "RUN): its training fields and env overrides; flags given with it "
                           "override them")),
    ("--save-buffer", dict(action="store_true",
                           help="store the replay buffer in checkpoints (large; makes --resume "
                                "bit-exact)")),
    ("--set", dict(action="append", metavar="KEY=VALUE", default=[],
                   help="override any training field (listed below); repeatable")),
    ("--env", dict(action="append", metavar="KEY=VALUE", default=[],
                   help="override any env field of the task (listed below); repeatable")),
    ("--robust", dict(action="store_true",
                      help="train with the robust preset: per-episode observation noise, "
                           "dropout, bias, action latency and physics randomization "
                           "(daddpg_jax.algo.config.ROBUST_ENV; test episodes stay nominal), "
                           "and each arm's last action in its observation (ROBUST_OBS: "
                           "action_history=1, kept in test episodes and exports); --env "
                           "overrides single fields; docs/ENVIRONMENTS.md")),
    ("--for-c-engine", dict(action="store_true",
                            help="MJX training of a policy that is to run on the C engine (the "
                                 "robot side's simulator; pickup, pot; needs MJX physics): "
                                 "physics version 9 and the grasp's physics randomized per "
                                 "training episode (daddpg_jax.algo.config.FOR_C_ENGINE_ENV; "
                                 "test episodes stay nominal); --env overrides single fields; "
                                 "add --cross-check c to follow the C engine's success; "
                                 "docs/MJX_VS_C.md")),
    ("--demos", dict(type=int, default=None, metavar="N",
                     help="play N episodes of the task's scripted controller at the start and "
                          "train on them beside the replay, with a behaviour-cloning term "
                          "(push, pickup, pot; not in the paper; same as --set n_demos=N; "
                          "default 0 = off; docs/TRAINING.md#demonstrations)")),
    # the run's options (running.runner.RunOptions) and its output
    ("--time-budget", dict(type=float, default=None, metavar="SECONDS",
                           help="stop after the epoch during which this much wall time has "
                                "passed")),
    ("--stop-at-success", dict(type=float, default=None, metavar="RATE",
                               help="stop after the first epoch whose test success rate is at "
                                    "least RATE (e.g. 0.9: time-to-target benchmarks)")),
    ("--no-progress", dict(action="store_true",
                           help="no progress bar, only one line per epoch (the default when "
                                "stderr is not a terminal)")),
    ("--no-tensorboard", dict(action="store_true",
                              help="do not write TensorBoard event files (RUN_DIR/tensorboard; "
                                   "default: every metrics.csv column against env steps, and "
                                   "the config as text)")),
    ("--wandb", dict(nargs="?", const="daddpg-jax", default=None, metavar="PROJECT",
                     help="also log to Weights & Biases, project PROJECT (default daddpg-jax); "
                          "needs the optional extra: pip install 'daddpg-jax[wandb]'; "
                          "WANDB_MODE=offline logs to RUN_DIR/wandb without an account")),
    ("--video-every", dict(type=int, default=0, metavar="N",
                           help="every N epochs, render test episodes to "
                                "RUN_DIR/videos/epoch_N.mp4 and to TensorBoard (needs "
                                "MUJOCO_GL=egl and imageio; without a renderer: one warning, "
                                "training goes on; default 0 = never)")),
    ("--debug", dict(action="store_true",
                     help="show the traceback of an unexpected error (default: one line)")),
)
"""daddpg-train's flags besides the multi-process ones (running.distributed.add_flags), in
--help order: (flag, argparse keywords). A `choices` or `help` that is a function is called with
the device when the parser is built (the task list then holds the tasks of --task-module)."""


def add_flags(parser, device: str) -> None:
    """The `FLAGS` on `parser`; `device` is the one --help names as the default."""
    for flag, kw in FLAGS:
        parser.add_argument(flag, **{k: v(device) if k in ("choices", "help") and callable(v)
                                     else v for k, v in kw.items()})


def check_flags(args) -> None:
    """The checks of the flags that need neither a device nor JAX (before resolve_config):
    ConfigError (one line, naming the flag)."""
    if args.stop_at_success is not None and not 0.0 <= args.stop_at_success <= 1.0:
        raise ConfigError(f"--stop-at-success must be in [0, 1], got {args.stop_at_success}")
    if args.video_every < 0:
        raise ConfigError(f"--video-every must be >= 0, got {args.video_every}")
    schema.parse_overrides(TrainConfig, args.set, "--set")


def field_help(device: str) -> str:
    """The field listing of --help: every training field with its value for each task at the
    default num_envs on `device`, and every env field with each task's value."""
    tasks = registry.TASKS
    cfgs = {t: build_config(t, device=device) for t in tasks}
    envs = {t: registry.task_config(t, **preset_env(t)) for t in tasks}
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


RESUME_KEEPS = ("robot_limits", "intervention_penalty")
"""env fields a resumed run keeps whatever --env says (--limits and --intervention-penalty may
only repeat them)"""


def resolve_config(args, load_recorded) -> tuple[TrainConfig, dict]:
    """(TrainConfig, env overrides) of daddpg-train's parsed flags `args`. The base is the task
    preset of a new run, or the recorded config of --resume / --config (read by
    `load_recorded(path)` -> (TrainConfig, env overrides)); the flags override it. Errors are
    ConfigError (one line, naming the flag)."""
    if args.resume and args.config:
        raise ConfigError("--resume and --config exclude each other")
    if args.resume and args.force:
        raise ConfigError("--resume and --force exclude each other (--force deletes the run)")
    if args.force and not args.out:
        raise ConfigError("--force needs --out (the run directory to replace)")
    if args.resume:
        cfg, env_over = load_recorded(args.resume)
        _check_resume_flags(args, cfg)
    elif args.config:
        cfg, env_over = load_recorded(args.config)
        if args.task is not None or args.num_envs is not None:
            # a new task or size: that preset's fields replace the recorded ones
            cfg = cfg.replace(**preset(args.task or cfg.task, args.num_envs or cfg.num_envs,
                                       device=args.device))
    else:
        task = args.task or settings.DEFAULT_TASK
        cfg, env_over = build_config(task, args.num_envs, device=args.device), preset_env(task)
    if args.robust:   # a resume refused --robust above
        env_over.update(robust_env(cfg.task))
    if args.for_c_engine:   # a resume refused --for-c-engine above
        env_over.update(for_c_engine_env(cfg.task))
    cfg = cfg.replace(**_field_overrides(args))
    env_cls = type(registry.default_config(cfg.task))
    kept = {k: env_over.get(k) for k in RESUME_KEEPS}
    env_over.update(schema.parse_overrides(env_cls, args.env, "--env"))
    _apply_limits(args, cfg.task, env_over)
    if args.resume and any(env_over.get(k) != v for k, v in kept.items()):
        raise ConfigError("--resume keeps the run's robot limits and intervention penalty "
                          "(they shape its replay buffer and rewards); start a new run instead")
    registry.task_config(cfg.task, **env_over)   # validates the env fields together
    if cfg.n_demos > 0:
        _check_demos(cfg.task)
    return cfg, env_over


def _check_resume_flags(args, cfg: TrainConfig) -> None:
    """A resumed run keeps its config: flags that would change it are ConfigError."""
    for name in ("task", "num_envs", *FIELD_FLAGS):
        v = getattr(args, name)
        if v is not None and v != getattr(cfg, name):
            raise ConfigError(f"--resume: --{name.replace('_', '-')} differs from the run's "
                              f"config ({getattr(cfg, name)!r}); start a new run instead")
    if args.robust:
        raise ConfigError("--resume: --robust is decided by the run's config; start a new "
                          "run instead")
    if args.for_c_engine:
        raise ConfigError("--resume: --for-c-engine is decided by the run's config; start a "
                          "new run instead")
    if args.demos is not None and args.demos != cfg.n_demos:
        raise ConfigError(f"--resume: --demos differs from the run's config "
                          f"({cfg.n_demos}); start a new run instead")


def _field_overrides(args) -> dict:
    """The TrainConfig fields the flags set (--set, --epochs, --save-buffer, --demos, ...)."""
    over = {k: getattr(args, k) for k in FIELD_FLAGS if getattr(args, k) is not None}
    over.update(schema.parse_overrides(TrainConfig, args.set, "--set"))
    if args.epochs is not None:
        over["n_epochs"] = args.epochs
    if args.save_buffer:
        over["save_buffer"] = True
    if args.demos is not None:
        over["n_demos"] = args.demos
    return over


def _check_demos(task: str) -> None:
    # lazy: the scripted controllers import JAX, needed only when demonstrations are asked for
    from mjx_envs.tasks import scripted

    if task not in scripted.POLICIES:
        raise ConfigError(f"--demos: task {task!r} has no scripted controller "
                          f"(available: {', '.join(sorted(scripted.POLICIES))})")


def limits_values(path: str, speed_scale: float | None, task: str, env_over: dict) -> tuple:
    """The ``robot_limits`` env setting (`mjx_envs.limit_rules.FLAT_SIZE` numbers) of a robot
    limits file at ``speed_scale``: ConfigError (one line) for an unreadable file, a control
    period other than the task's or a task the file does not allow."""
    # lazy: the robot side's reader (NumPy), loaded only when --limits is given
    from daddpg_jax.deploy.limits import LimitsError, RobotLimits

    try:
        limits = RobotLimits.load(path)
        safety = limits.safety_limits(1.0 if speed_scale is None else speed_scale)
    except LimitsError as e:
        raise ConfigError(f"--limits: {e}") from None
    env = registry.task_config(task, **{k: v for k, v in env_over.items()  # (its timing)
                                        if k not in ("robot_limits", "intervention_penalty")})
    dt = float(env.timestep) * int(env.n_substeps)
    if abs(limits.control_period - dt) > 1e-9 + 1e-6 * dt:
        raise ConfigError(f"--limits: the file's control period {limits.control_period:g} s is "
                          f"not the task's {dt:g} s")
    if limits.task and limits.task != task:
        raise ConfigError(f"--limits: the file is for task {limits.task!r}, not {task!r}")
    return limit_rules.Limits(safety.workspace_low, safety.workspace_high, safety.max_step,
                              safety.min_clearance, safety.finger_low,
                              safety.finger_high).flat()


def _apply_limits(args, task: str, env_over: dict) -> None:
    """--limits / --speed-scale / --intervention-penalty into ``env_over`` (a resumed run keeps
    its recorded limits and penalty: the flags must give the same values)."""
    path, scale = getattr(args, "limits", None), getattr(args, "speed_scale", None)
    penalty = getattr(args, "intervention_penalty", None)
    if penalty is not None:
        if penalty < 0:
            raise ConfigError(f"--intervention-penalty must be >= 0, got {penalty:g}")
        if (getattr(args, "resume", None)
                and float(env_over.get("intervention_penalty", 0.0)) != float(penalty)):
            raise ConfigError("--resume: --intervention-penalty differs from the run's recorded "
                              "penalty; start a new run instead")
        env_over["intervention_penalty"] = float(penalty)
    if path is None:
        if scale is not None:
            raise ConfigError("--speed-scale needs --limits")
        return
    values = limits_values(path, scale, task, env_over)
    recorded = tuple(env_over.get("robot_limits", ()) or ())
    if getattr(args, "resume", None) and tuple(recorded) != values:
        raise ConfigError("--resume: --limits differs from the run's recorded limits; start a "
                          "new run instead")
    env_over["robot_limits"] = values
