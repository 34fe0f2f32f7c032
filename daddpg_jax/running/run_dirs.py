"""Run directories as ``daddpg-train`` chooses and claims them: the recorded config of a run to
resume or rerun, a new run's default name, and the checks and locks that keep two runs out of
one directory. Errors are ConfigError (one line, naming the flag)."""

from __future__ import annotations

import os
import time

from daddpg_jax.running import checkpoint as ckpt
from daddpg_jax.running import distributed
from mjx_envs.schema import ConfigError


def of_path(path: str) -> str:
    """The run directory of `path`: a run directory itself, or the directory of its
    config.json."""
    return path if os.path.isdir(path) else os.path.dirname(os.path.abspath(path))


def recorded(path: str):
    """(TrainConfig, env overrides) of a config.json (or of a run directory holding one)."""
    run_dir = of_path(path)
    if not os.path.exists(os.path.join(run_dir, "config.json")):
        raise ConfigError(f"{path}: no config.json there")
    try:
        cfg, payload = ckpt.load_config(run_dir)
    except ckpt.ConfigFileError as e:
        raise ConfigError(str(e)) from None
    return cfg, dict(payload.get("env_overrides", {}))


def resumed(path: str, out: str | None) -> str:
    """The directory of the run to resume at `path` (--resume); `out` (--out) must name it."""
    run_dir = of_path(path)
    if out and os.path.abspath(out) != os.path.abspath(run_dir):
        raise ConfigError("--resume continues the run in its own directory; drop --out")
    return run_dir


def default_name(cfg) -> str:
    """runs/<task>_<algo>_s<seed>_<time>: a new run's directory without --out."""
    return os.path.join(
        "runs", f"{cfg.task}_{cfg.algo}_s{cfg.seed}_{time.strftime('%Y%m%d-%H%M%S')}")


def check_out(path: str, force: bool) -> None:
    """A new run's directory: new, empty, or (with force) a run to replace; else ConfigError."""
    if os.path.exists(path) and not os.path.isdir(path):
        raise ConfigError(f"--out {path}: is a file, not a directory")
    parent = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise ConfigError(f"--out {path}: {parent} is a file, not a directory")
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


def claim_new(run_dir: str, force: bool) -> str:
    """A new run's directory as process 0 names, checks and locks it, on every process (the
    default name holds the time); ConfigError everywhere when process 0's check fails."""

    def check(path):
        check_out(path, force)
        lock(path)   # held until the process ends: a second run on this --out stops here
        check_out(path, force)   # again, under the lock (two runs started at once)
        return path

    return distributed.on_primary(check, run_dir, errors=(ConfigError,))


def lock(run_dir: str) -> None:
    """Takes the lock of a run directory (held until the process ends); ConfigError when
    another process holds it."""
    try:
        ckpt.lock_run_dir(run_dir)
    except ckpt.RunLockedError as e:
        raise ConfigError(str(e)) from None


unlock = ckpt.unlock_run_dir


def claim(run_dir: str, resume: bool, force: bool, primary: bool) -> str:
    """The run's directory, claimed before training: a new run's named, checked and locked
    (`claim_new`, on every process); a resumed run's locked by process 0 (`primary`)."""
    if not resume:
        return claim_new(run_dir, force)
    if primary:
        lock(run_dir)
    return run_dir

