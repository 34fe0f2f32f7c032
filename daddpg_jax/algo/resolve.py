"""A training run's configuration from the flags of ``daddpg-train``: the task preset, or a
recorded run's config, merged with the flags' overrides; and the field listing of its --help.

JAX-free (``daddpg-train --help`` and argument errors load no JAX): a recorded config is read
through the `load_recorded` function the caller passes (``running.run_dirs.recorded``).
"""

from __future__ import annotations

import textwrap

from daddpg_jax.algo.config import TrainConfig, build_config, preset, preset_env, robust_env
from mjx_envs import schema, settings
from mjx_envs.schema import ConfigError

FIELD_FLAGS = ("algo", "her", "physics", "seed", "task_module")
"""flags that are also TrainConfig fields (flag attribute = field name)"""


def field_help(device: str) -> str:
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
    cfg = cfg.replace(**_field_overrides(args))
    env_cls = type(settings.default_config(cfg.task))
    env_over.update(schema.parse_overrides(env_cls, args.env, "--env"))
    settings.task_config(cfg.task, **env_over)   # validates the env fields together
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
