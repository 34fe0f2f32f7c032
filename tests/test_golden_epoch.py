"""One epoch of each task (2 envs, seed 0, C engine) reproduces the golden record of this
machine class (tests/data/golden_epoch*.json, written by ``python -m tests.golden_epoch``; see
`tests.golden_epoch.machine_class`): every metrics.csv value except the timing columns.
Guards refactors against silent changes of behaviour. On a CPU of no record class the epoch
must reproduce one of the records, or else the machine-independent part (with a warning).
Cost: ~25-50 s per task (compile + one epoch), e2e tier; the class tests ~0 s, default tier."""
import json
import math
import warnings

import numpy as np
import pytest

from tests.golden_epoch import (
    CLASS,
    RECORD,
    RTOL,
    TASKS,
    epoch_metrics,
    machine_class,
    machine_independent,
    matching_record,
)


@pytest.mark.e2e
@pytest.mark.parametrize("task", TASKS)
def test_one_epoch_matches_the_golden_record(task, tmp_path):
    with open(RECORD) as f:
        want = json.load(f)[task]
    got = epoch_metrics(task, str(tmp_path / task))
    assert sorted(got) == sorted(want), "metrics.csv columns changed"
    if CLASS is None:
        if matching_record(task, got) is not None:
            return
        assert not machine_independent(got, want), machine_independent(got, want)
        warnings.warn(f"this CPU has no golden record class; {task}'s epoch was held to the "
                      "machine-independent part of the record only (add a class in "
                      "tests/golden_epoch.py and run python -m tests.golden_epoch)", stacklevel=2)
        return
    for k in want:
        np.testing.assert_allclose(got[k], want[k], rtol=RTOL, atol=0, err_msg=k)


def _cpuinfo(vendor: str, flags: str) -> str:
    return f"processor\t: 0\nvendor_id\t: {vendor}\nflags\t\t: fpu sse2 {flags}\n"


def test_machine_classes_from_cpuinfo():
    assert machine_class(_cpuinfo("AuthenticAMD", "avx avx2 fma")) == "amd-avx2"
    assert machine_class(_cpuinfo("AuthenticAMD", "avx2 avx512f")) is None
    assert machine_class(_cpuinfo("GenuineIntel", "avx2 avx512f avx512_bf16 amx_tile")) == \
        "intel-amx"
    assert machine_class(_cpuinfo("GenuineIntel", "avx2 avx512f")) is None
    assert machine_class(_cpuinfo("GenuineIntel", "avx2 amx_tile")) is None
    assert machine_class("") is None


def test_records_agree_on_what_no_cpu_changes():
    """Every record has the same columns and counts; the records of different CPUs differ
    (were they equal, one record would do)."""
    from tests.golden_epoch import RECORDS
    recs = {}
    for name, path in RECORDS.items():
        with open(path) as f:
            recs[name] = json.load(f)
    ref = recs["reference"]
    for name, rec in recs.items():
        assert sorted(rec) == sorted(TASKS)
        for task in TASKS:
            assert machine_independent(rec[task], ref[task]) == [], (name, task)
            assert matching_record(task, rec[task]) is not None
    for task in TASKS:
        assert len({json.dumps(r[task], sort_keys=True) for r in recs.values()}) == len(recs)


def test_machine_independent_flags_counts_rates_and_nan():
    with open(RECORD) as f:
        want = json.load(f)["reach"]
    assert machine_independent(dict(want), want) == []
    bad = dict(want, env_steps=want["env_steps"] + 1)
    assert any("env_steps" in b for b in machine_independent(bad, want))
    bad = dict(want, test_success_rate=1.5)
    assert any("test_success_rate" in b for b in machine_independent(bad, want))
    bad = dict(want, critic_loss=math.nan)
    assert any("critic_loss" in b for b in machine_independent(bad, want))
    assert "metrics.csv columns" in machine_independent({"epoch": 1.0}, want)[0]
