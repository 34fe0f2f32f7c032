"""scripted_demo.py: the zero-action baseline leaves the object in place and reports it."""

import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _run(*args):
    cmd = [sys.executable, os.path.join(ROOT, "experiments", "scripted_demo.py"), *args]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=600)


def test_zero_policy_baseline_on_pot():
    r = _run("--task", "pot", "--policy", "zero", "--episodes", "3")
    assert r.returncode == 0, r.stderr
    assert "success 0.00 (0/3) with zero actions on physics=c" in r.stdout
    m = re.search(r"final goal distance, m: left ([\d.]+) right ([\d.]+)", r.stdout)
    # goals are 0.05-0.12 m above the resting pot: an unmoved pot is at least 0.05 m from them
    assert m and all(0.05 <= float(x) <= 0.2 for x in m.groups()), r.stdout


def test_bad_env_override_is_an_error():
    r = _run("--task", "pot", "--policy", "zero", "--env", "no_such_field=1")
    assert r.returncode != 0 and "unknown --env field 'no_such_field'" in (r.stdout + r.stderr)
