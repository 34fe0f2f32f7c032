"""Episode starts shared by the trainer's evaluation and the robot client: a file of N episodes'
desired goals [N, 2, 3] and initial states qpos [N, nq] (NumPy only).

``daddpg-evaluate RUN --save-starts FILE`` writes the episodes it played (their goals and
first states, with the success it measured on each); ``daddpg-robot-client --arms sim|ur-sim
--starts FILE`` plays the same episodes in the simulated cell, so the two success rates are
paired episode by episode (``experiments/limits_match.py``; docs/DEPLOYMENT.md, "Training under
the robot's limits"). The file is a NumPy ``.npz`` without pickled objects: arrays ``goal``,
``qpos``, optionally ``success`` [N] (bool), and ``meta``, a JSON string holding ``format``
(`FORMAT`), ``task`` and what wrote it.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import numpy as np

FORMAT = "daddpg-episode-starts/1"
"""the ``format`` a starts file's meta names (another one is refused)"""


class StartsError(ValueError):
    """A starts file that cannot be used; the message is one line naming the file."""


@dataclass(frozen=True)
class EpisodeStarts:
    """N episodes' starts: ``goal`` [N, 2, 3] and ``qpos`` [N, nq] float32, ``success`` [N]
    bool or None (the writer's outcome per episode), ``meta`` (task, format, writer's fields)."""
    goal: np.ndarray
    qpos: np.ndarray
    success: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    @property
    def task(self) -> str:
        return str(self.meta.get("task", ""))

    def __len__(self) -> int:
        return len(self.goal)


def save(path: str, task: str, goal, qpos, success=None, **meta) -> str:
    """Writes N episodes' starts to ``path`` (``.npz`` is added when missing) and returns the
    path written. ``meta``: JSON-able fields recorded beside ``task`` (seed, run, checkpoint,
    physics, ...). ValueError for inconsistent shapes or non-finite values."""
    goal = np.asarray(goal, np.float32)
    qpos = np.asarray(qpos, np.float32)
    _check(goal, qpos, success, "the starts to save")
    arrays = dict(goal=goal, qpos=qpos,
                  meta=np.array(json.dumps({"format": FORMAT, "task": task, **meta})))
    if success is not None:
        arrays["success"] = np.asarray(success, bool).reshape(len(goal))
    path = path if path.endswith(".npz") else path + ".npz"
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp.npz"
    np.savez(tmp, **arrays)
    os.replace(tmp, path)   # a crash leaves the old file or none, never half of one
    return path


def load(path: str, task: str | None = None, nq: int | None = None) -> EpisodeStarts:
    """The starts in ``path``; StartsError (one line) when it cannot be read, is not a starts
    file, has inconsistent or non-finite arrays, or (when given) is for another ``task`` or
    another number of state coordinates ``nq``."""
    where = f"--starts {path}"
    try:
        with np.load(path, allow_pickle=False) as f:
            arrays = {k: f[k] for k in f.files}
        meta = json.loads(str(arrays["meta"]))
    except FileNotFoundError:
        raise StartsError(f"{where}: no such file") from None
    except (OSError, ValueError, KeyError) as e:
        raise StartsError(f"{where}: not a starts file written by daddpg-evaluate "
                          f"--save-starts ({' '.join(str(e).split())[:120]})") from None
    found = meta.get("format") if isinstance(meta, dict) else None
    if found != FORMAT:
        raise StartsError(f"{where}: format {found!r}, expected {FORMAT!r}")
    for k in ("goal", "qpos"):
        if k not in arrays:
            raise StartsError(f"{where}: no {k!r} array")
    goal = arrays["goal"].astype(np.float32)
    qpos = arrays["qpos"].astype(np.float32)
    success = arrays.get("success")
    try:
        _check(goal, qpos, success, where)
    except ValueError as e:
        raise StartsError(str(e)) from None
    if task is not None and meta.get("task") != task:
        raise StartsError(f"{where}: starts of the {meta.get('task')!r} task, the run's task is "
                          f"{task!r}")
    if nq is not None and qpos.shape[1] != nq:
        raise StartsError(f"{where}: states of {qpos.shape[1]} coordinates, the {task or ''} "
                          f"model has {nq} (another physics version or scene?)")
    return EpisodeStarts(goal, qpos, None if success is None else success.astype(bool), meta)


def _check(goal, qpos, success, where: str) -> None:
    if goal.ndim != 3 or goal.shape[1:] != (2, 3) or len(goal) < 1:
        raise ValueError(f"{where}: goal must be [N, 2, 3] with N >= 1, got {list(goal.shape)}")
    if qpos.ndim != 2 or len(qpos) != len(goal):
        raise ValueError(f"{where}: qpos must be [N, nq] with the goals' N = {len(goal)}, got "
                         f"{list(qpos.shape)}")
    if success is not None and np.asarray(success).size != len(goal):
        raise ValueError(f"{where}: success must hold N = {len(goal)} values, got "
                         f"{np.asarray(success).size}")
    for name, a in (("goal", goal), ("qpos", qpos)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{where}: {name} holds non-finite values")
