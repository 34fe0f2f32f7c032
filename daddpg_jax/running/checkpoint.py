"""Orbax checkpoints of a TrainState in RUN_DIR/checkpoints/{step}, plus RUN_DIR/config.json.

Each checkpoint holds the item `state` (agents, targets, optimizer states, normalizers, key,
counters) and, when asked, the item `buffer` (the replay buffer: large). Restoring without a
saved buffer keeps the template's buffer (e.g. a fresh empty one from `init`): training then
resumes with the same networks and normalizers but refills the replay from scratch, so it is
not bit-identical to an uninterrupted run. With the buffer saved, 1 epoch + resume + 1 epoch
equals a 2-epoch run. Orbax writes to a temporary directory and renames it when complete, so a
killed run resumes from the last complete checkpoint. The last `keep` checkpoints are kept.
RUN_DIR/checkpoints_best/{step} holds one more: a copy (without the buffer) of the checkpoint
with the best test success (`save_best`), renamed into place when complete.
Demonstration episodes (TrainConfig.n_demos) are never saved: `init` plays the same ones again
from the seed, and restoring keeps the template's. A reader that only acts (evaluation, export:
``daddpg_jax.running.checkpoint_policy``) restores into an ``algo.actors.ActorParams`` template
instead: only the actors and normalizers are restored.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import fcntl
import glob
import importlib.metadata
import json
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import traceback

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
import tensorstore as ts
from flax import serialization

from daddpg_jax.algo.actors import ActorParams
from daddpg_jax.algo.config import TrainConfig
from daddpg_jax.algo.sharding import on_mesh
from daddpg_jax.running.host import host_info
from mjx_envs.model import physics_version_note
from mjx_envs.settings import PHYSICS_VERSION, recorded_physics_version

RUN_FILES = ("config.json", "metrics.csv", "learning_curve.png", "checkpoints",
             "checkpoints_best", "tensorboard", "videos", "wandb")
"""what a training run writes in its directory (besides LOCK_FILE)"""

LOCK_FILE = ".lock"
"""RUN_DIR/.lock: the run directory's lock (``lock_run_dir``); kept when the run ends"""

_TMP_PREFIX = ".tmp-"
"""temporary files of atomic writes: RUN_DIR/.tmp-<name>-<random> (``write_atomic``)"""


def checkpoint_dir(run_dir, best: bool = False) -> str:
    """RUN_DIR/checkpoints, or with best=True RUN_DIR/checkpoints_best."""
    name = "checkpoints_best" if best else "checkpoints"
    return os.path.join(os.path.abspath(os.fspath(run_dir)), name)


def _manager(run_dir, keep: int | None = None, best: bool = False) -> ocp.CheckpointManager:
    opts = ocp.CheckpointManagerOptions(max_to_keep=keep, create=True)
    return ocp.CheckpointManager(checkpoint_dir(run_dir, best), options=opts)


def _split(state):
    tree = serialization.to_state_dict(state)
    buffer = tree.pop("buffer")
    # demonstrations are not saved: init replays them from the seed (same episodes)
    tree.pop("demos", None)
    return tree, buffer


def save(run_dir, state, step: int, save_buffer: bool = False, keep: int = 3) -> str:
    """Saves `state` as checkpoint `step` (blocking until written). Returns its directory.

    Any failure (a full disk, a write error inside orbax or TensorStore) raises
    :class:`CheckpointSaveError` with one line naming the cause; what the failed save left
    (orbax's temporary directory) is deleted, and the checkpoints before stay as they were."""
    tree, buffer = _split(state)
    items = {"state": ocp.args.StandardSave(tree)}
    if save_buffer:
        items["buffer"] = ocp.args.StandardSave(buffer)
    try:
        with _quiet_failing_save(), _manager(run_dir, keep) as mngr:
            mngr.save(int(step), args=ocp.args.Composite(**items), force=True)
            mngr.wait_until_finished()
    except Exception as e:  # noqa: BLE001 (orbax, TensorStore and OS errors alike)
        remove_partial(run_dir)
        last = latest_step(run_dir)
        where = (f"resume from checkpoint {last}" if last is not None
                 else "no earlier checkpoint: start the run again")
        why = root_cause(e, width=160)
        if _disk_full(e):
            why = f"no space left on device: {why}"
        raise CheckpointSaveError(
            f"could not save checkpoint {int(step)} in {checkpoint_dir(run_dir)} "
            f"({why}); free space or fix the cause, then {where} with "
            f"daddpg-train --resume {os.fspath(run_dir)}") from e
    return os.path.join(checkpoint_dir(run_dir), str(int(step)))


