"""The golden record: one training epoch of each task (2 envs, seed 0, C engine), its
metrics.csv values without the timing columns. A refactor must reproduce them
(tests/test_golden_epoch.py); a deliberate change of behaviour (physics, presets) records
them again, in its own commit:

    python -m tests.golden_epoch          # rewrites this machine class's record

XLA compiles the CPU code for the host's instruction set, and one epoch of training carries
the last-bit differences of its float32 sums into every metric. So the record is kept per
machine class (`machine_class`): ``reference`` (tests/data/golden_epoch.json, the machine
the record was first taken on) and ``amd-avx2`` (tests/data/golden_epoch_amd_avx2.json: AMD
CPUs without AVX-512, taken at a revision whose epochs are bit-identical to the reference
record's revision on such a machine). Each class is held to the same 1e-6.
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
DATA = os.path.join(os.path.dirname(__file__), "data")
RECORDS = {"reference": os.path.join(DATA, "golden_epoch.json"),
           "amd-avx2": os.path.join(DATA, "golden_epoch_amd_avx2.json")}


def machine_class() -> str:
    """``amd-avx2`` on an AMD CPU without AVX-512 (read from /proc/cpuinfo), else
    ``reference``."""
    try:
        with open("/proc/cpuinfo") as f:
            info = f.read(1 << 16)
    except OSError:
        return "reference"
    flags = next((line.split(":", 1)[1].split() for line in info.splitlines()
                  if line.startswith("flags")), [])
    amd = "AuthenticAMD" in info
    return "amd-avx2" if amd and "avx2" in flags and "avx512f" not in flags else "reference"


RECORD = RECORDS[machine_class()]
"""the record this machine is held to"""
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
