"""compare_sb3.py end to end for our side (SB3 and torch are an optional extra, not in [dev])."""

import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_compare_ours_only_writes_results(tmp_path):
    out = str(tmp_path / "cmp")
    cmd = [sys.executable, os.path.join(ROOT, "experiments", "compare_sb3.py"), "--task", "reach",
           "--methods", "single", "--time-budget", "20", "--eval-episodes", "20", "--out", out]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-2000:]
    files = os.listdir(out)
    assert "results.json" in files and "results.md" in files, files
    data = json.load(open(os.path.join(out, "results.json")))
    text = json.dumps(data)
    assert "single" in text and "env_steps" in text


def test_compare_rejects_unknown_method(tmp_path):
    cmd = [sys.executable, os.path.join(ROOT, "experiments", "compare_sb3.py"),
           "--methods", "ppo", "--out", str(tmp_path / "x")]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert res.returncode == 2 and "unknown method" in res.stderr
