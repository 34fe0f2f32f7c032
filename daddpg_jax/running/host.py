"""What machine a run or a benchmark ran on (standard library only).

A fixed seed trains deterministically on one host (tests/test_train.py), but XLA compiles for
the CPU it runs on, so two CPU models may round differently (a measured case: docs/RESULTS.md,
"Push trained with latency only, 30 minutes without the stop"). config.json records the host
for that reason.
"""

from __future__ import annotations

import os
import platform


def cpu_name() -> str:
    """The CPU's model name (/proc/cpuinfo on Linux), else `platform.processor()`."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def host_info() -> dict:
    """{cpu, cores, system, python}: the host fields of config.json and the benchmarks."""
    return dict(cpu=cpu_name(), cores=os.cpu_count(), system=platform.platform(),
                python=platform.python_version())
