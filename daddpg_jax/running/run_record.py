"""What a training run has written to its directory, and how it resumes from it: the
metrics.csv rows (columns: `daddpg_jax.running.metric_columns`), the end of an epoch
(`RunLog.commit`: CSV row, checkpoint, best checkpoint), the checks and lock of a run directory
before a run, and the resume from the newest readable checkpoint (`resume`, `restore_readable`).
The loop of epochs that calls these is ``daddpg_jax.running.runner``; the layout of a run
directory and its crash safety are in that module's docstring.
"""

from __future__ import annotations

import csv
import io
import math
import os
import sys
from dataclasses import dataclass

from daddpg_jax.algo.config import TrainConfig
from daddpg_jax.running import checkpoint as ckpt
from daddpg_jax.running import distributed as dist
from daddpg_jax.running.metric_columns import METRIC_COLUMNS


def warn(msg: str) -> None:
    """One line on stderr (from process 0 only in a multi-process job)."""
    if dist.is_primary():
        print(f"warning: {msg}", file=sys.stderr, flush=True)


def read_rows(path) -> list[dict]:
    """metrics.csv's rows; a torn row (cut short by a kill while an older version appended it)
    is left out."""
    if not os.path.exists(path):
        return []
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    good = []
    for r in rows:
        try:
            int(r["epoch"])
        except (KeyError, TypeError, ValueError):
            continue
        if None not in r and None not in r.values():
            good.append(r)
    return good


def write_rows(path, rows: list[dict], columns: tuple = METRIC_COLUMNS) -> None:
    """Rewrites metrics.csv whole through a temporary file and os.replace: a kill at any moment
    leaves the old file or the new one. `columns`: the run's (`metric_columns.metric_columns`)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\r\n")
    w.writeheader()
    for row in rows:
        w.writerow({k: row.get(k, "") for k in columns})
    ckpt.write_atomic(path, buf.getvalue())


def success_of(row) -> float:
    try:
        v = float(row["test_success_rate"])
    except (KeyError, TypeError, ValueError):
        return math.nan
    return v


@dataclass
class RunLog:
    """What a run has written: its CSV rows, the best test success among them (the one in
    checkpoints_best/), the wall time of the epochs before this call, and the CSV's columns."""
    run_dir: str
    rows: list
    best: float = -math.inf
    wall_offset: float = 0.0
    columns: tuple = METRIC_COLUMNS

    @property
    def epoch(self) -> int:
        return int(self.rows[-1]["epoch"]) if self.rows else 0

    def commit(self, cfg: TrainConfig, state, row: dict) -> None:
        """The end of an epoch: CSV row (atomic rewrite), checkpoint, then the best one. In a
        multi-process job every process saves its part of the checkpoint; process 0 alone
        writes the CSV and the best checkpoint's copy."""
        self.rows.append(row)
        primary = dist.is_primary()
        if primary:
            write_rows(os.path.join(self.run_dir, "metrics.csv"), self.rows, self.columns)
        epoch = int(row["epoch"])
        ckpt.save(self.run_dir, state, epoch, save_buffer=cfg.save_buffer,
                  keep=cfg.keep_checkpoints)   # CheckpointSaveError: one line, run resumable
        if success_of(row) > self.best:
            if primary:
                try:
                    ckpt.save_best(self.run_dir, epoch)
                except OSError as e:
                    raise ckpt.CheckpointSaveError(
                        f"could not copy checkpoint {epoch} to "
                        f"{ckpt.checkpoint_dir(self.run_dir, best=True)} ({ckpt.root_cause(e)});"
                        f" free space or fix the cause, then resume with daddpg-train --resume "
                        f"{self.run_dir}") from e
            self.best = success_of(row)
        dist.barrier(f"daddpg-epoch-{epoch}")


def check_resume_layout(run_dir: str, layout) -> None:
    """A run resumes on the process layout it was started on (a buffer saved on n devices
    restores on n devices; the processes' devices hold its shards)."""
    try:
        _, payload = ckpt.load_config(run_dir)
    except (OSError, ValueError, KeyError):
        return   # resume reports what is missing
    saved = payload.get("distributed")
    now = layout.to_dict() if layout is not None else None
    if saved != now:
        def describe(d):
            return ("one process" if d is None else
                    f"{d['num_processes']} processes with {d['process_devices']} devices")
        raise ckpt.RunDirError(f"{run_dir!r} was trained by {describe(saved)}; this job has "
                          f"{describe(now)}: resume it on the same layout")


