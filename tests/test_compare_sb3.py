"""experiments/sb3/compare_sb3.py end to end for our side (SB3 and torch are an optional extra,
not in [dev])."""

import json
import os
import subprocess
import sys

import pytest

from experiments.sb3 import compare_sb3
from experiments.sb3 import harness as sb3_compare
from tests.conftest import call_main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(ROOT, "experiments", "sb3", "compare_sb3.py")


@pytest.mark.e2e
def test_compare_ours_only_writes_results(tmp_path):
    out = str(tmp_path / "cmp")
    cmd = [sys.executable, SCRIPT, "--task", "reach",
           "--methods", "single", "--time-budget", "20", "--eval-episodes", "20", "--out", out]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-2000:]
    files = os.listdir(out)
    assert "results.json" in files and "results.md" in files, files
    data = json.load(open(os.path.join(out, "results.json")))
    text = json.dumps(data)
    assert "single" in text and "env_steps" in text


def test_compare_rejects_unknown_method(tmp_path, capsys):
    code = call_main(compare_sb3.main, ["--methods", "ppo", "--out", tmp_path / "x"])
    assert code == 2 and "unknown method" in capsys.readouterr().err


def _parse(*argv):
    return sb3_compare, compare_sb3.build_parser().parse_args(list(argv))


def test_sb3_schedule_matches_ours_per_cycle():
    cmp, args = _parse("--task", "reach")
    # legacy: one env, 20 gradient steps per 50-step episode = our 2-env replay ratio (0.4)
    assert cmp.sb3_schedule(args) == (1, (1, "episode"), 20)
    assert cmp.sb3_eval_every(args) == 2000
    cmp, args = _parse("--task", "reach", "--num-envs", "32", "--updates-per-cycle", "10",
                       "--cycles-per-epoch", "3")
    # N envs: U gradient steps after every 50 steps of all envs, evaluated once per epoch of ours
    assert cmp.sb3_schedule(args) == (32, (50, "step"), 10)
    assert cmp.sb3_eval_every(args) == 3 * 32 * 50
    cmp, args = _parse("--task", "push", "--num-envs", "8")
    assert cmp.sb3_schedule(args) == (8, (50, "step"), 40)
    assert cmp.sb3_eval_every(args) == 50 * 8 * 50


@pytest.mark.e2e
def test_compare_ours_many_envs_settings(tmp_path):
    out = str(tmp_path / "cmp")
    cmd = [sys.executable, SCRIPT, "--task", "reach",
           "--methods", "single", "--time-budget", "5", "--eval-episodes", "10",
           "--num-envs", "4", "--updates-per-cycle", "3", "--cycles-per-epoch", "2", "--out", out]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-2000:]
    data = json.load(open(os.path.join(out, "results.json")))
    settings = data["results"][0]["settings"]
    assert settings["num_envs"] == 4 and settings["n_batches"] == 3 and settings["n_cycles"] == 2
    assert settings["eval_every_env_steps"] == 400
    steps = [r["env_steps"] for r in data["results"][0]["curve"]]
    assert steps and all(s % 400 == 0 for s in steps), steps


def test_compare_rejects_bad_num_envs(tmp_path, capsys):
    code = call_main(compare_sb3.main, ["--num-envs", "0", "--out", tmp_path / "x"])
    assert code == 2 and "--num-envs must be >= 1" in capsys.readouterr().err