def _disk_full(e: BaseException) -> bool:
    """Whether an exception chain says the disk is full (ENOSPC, or TensorStore's
    RESOURCE_EXHAUSTED with os_error_code 28)."""
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        text = str(e)
        if (getattr(e, "errno", None) == 28 or "No space left on device" in text
                or "os_error_code='28'" in text):
            return True
        e = e.__cause__ or e.__context__
    return False


class _DropOrbaxErrors(logging.Filter):
    """Drops ERROR records about orbax's work (the message or the traceback names orbax)."""

    def filter(self, record):
        if record.levelno < logging.ERROR:
            return True
        text = record.getMessage()
        if record.exc_info and record.exc_info[2] is not None:
            text += "".join(traceback.format_tb(record.exc_info[2]))
        return "orbax" not in text


_QUIET_LOGGERS = ("absl", "asyncio", "orbax")
_QUIET = _DropOrbaxErrors()


def _closed_loop(etype, value, tb) -> bool:
    """Whether an error is 'RuntimeError: Event loop is closed' raised in asyncio's event loop
    (TensorStore's completion callbacks of a save that orbax gave up on)."""
    last = tb
    while last is not None and last.tb_next is not None:
        last = last.tb_next
    where = last.tb_frame.f_code.co_filename if last is not None else ""
    return (etype is RuntimeError and "Event loop is closed" in str(value)
            and where.endswith(os.path.join("asyncio", "base_events.py")))


def _closed_loop_hook(prev):
    """sys.unraisablehook (TensorStore reports a failed callback as unraisable) that drops the
    errors of `_closed_loop` and passes everything else to `prev`."""
    def hook(u):
        if not _closed_loop(u.exc_type, u.exc_value, u.exc_traceback):
            prev(u)

    hook._daddpg_closed_loop = True
    return hook


@contextlib.contextmanager
def _quiet_failing_save():
    """While orbax saves: a failing save (e.g. a full disk) makes each of orbax's worker threads
    log the failure with its traceback (absl ERROR records, during and after the save), asyncio
    log its never-retrieved task errors, and TensorStore's callbacks into the closed event loop
    print 'Event loop is closed' tracebacks: hundreds of lines for one error, which `save`
    raises itself and the runner reports in one line. ERROR records that name orbax are dropped
    during the save, and from then on if it failed; so are the closed-loop tracebacks."""
    if not getattr(sys.unraisablehook, "_daddpg_closed_loop", False):
        sys.unraisablehook = _closed_loop_hook(sys.unraisablehook)
    loggers = [logging.getLogger(n) for n in _QUIET_LOGGERS]
    for lg in loggers:
        lg.addFilter(_QUIET)
    try:
        yield
    except BaseException:
        raise   # the filters stay: orbax's threads go on logging the failure
    else:
        for lg in loggers:
            lg.removeFilter(_QUIET)


def root_cause(e: BaseException, width: int = 200) -> str:
    """'Type: first line' of the innermost exception of e's chain (e.g. TensorStore's or the
    OS's reason under orbax's wrappers), at most `width` characters."""
    seen = set()
    while (e.__cause__ or e.__context__) is not None and id(e) not in seen:
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    lines = str(e).strip().splitlines()
    text = f"{type(e).__name__}: {lines[0]}" if lines else type(e).__name__
    return text if len(text) <= width else text[:width - 3] + "..."


