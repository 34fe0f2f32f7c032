"""The golden record: one training epoch of each task (2 envs, seed 0, C engine), its
metrics.csv values without the timing columns. A refactor must reproduce them
(tests/test_golden_epoch.py); a deliberate change of behaviour (physics, presets) records
them again, in its own commit, on each machine class it can reach:

    python -m tests.golden_epoch          # rewrites this machine class's record

XLA compiles the CPU code for the host's instruction set, and one epoch of training carries
the last-bit differences of its float32 sums into every metric (across machines the losses of
one epoch differ by up to 10 %, the success and contact rates by whole episodes). So the record
is kept per machine class (`machine_class`), each held to the same 1e-6:

- ``amd-avx2`` (tests/data/golden_epoch_amd_avx2.json): AMD CPUs without AVX-512 (AMD EPYC
  Zen 2 VMs), taken at a revision whose epochs are bit-identical to the reference record's
  revision on such a machine;
- ``intel-amx`` (tests/data/golden_epoch_intel_amx.json): Intel CPUs with AVX-512 and AMX
  (Intel Xeon VMs, Sapphire Rapids generation), taken at a revision whose four epochs equal
  the values the e2e tier printed on such a VM at the previous revision;
- ``reference`` (tests/data/golden_epoch.json): the machine the record was first taken on; its
  CPU was not recorded, so any other CPU is held to whichever record it reproduces
  (`matching_record`) and, where it reproduces none, to the machine-independent part of the
  record only (`machine_independent`), with a warning that names the command above.
"""
import csv
import json
import math
import os
import sys
import tempfile

from daddpg_jax.cli.train import main

TASKS = ("reach", "push", "pickup", "pot")
TIMING = ("wall_time", "env_steps_per_s", "updates_per_s", "rollout_time", "update_time",
          "eval_time")
"""metrics.csv columns that measure time, not behaviour"""
DATA = os.path.join(os.path.dirname(__file__), "data")
RECORDS = {"reference": os.path.join(DATA, "golden_epoch.json"),
           "amd-avx2": os.path.join(DATA, "golden_epoch_amd_avx2.json"),
           "intel-amx": os.path.join(DATA, "golden_epoch_intel_amx.json")}
RTOL = 1e-6
"""float32 values written as float64 text; 1e-6 relative leaves room only for the last float32
bit (a changed success, step or update count differs by far more)"""
COUNTS = ("epoch", "env_steps", "updates")
"""columns that do not depend on the machine's float rounding"""


def _cpu(info: str) -> tuple[str, set]:
    flags = next((line.split(":", 1)[1].split() for line in info.splitlines()
                  if line.startswith("flags")), [])
    vendor = next((line.split(":", 1)[1].strip() for line in info.splitlines()
                   if line.startswith("vendor_id")), "")
    return vendor, set(flags)


def machine_class(info: str | None = None) -> str | None:
    """The record class of this CPU, read from /proc/cpuinfo (or ``info``, its text):
    ``amd-avx2`` for an AMD CPU with AVX2 and without AVX-512, ``intel-amx`` for an Intel CPU
    with AVX-512 and AMX tiles, else None (a CPU no record was taken on, or none readable)."""
    if info is None:
        try:
            with open("/proc/cpuinfo") as f:
                info = f.read(1 << 16)
        except OSError:
            return None
    vendor, flags = _cpu(info)
    if vendor == "AuthenticAMD" and "avx2" in flags and "avx512f" not in flags:
        return "amd-avx2"
    if vendor == "GenuineIntel" and "avx512f" in flags and "amx_tile" in flags:
        return "intel-amx"
    return None


def matches(got: dict, want: dict) -> bool:
    """Whether ``got`` reproduces the record ``want``: the same columns, each value within
    `RTOL`."""
    return sorted(got) == sorted(want) and all(
        abs(got[k] - want[k]) <= RTOL * abs(want[k]) or got[k] == want[k]
        or (math.isnan(got[k]) and math.isnan(want[k])) for k in want)


def matching_record(task: str, got: dict) -> str | None:
    """The first record class whose ``task`` entry ``got`` reproduces, else None."""
    for name, path in RECORDS.items():
        with open(path) as f:
            if matches(got, json.load(f)[task]):
                return name
    return None


def machine_independent(got: dict, want: dict) -> list[str]:
    """What ``got`` breaks of the part of a record no CPU changes: its columns, its `COUNTS`,
    rates within [0, 1] and finite losses (NaN where the record has NaN). Empty when it holds."""
    bad = []
    if sorted(got) != sorted(want):
        return [f"metrics.csv columns changed: {sorted(set(got) ^ set(want))}"]
    for k in COUNTS:
        if got[k] != want[k]:
            bad.append(f"{k}: {got[k]} != {want[k]}")
    for k, v in got.items():
        if math.isnan(want[k]) != math.isnan(v):
            bad.append(f"{k}: {v} where the record has {want[k]}")
        elif k.endswith("_rate") and not math.isnan(v) and not 0.0 <= v <= 1.0:
            bad.append(f"{k}: {v} outside [0, 1]")
        elif not math.isnan(v) and not math.isfinite(v):
            bad.append(f"{k}: {v} not finite")
    return bad


CLASS = machine_class()
"""this machine's record class (None: no record was taken on this CPU)"""
RECORD = RECORDS[CLASS or "reference"]
"""the record this machine is held to (for an unknown CPU, the one `python -m
tests.golden_epoch` would write)"""
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
    if CLASS is None and "--reference" not in sys.argv[1:]:
        sys.exit("this CPU belongs to no record class (tests.golden_epoch.machine_class); add "
                 "one there, or pass --reference to rewrite tests/data/golden_epoch.json")
    record = {}
    with tempfile.TemporaryDirectory() as tmp:
        for task in TASKS:
            record[task] = epoch_metrics(task, os.path.join(tmp, task))
            print(task, record[task], flush=True)
    with open(RECORD, "w") as f:
        json.dump(record, f, indent=1, sort_keys=True)
        f.write("\n")
    print("wrote", RECORD)