def prepare_run_dir(run_dir: str, resume: bool, force: bool) -> None:
    """Checks run_dir before anything compiles and takes its lock (held until `train` returns;
    RunLockedError when another process holds it); with force deletes the run in it."""
    if os.path.exists(run_dir) and not os.path.isdir(run_dir):
        raise ckpt.RunDirError(f"{run_dir!r} is a file, not a run directory")
    if resume:
        if force:
            raise ValueError("resume and force exclude each other")
        if not os.path.exists(os.path.join(run_dir, "config.json")):
            raise ckpt.RunDirError(f"{run_dir!r} has no config.json: not a training run directory "
                              "(nothing to resume)")
    ckpt.lock_run_dir(run_dir)
    if resume:
        return
    try:
        _prepare_new_run_dir(run_dir, force)
    except BaseException:
        ckpt.unlock_run_dir(run_dir)
        raise


def _prepare_new_run_dir(run_dir: str, force: bool) -> None:
    if force:
        ckpt.wipe_run(run_dir)
    else:
        steps = ckpt.all_steps(run_dir) or ckpt.all_steps(run_dir, best=True)
        if steps:
            raise ckpt.RunDirError(f"{run_dir!r} already holds a run (checkpoints {steps}); resume "
                              "it, or delete it first (force=True, daddpg-train --force)")
        ckpt.remove_run_files(run_dir)   # leftovers of a run killed in its first epoch
    os.makedirs(run_dir, exist_ok=True)


def _restore_newest_readable(run_dir: str, template, steps: list):
    """(state, step) of the newest of `steps` that restores, and the [(step, error)] of the
    newer ones that did not (each warned about). In a multi-process job the processes agree:
    the newest step that every process can read."""
    bad = []
    for step in reversed(steps):
        why = None
        try:
            ckpt.verify(run_dir, step)
        except Exception as e:  # noqa: BLE001 (TensorStore, orbax, OS errors: all unreadable)
            why = ckpt.root_cause(e)
        failed = dist.agree_ok(why is None)
        if failed and why is None:
            why = f"unreadable on process {', '.join(map(str, failed))}"
        if not failed:
            try:
                state, step = ckpt.restore(run_dir, template, step)
                return state, step, bad
            except Exception as e:  # noqa: BLE001 (as above)
                if dist.is_multiprocess():
                    raise
                why = ckpt.root_cause(e)
        _quiet_failed_reads()
        warn(f"checkpoint {step} ({ckpt.step_dir(run_dir, step)}) cannot be read "
             f"({why}); trying an older one")
        bad.append((step, why))
    return None, None, bad


def restore_readable(run_dir: str, template, step: int | None = None, best: bool = False):
    """(state, step) for a reader of a run (export, evaluation): checkpoint `step`, or (None)
    the newest readable one, older ones tried after a warning naming each unreadable one, as
    `--resume` does; nothing is deleted. CheckpointError (one line) when none can be read."""
    steps = [int(step)] if step is not None else ckpt.all_steps(run_dir, best)
    bad = []
    for s in reversed(steps):
        try:
            ckpt.verify(run_dir, s, best)
            return ckpt.restore(run_dir, template, s, restore_buffer=False, best=best)
        except Exception as e:  # noqa: BLE001 (TensorStore, orbax, OS errors: all unreadable)
            why = ckpt.root_cause(e)
        _quiet_failed_reads()
        bad.append((s, why))
        if s != steps[0]:
            warn(f"checkpoint {s} ({ckpt.step_dir(run_dir, s, best)}) cannot be read "
                 f"({why}); using an older one")
    if not bad:
        raise ckpt.CheckpointError(f"run {run_dir} has no checkpoint")
    if step is not None:
        raise ckpt.CheckpointError(f"checkpoint {step} of {run_dir} cannot be read ({bad[0][1]})")
    tried = ", ".join(str(s) for s, _ in bad)
    raise ckpt.CheckpointError(f"no checkpoint of {run_dir} can be read (tried {tried}; newest: "
                          f"{bad[0][1]})")