class CheckpointSaveError(OSError):
    """A checkpoint could not be written (e.g. the disk is full); the message is one line."""


class RunDirError(FileNotFoundError):
    """A directory is not a run directory, or lacks the asked-for checkpoint."""


class CheckpointError(RuntimeError):
    """No checkpoint of a run can be read; the message says which and why."""


class ConfigFileError(RunDirError):
    """A run's config.json cannot be read (not JSON, not an object, no 'config', bad values);
    the message names the file."""


class RunLockedError(RunDirError):
    """Another process holds the run directory's lock."""


_LOCKS: dict = {}
"""run directory (absolute path) -> [fd of its lock file, holders] held by this process"""


def lock_run_dir(run_dir) -> str:
    """Takes the lock of `run_dir` (created if missing) for this process: an exclusive
    ``flock`` on RUN_DIR/.lock, held until :func:`unlock_run_dir` or the process ends (a kill
    releases it). Raises :class:`RunLockedError` when another process holds it. Re-entrant
    within a process (each call needs one ``unlock_run_dir``). Returns the lock file's path."""
    d = os.path.abspath(os.fspath(run_dir))
    path = os.path.join(d, LOCK_FILE)
    if d in _LOCKS:
        _LOCKS[d][1] += 1
        return path
    os.makedirs(d, exist_ok=True)
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        try:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
        finally:
            os.close(fd)
        raise RunLockedError(f"{d}: another process (pid {holder}) is using this run "
                             "directory; wait for it to end or choose another --out") from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    _LOCKS[d] = [fd, 1]
    return path


def unlock_run_dir(run_dir) -> None:
    """Releases one hold of `run_dir`'s lock taken by :func:`lock_run_dir` (the lock file
    stays)."""
    d = os.path.abspath(os.fspath(run_dir))
    held = _LOCKS.get(d)
    if held is None:
        return
    held[1] -= 1
    if held[1] <= 0:
        del _LOCKS[d]
        os.close(held[0])   # closing the descriptor releases the flock


def is_empty_run_dir(path) -> bool:
    """Whether `path` is missing, or a directory holding nothing but a run directory's lock
    file (left by a run that wrote nothing else)."""
    if not os.path.isdir(path):
        return not os.path.exists(path)
    return not [n for n in os.listdir(path) if n != LOCK_FILE]


def check_run_dir(run_dir, step: int | None = None, best: bool = False) -> list:
    """Checks that ``run_dir`` is a training run with checkpoint ``step`` (default: any; with
    best=True its best checkpoint) and returns its checkpoint steps; raises
    :class:`RunDirError` with a message for the user."""
    run_dir = os.fspath(run_dir)
    if not os.path.isdir(run_dir):
        raise RunDirError(f"run directory {run_dir!r} does not exist")
    if not os.path.exists(os.path.join(run_dir, "config.json")):
        raise RunDirError(f"{run_dir!r} has no config.json: not a training run directory "
                          "(written by experiments/run.py)")
    steps = all_steps(run_dir, best)
    if not steps and best:
        raise RunDirError(f"run {run_dir!r} has no best checkpoint under "
                          f"{checkpoint_dir(run_dir, best)} (runs keep one since best "
                          "checkpoints were introduced; export the latest one instead)")
    if not steps:
        raise RunDirError(f"run {run_dir!r} has no checkpoint under {checkpoint_dir(run_dir)} "
                          "(a run writes one at the end of each epoch)")
    if step is not None and int(step) not in steps:
        raise RunDirError(f"run {run_dir!r} has no checkpoint {step}; available: {steps}")
    return steps


