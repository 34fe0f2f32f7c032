"""The golden record: one training epoch of each task (2 envs, seed 0, C engine), its
metrics.csv values without the timing columns. A refactor must reproduce them
(tests/test_golden_epoch.py); a deliberate change of behaviour (physics, presets) records
them again, in its own commit:

    python -m tests.golden_epoch          # rewrites tests/data/golden_epoch.json
"""
import csv
import json
import os
import tempfile

from daddpg_jax.cli.train import main

TASKS = ("reach", "push", "pickup", "pot")
TIMING = ("wall_time", "env_steps_per_s", "updates_per_s", "rollout_time", "update_time",
          "eval_time")
"""metrics.csv columns that measure time, not behaviour"""
RECORD = os.path.join(os.path.dirname(__file__), "data", "golden_epoch.json")
PINNED = ("--env", "physics_version=2")
"""the physics the record was taken with: version 2 (version 3 changed pot's finger-handle
contacts; on the C engine the other tasks act in versions 2 and 3 alike)"""


def epoch_metrics(task: str, out: str) -> dict:
    """Trains ``task`` for one epoch into ``out`` and returns the epoch's metrics.csv row
    (floats; timing columns left out)."""
    code = main(["--task", task, "--num-envs", "2", "--epochs", "1", "--seed", "0",
                 "--physics", "c", "--out", out, "--force", "--no-progress",
                 "--no-tensorboard", *PINNED])
    if code not in (0, None):
        raise RuntimeError(f"daddpg-train {task} exited {code}")
    with open(os.path.join(out, "metrics.csv")) as f:
        (row,) = list(csv.DictReader(f))
    return {k: float(v) for k, v in row.items() if k not in TIMING}


if __name__ == "__main__":
    record = {}
    with tempfile.TemporaryDirectory() as tmp:
        for task in TASKS:
            record[task] = epoch_metrics(task, os.path.join(tmp, task))
            print(task, record[task], flush=True)
    with open(RECORD, "w") as f:
        json.dump(record, f, indent=1, sort_keys=True)
        f.write("\n")