def _quiet_failed_reads() -> None:
    """After a failed restore, orbax's other reads of that checkpoint fail too, and Python
    prints each as 'Exception ignored in: <coroutine ...>' with a long traceback when it
    collects them (at exit); the warning already said it. Drops those, nothing else."""
    prev = sys.unraisablehook
    if getattr(prev, "_daddpg_quiet", False):
        return

    def hook(u):
        name = getattr(getattr(u.object, "cr_code", None), "co_filename", "")
        if "orbax" in name or "tensorstore" in name:
            return
        prev(u)

    hook._daddpg_quiet = True
    sys.unraisablehook = hook


def resume(run_dir: str, template, columns: tuple = METRIC_COLUMNS):
    """(state restored from the newest readable checkpoint, its RunLog). metrics.csv is rewritten
    (with `columns`) without the rows of later epochs (a kill between the CSV write and the
    checkpoint, or an unreadable checkpoint), newer unreadable checkpoints are deleted, and
    checkpoints_best/ is made to agree with the CSV. No complete checkpoint: warns and starts
    from epoch 0."""
    metrics_path = os.path.join(run_dir, "metrics.csv")
    primary = dist.is_primary()
    dist.on_primary(ckpt.remove_partial, run_dir)
    rows = read_rows(metrics_path)
    # process 0's list on every process, so that all of them try the same steps in the same
    # order (each step's readability is then agreed on by all: _restore_newest_readable)
    steps = dist.from_primary(ckpt.all_steps(run_dir))
    if not steps:
        warn(f"{run_dir} has no complete checkpoint (the run was stopped during its first "
             "epoch); starting it again from epoch 0")
        if primary:
            ckpt.remove_steps(run_dir, ckpt.all_steps(run_dir, best=True), best=True)
            write_rows(metrics_path, [], columns)
        dist.barrier("daddpg-resume")
        return template, RunLog(run_dir, [], columns=columns)
    state, step, bad = _restore_newest_readable(run_dir, template, steps)
    if state is None:
        raise ckpt.CheckpointError(
            f"no checkpoint of {run_dir} can be read (tried {', '.join(str(s) for s, _ in bad)};"
            f" newest: {bad[0][1]}); if --set changed a field that fixes array shapes "
            "(hidden, buffer_size, ...), resume without it, else start the run again with "
            "--force")
    if bad:
        warn(f"resuming from checkpoint {step}; deleting the unreadable checkpoint(s) "
             f"{', '.join(str(s) for s, _ in bad)}")
    rows = [r for r in rows if int(r["epoch"]) <= step]
    log = RunLog(run_dir, rows, wall_offset=float(rows[-1]["wall_time"]) if rows else 0.0,
                 columns=columns)
    if primary:
        ckpt.remove_steps(run_dir, [s for s, _ in bad])
        write_rows(metrics_path, rows, columns)
        log.best = _reconcile_best(run_dir, rows)
    dist.barrier("daddpg-resume")
    return state, log


def _reconcile_best(run_dir: str, rows: list) -> float:
    """Makes checkpoints_best/ hold the checkpoint of the CSV row with the best test success
    (earliest of ties), copying it from checkpoints/ if a kill came before the copy; if it is
    on disk nowhere, the best one that is (with a warning). Returns its test success."""
    cands = sorted(((success_of(r), int(r["epoch"])) for r in rows
                    if not math.isnan(success_of(r))), key=lambda c: (-c[0], c[1]))
    best_steps = set(ckpt.all_steps(run_dir, best=True))
    main_steps = set(ckpt.all_steps(run_dir))
    for i, (value, epoch) in enumerate(cands):
        if epoch not in best_steps and epoch not in main_steps:
            continue
        if epoch not in best_steps:
            ckpt.save_best(run_dir, epoch)
        ckpt.remove_steps(run_dir, best_steps - {epoch}, best=True)
        if i > 0:
            warn(f"the best checkpoint (epoch {cands[0][1]}, test success {cands[0][0]:.3f}) "
                 f"is not on disk; epoch {epoch} (test success {value:.3f}) is kept as the "
                 "best one instead")
        return value
    ckpt.remove_steps(run_dir, best_steps, best=True)
    if cands:
        warn(f"the best checkpoint (epoch {cands[0][1]}) is not on disk, nor any other epoch "
             "of metrics.csv; the next epochs start the best checkpoint again")
    return -math.inf