def all_steps(run_dir, best: bool = False):
    """The complete checkpoints' steps (best=True: of checkpoints_best/), ascending: the
    directories named by a step number (orbax and `save_best` write under a temporary name and
    rename when complete). Read from the directory, not through an orbax CheckpointManager,
    whose creation is a barrier of all processes of a multi-process job."""
    d = checkpoint_dir(run_dir, best)
    if not os.path.isdir(d):
        return []
    return sorted(int(n) for n in os.listdir(d)
                  if n.isdigit() and os.path.isdir(os.path.join(d, n)))


def latest_step(run_dir, best: bool = False) -> int | None:
    steps = all_steps(run_dir, best)
    return steps[-1] if steps else None


def step_dir(run_dir, step: int, best: bool = False) -> str:
    return os.path.join(checkpoint_dir(run_dir, best), str(int(step)))


def has_buffer(run_dir, step: int, best: bool = False) -> bool:
    return os.path.isdir(os.path.join(step_dir(run_dir, step, best), "buffer"))


def save_best(run_dir, step: int) -> str:
    """Makes checkpoint `step` the best one: copies RUN_DIR/checkpoints/{step} (without the
    replay buffer) to a temporary name in checkpoints_best/, renames it into place, then deletes
    the other best checkpoints. A kill at any moment leaves the previous best or the new one
    complete (and maybe a temporary copy, which `remove_partial` deletes)."""
    src = step_dir(run_dir, step)
    if not os.path.isdir(src):
        raise FileNotFoundError(f"no checkpoint {step} under {checkpoint_dir(run_dir)}")
    best_dir = checkpoint_dir(run_dir, best=True)
    os.makedirs(best_dir, exist_ok=True)
    # a new directory of an unpredictable name (never one planted there beforehand)
    tmp = tempfile.mkdtemp(prefix=f"{_COPY_PREFIX}{int(step)}-", dir=best_dir)
    try:
        shutil.copytree(src, tmp, ignore=shutil.ignore_patterns("buffer"), dirs_exist_ok=True)
        dst = step_dir(run_dir, step, best=True)
        if os.path.islink(dst) or os.path.isfile(dst):
            os.remove(dst)
        elif os.path.exists(dst):
            shutil.rmtree(dst)
        os.rename(tmp, dst)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    remove_steps(run_dir, [s for s in all_steps(run_dir, best=True) if s != int(step)],
                 best=True)
    return dst


_COPY_PREFIX = ".copy-"
_ORBAX_TMP = ".orbax-checkpoint-tmp"


def remove_partial(run_dir) -> list:
    """Deletes what a killed save leaves behind (orbax's temporary directories, a partial copy
    of `save_best`) in checkpoints/ and checkpoints_best/. Returns the paths deleted."""
    gone = []
    for best in (False, True):
        d = checkpoint_dir(run_dir, best)
        if not os.path.isdir(d):
            continue
        for name in sorted(os.listdir(d)):
            if _ORBAX_TMP in name or name.startswith(_COPY_PREFIX):
                p = os.path.join(d, name)
                if os.path.islink(p):
                    os.remove(p)
                else:
                    shutil.rmtree(p, ignore_errors=True)
                gone.append(p)
    return gone


def remove_steps(run_dir, steps, best: bool = False) -> None:
    """Deletes checkpoints `steps` (best=True: of checkpoints_best/)."""
    for s in steps:
        shutil.rmtree(step_dir(run_dir, s, best), ignore_errors=True)


def is_run_dir(path) -> bool:
    """Whether `path` is a directory holding a training run: a config.json written by
    `save_config`, or (a run without one) a metrics.csv with the runner's header."""
    try:
        with open(os.path.join(path, "config.json")) as f:
            payload = json.load(f)
        return isinstance(payload, dict) and "config" in payload and "versions" in payload
    except FileNotFoundError:
        pass
    except (OSError, ValueError):
        return False
    try:
        with open(os.path.join(path, "metrics.csv")) as f:
            return f.readline().startswith("epoch,env_steps,")
    except OSError:
        return False


