"""One epoch of each task (2 envs, seed 0, C engine) reproduces the golden record of this
machine class (tests/data/golden_epoch*.json, written by ``python -m tests.golden_epoch``; see
`tests.golden_epoch.machine_class`): every metrics.csv value except the timing columns.
Guards refactors against silent changes of behaviour.
Cost: ~25-50 s per task (compile + one epoch), e2e tier."""
import json

import numpy as np
import pytest

from tests.golden_epoch import RECORD, TASKS, epoch_metrics


@pytest.mark.e2e
@pytest.mark.parametrize("task", TASKS)
def test_one_epoch_matches_the_golden_record(task, tmp_path):
    with open(RECORD) as f:
        want = json.load(f)[task]
    got = epoch_metrics(task, str(tmp_path / task))
    assert sorted(got) == sorted(want), "metrics.csv columns changed"
    for k in want:
        # float32 values written as float64 text; 1e-6 relative leaves room only for the last
        # float32 bit (a changed success, step or update count differs by far more)
        np.testing.assert_allclose(got[k], want[k], rtol=1e-6, atol=0, err_msg=k)
