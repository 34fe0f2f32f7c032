"""reproduce.py on a tiny budget produces every output file in the expected format."""

import csv
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from daddpg_jax.analysis.reproduce import FINAL_COLUMNS, Experiment, experiments, final_row
from daddpg_jax.cli import reproduce as reproduce_cli
from tests.conftest import call_main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_experiment_list():
    pairs = experiments(3, ablations=True)
    labels = [(e.label, s) for e, s in pairs]
    assert labels[:3] == [("daddpg", 0), ("daddpg", 1), ("daddpg", 2)]
    assert {e.label for e, _ in pairs[3:]} == {"maddpg", "ddpg", "single", "daddpg_noher"}
    assert [e.her for e, _ in pairs if e.label == "daddpg_noher"] == ["none"]
    more = experiments(2, ablations=True, first_seed=1)
    assert [(e.label, s) for e, s in more][:2] == [("daddpg", 1), ("daddpg", 2)]
    assert {s for _, s in more[2:]} == {1}
    assert [(e.label, s) for e, s in experiments(1, algos=["ddpg"], first_seed=4)] == [("ddpg", 4)]


def test_cli_rejects_negative_first_seed(capsys):
    assert call_main(reproduce_cli.main, ["--task", "reach", "--first-seed", "-1"]) == 2
    assert "--first-seed must be >= 0" in capsys.readouterr().err


def test_final_row_thresholds():
    rows = [dict(epoch=i + 1, env_steps=(i + 1) * 100, wall_time=10.0 * (i + 1),
                 test_success_rate=s, test_arm_contact_rate=0.1) for i, s in
            enumerate([0.0, 0.6, 0.95, 0.9])]
    r = final_row("reach", Experiment("daddpg", "daddpg", "future"), 0, rows)
    assert r["env_steps_to_0.5"] == 200 and r["wall_time_to_0.9"] == 30.0
    assert r["final_test_success"] == 0.9 and r["best_test_success"] == 0.95
    assert set(r) == set(FINAL_COLUMNS)


def test_final_row_counts_float32_rates_at_the_level():
    """90/100 episodes logged in float32 (0.89999998) reaches 0.9; 89/100 does not."""
    rates = [float(np.float32(0.89)), float(np.float32(0.9)), 1.0]
    rows = [dict(epoch=i + 1, env_steps=(i + 1) * 100, wall_time=10.0 * (i + 1),
                 test_success_rate=s, test_arm_contact_rate=0.1) for i, s in enumerate(rates)]
    r = final_row("push", Experiment("daddpg", "daddpg", "future"), 0, rows)
    assert r["env_steps_to_0.9"] == 200 and r["wall_time_to_0.9"] == 20.0


@pytest.mark.e2e
def test_reproduce_tiny_budget_writes_outputs(tmp_path):
    out = str(tmp_path / "res")
    cmd = [sys.executable, os.path.join(ROOT, "experiments", "reproduce.py"), "--task", "reach",
           "--seeds", "1", "--env-steps", "200", "--budget-minutes", "5", "--out", out,
           "--set", "n_cycles=2", "--set", "n_batches=2", "--set", "hidden=32,32",
           "--set", "n_test_episodes=10", "--set", "buffer_size=10000"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-2000:]
    d = os.path.join(out, "reach")
    for name in ("final.csv", "curves.png", "summary.json"):
        assert os.path.getsize(os.path.join(d, name)) > 0, name
    rows = list(csv.DictReader(open(os.path.join(d, "final.csv"))))
    assert len(rows) == 1 and tuple(rows[0].keys()) == FINAL_COLUMNS
    assert rows[0]["label"] == "daddpg" and int(rows[0]["epochs"]) == 1
    assert int(rows[0]["env_steps"]) == 2 * 2 * 50
    summary = json.load(open(os.path.join(d, "summary.json")))
    assert summary["task"] == "reach" and len(summary["final"]) == 1
    # a second call finds the run complete and does not train again
    res2 = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert res2.returncode == 0 and "done (1 epochs" in res2.stdout