def remove_run_files(run_dir) -> None:
    """Deletes what a training run writes in `run_dir` (RUN_FILES and their temporary files);
    other files stay."""
    temporary = [os.path.basename(p) for p in glob.glob(os.path.join(run_dir, _TMP_PREFIX + "*"))]
    legacy = ("config.json.tmp", "metrics.csv.tmp", "learning_curve.tmp.png")  # older versions'
    for name in RUN_FILES + legacy + tuple(temporary):
        p = os.path.join(run_dir, name)
        if os.path.isdir(p) and not os.path.islink(p):
            shutil.rmtree(p)
        elif os.path.lexists(p):
            os.remove(p)


def wipe_run(run_dir) -> None:
    """Deletes the run in `run_dir` (`remove_run_files`), for a new run in its place; refuses
    a non-empty directory that holds no run."""
    if is_empty_run_dir(run_dir):
        return
    if not is_run_dir(run_dir):
        raise RunDirError(f"{run_dir!r} is not a training run directory (no config.json "
                          "written by a run): not deleting anything in it")
    remove_run_files(run_dir)


def verify(run_dir, step: int, best: bool = False) -> None:
    """Reads every array of checkpoint `step` once (TensorStore, synchronously) and parses its
    metadata; raises the first error (e.g. ValueError 'OUT_OF_RANGE: Error reading ...' for a
    truncated data file). `restore` would fail on the same checkpoint, but from inside orbax's
    concurrent reads, whose other failures then print pages of tracebacks."""
    d = step_dir(run_dir, step, best)
    with open(os.path.join(d, "_CHECKPOINT_METADATA")) as f:
        json.load(f)
    for item in ("state", "buffer"):
        path = os.path.join(d, item)
        if not os.path.isdir(path):
            continue
        with open(os.path.join(path, "_METADATA")) as f:
            json.load(f)
        if not os.path.exists(os.path.join(path, "manifest.ocdbt")):
            continue   # not an OCDBT checkpoint: restore() reads it
        base = {"driver": "ocdbt", "base": {"driver": "file", "path": path + os.sep}}
        keys = ts.KvStore.open(base).result().list().result()
        for k in keys:
            if k.endswith(b"/.zarray"):
                spec = {"driver": "zarr", "kvstore": {**base, "path": k[:-len(".zarray")].decode()}}
                ts.open(spec, open=True).result().read().result()


def restore(run_dir, template, step: int | None = None, restore_buffer: bool | None = None,
            best: bool = False):
    """Restores checkpoint `step` (default: latest) into the structure of `template` (a TrainState
    from `init`, which fixes shapes, dtypes and shardings). restore_buffer=None restores the
    buffer when the checkpoint has one; otherwise the template's buffer is kept. best=True
    reads checkpoints_best/ (the checkpoint with the best test success; no buffer).
    A template that is an `ActorParams` (``algo.actors.abstract_params``: shapes only) reads
    the actors and normalizers alone (`_restore_actors`; restore_buffer is then ignored).
    Returns (state, step)."""
    if step is None:
        step = latest_step(run_dir, best)
        if step is None:
            raise FileNotFoundError(f"no checkpoint under {checkpoint_dir(run_dir, best)}")
    step = int(step)
    if isinstance(template, ActorParams):
        return _restore_actors(run_dir, template, step, best), step
    if restore_buffer is None:
        restore_buffer = has_buffer(run_dir, step, best)
    elif restore_buffer and not has_buffer(run_dir, step, best):
        raise FileNotFoundError(f"checkpoint {step} was saved without the replay buffer")
    tree, buffer = _split(template)
    # each leaf with the template's sharding (an abstract template's: the first local
    # device): a checkpoint saved on other devices (several, or another process layout)
    # restores onto the template's devices
    one = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    abstract = lambda t: jax.tree.map(
        lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype,
                                       sharding=getattr(x, "sharding", None) or one), t)
    items = {"state": ocp.args.StandardRestore(abstract(tree))}
    if restore_buffer:
        items["buffer"] = ocp.args.StandardRestore(abstract(buffer))
    with _manager(run_dir, best=best) as mngr:
        out = mngr.restore(step, args=ocp.args.Composite(**items))
    full = dict(out["state"])
    if restore_buffer:
        full["buffer"] = out["buffer"]
    # Orbax returns arrays committed to a device; jit keys its cache on that. The trainer's
    # `init` lays its state out on the device mesh (NamedShardings, daddpg_jax/algo/sharding.py)
    # and orbax restores into exactly those: keep them. Any other template's arrays are
    # uncommitted: re-place the restored arrays uncommitted too.
    if not on_mesh(template):
        full = jax.tree.map(lambda x: jnp.asarray(np.asarray(x)), full)
    if not restore_buffer:
        full["buffer"] = buffer
    full["demos"] = serialization.to_state_dict(template)["demos"]
    return serialization.from_state_dict(template, full), step


def _restore_actors(run_dir, template: ActorParams, step: int, best: bool = False) -> ActorParams:
    """Checkpoint `step`'s actors and normalizers (the saved state's ``agent.actor``,
    ``obs_norm`` and ``goal_norm``) into the structure of `template`, whose shapes must match
    the saved ones. Orbax's partial restore reads those arrays only: not the critics, target
    networks, optimizer states or buffer, and no template of them is built. The arrays come
    back uncommitted, as `restore` gives them for a template off the device mesh."""
    parts = serialization.to_state_dict(template)
    saved = {"agent": {"actor": parts["actor"]}, "obs_norm": parts["obs_norm"],
             "goal_norm": parts["goal_norm"]}
    one = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    target = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=one), saved)
    args = ocp.args.PyTreeRestore(item=target, partial_restore=True,
                                  restore_args=ocp.checkpoint_utils.construct_restore_args(target))
    with _manager(run_dir, best=best) as mngr:
        out = mngr.restore(step, args=ocp.args.Composite(state=args))["state"]
    out = jax.tree.map(lambda x: jnp.asarray(np.asarray(x)), dict(out))
    return serialization.from_state_dict(template, {"actor": out["agent"]["actor"],
                                                    "obs_norm": out["obs_norm"],
                                                    "goal_norm": out["goal_norm"]})


def _version(pkg: str) -> str | None:
    try:
        return importlib.metadata.version(pkg)
    except importlib.metadata.PackageNotFoundError:
        return None


def _git_revision(path) -> str | None:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=path, capture_output=True,
                             text=True, timeout=5)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def save_config(run_dir, cfg, **extra) -> str:
    """Writes RUN_DIR/config.json: the TrainConfig, package versions, device, git revision, the
    host (CPU model, cores) and any `extra` JSON-serializable fields (e.g. env overrides)."""
    os.makedirs(run_dir, exist_ok=True)
    cfg_dict = cfg.to_dict() if hasattr(cfg, "to_dict") else dataclasses.asdict(cfg)
    repo = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    payload = dict(
        config=cfg_dict,
        versions={p: _version(p) for p in ("jax", "jaxlib", "flax", "optax", "orbax-checkpoint",
                                           "numpy", "mujoco", "mujoco-mjx", "daddpg-jax")},
        device=str(jax.devices()[0].device_kind), backend=jax.default_backend(),
        git_revision=_git_revision(repo), host=host_info(),
        # the physics the run simulates: its env override (an older run resumed) or this install's
        physics_version=int((extra.get("env_overrides") or {}).get("physics_version",
                                                                    PHYSICS_VERSION)),
        created=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        **extra,
    )
    path = os.path.join(run_dir, "config.json")
    write_atomic(path, json.dumps(payload, indent=2, sort_keys=True))
    return path


def temp_path(path, suffix: str = "") -> str:
    """A new, empty file beside `path` for an atomic write, created with O_EXCL under an
    unpredictable name (``.tmp-<name>-<random><suffix>``, mode 0600): a file or symlink planted
    in the directory is never written through. The caller renames it over `path` or deletes
    it."""
    d, name = os.path.split(os.path.abspath(os.fspath(path)))
    fd, tmp = tempfile.mkstemp(prefix=f"{_TMP_PREFIX}{name}-", suffix=suffix, dir=d)
    os.close(fd)
    return tmp


def write_atomic(path, text: str) -> None:
    """Writes `text` to `path` through a temporary file (`temp_path`) and os.replace: a kill at
    any moment leaves the old file or the new one, never a part."""
    d, name = os.path.split(os.path.abspath(os.fspath(path)))
    fd, tmp = tempfile.mkstemp(prefix=f"{_TMP_PREFIX}{name}-", dir=d)
    try:
        with os.fdopen(fd, "w", newline="") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.lexists(tmp):
            os.remove(tmp)
        raise


def load_config(run_dir):
    """Reads RUN_DIR/config.json back into a TrainConfig (and returns the whole payload).
    A file that is not JSON, not an object with a 'config' object, or holds invalid values
    raises :class:`ConfigFileError` (one line naming the file); a missing one
    FileNotFoundError."""
    path = os.path.join(os.fspath(run_dir), "config.json")
    try:
        with open(path) as f:
            payload = json.load(f)
    except UnicodeDecodeError as e:
        raise ConfigFileError(f"{path}: not a readable config.json (not UTF-8 text: {e})") \
            from None
    except json.JSONDecodeError as e:
        raise ConfigFileError(f"{path}: not a readable config.json (invalid JSON: {e})") \
            from None
    except IsADirectoryError:
        raise ConfigFileError(f"{path}: is a directory, not a config.json") from None
    if not isinstance(payload, dict):
        raise ConfigFileError(f"{path}: not a run's config.json (a JSON "
                              f"{type(payload).__name__}, not an object)")
    if not isinstance(payload.get("config"), dict):
        what = "has no 'config' entry" if "config" not in payload else "its 'config' is no object"
        raise ConfigFileError(f"{path}: not a run's config.json ({what})")
    if not isinstance(payload.get("env_overrides", {}), dict):
        raise ConfigFileError(f"{path}: its 'env_overrides' is not an object")
    try:
        cfg = TrainConfig.from_dict(payload["config"])
    except (TypeError, ValueError) as e:   # ConfigError is a ValueError
        raise ConfigFileError(f"{path}: invalid training config ({e})") from None
    # a run acts with the physics it was trained on: an older version becomes an env override
    # (the env builds that version's scene, `mjx_envs.model.load_model`)
    recorded = recorded_physics_version(payload.get("physics_version"))
    overrides = payload.setdefault("env_overrides", {})
    if recorded != PHYSICS_VERSION and "physics_version" not in overrides:
        overrides["physics_version"] = recorded
    return cfg, payload


def physics_note(run_dir, payload, task: str, simulated: int | None = None,
                 engine: str | None = None) -> None:
    """Prints one warning line (once per run and process) when a run of `task` is simulated
    with a physics version (`simulated`, default its own) that acts unlike the one it was
    trained on, on `engine` when named (`mjx_envs.model.physics_version_note`)."""
    recorded = payload.get("physics_version")
    own = (payload.get("env_overrides") or {}).get("physics_version", recorded)
    note = physics_version_note(recorded, task, own if simulated is None else simulated, engine)
    key = (os.fspath(run_dir), simulated)
    if note and key not in _PHYSICS_NOTED:
        _PHYSICS_NOTED.add(key)
        print(f"warning: {run_dir}: {note}", file=sys.stderr, flush=True)


_PHYSICS_NOTED: set = set()
