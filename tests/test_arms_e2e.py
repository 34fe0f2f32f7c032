"""Command-level checks of the UR path (marked e2e): daddpg-serve and daddpg-robot-client as
commands (experiments/*.py in subprocesses) through --arms sim and --arms ur-sim, and
daddpg-calibrate correcting a calibration error of the simulated bases. The policy is the
hand-built reach controller of tests/reach_controller.py. Cost: ~12 s the module."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys

import pytest

from daddpg_jax.deploy.limits import SHIPPED
from tests.reach_controller import write_reach_controller

pytestmark = [pytest.mark.e2e, pytest.mark.usefixtures("arm_recorder")]

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SERVE = os.path.join(ROOT, "experiments", "serve.py")
CLIENT = os.path.join(ROOT, "experiments", "robot_client.py")
CALIBRATE = os.path.join(ROOT, "experiments", "calibrate.py")
ENV = dict(os.environ, JAX_PLATFORMS="cpu")
ERROR = "0.02,0.01,0,2,-0.01,-0.02,0.005,-2"


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    path = write_reach_controller(tmp_path_factory.mktemp("p") / "rc.npz")
    proc = subprocess.Popen([sys.executable, SERVE, path, "--port", "0"], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV)
    m = re.search(r" on (http://\S+) \(", proc.stdout.readline())
    assert m, proc.stderr.read()
    yield m.group(1)
    proc.kill()
    proc.wait()


def _client(url, *args):
    r = subprocess.run([sys.executable, CLIENT, "--server", url, *args], cwd=ROOT, text=True,
                       capture_output=True, env=ENV, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return json.loads(r.stdout)


def test_ur_sim_succeeds_at_the_sim_rate_as_commands(service, tmp_path):
    """~12 s: 30 episodes (same seed, unpaced) through --arms sim and --arms ur-sim: the ur-sim
    rate lies in the sim's 95% CI; with a calibration error of the simulated bases the
    uncalibrated run fails, and after daddpg-calibrate the success is back."""
    lim = tmp_path / "cell.toml"
    shutil.copy(os.path.join(SHIPPED, "sim.toml"), lim)
    common = ["--limits", str(lim), "--fast", "--episodes", "30", "--deadline-ms", "40"]
    sim = _client(service, *common, "--arms", "sim")
    ur = _client(service, *common, "--arms", "ur-sim")
    lo, hi = sim["success_ci95"]
    assert sim["success_rate"] >= 0.8 and lo <= ur["success_rate"] <= hi, (sim, ur)
    assert ur["arms"] == "ur-sim"
    off = _client(service, *common, "--arms", "ur-sim", "--sim-base-error", ERROR)
    assert off["success_rate"] <= 0.1
    r = subprocess.run([sys.executable, CALIBRATE, "--limits", str(lim), "--points",
                        os.path.join(SHIPPED, "board_example.json"), "--arms", "ur-sim",
                        "--sim-base-error", ERROR], cwd=ROOT, text=True, capture_output=True,
                       env=ENV, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "residuals mm" in r.stdout and "[calibration.left]" in lim.read_text()
    fixed = _client(service, *common, "--arms", "ur-sim", "--sim-base-error", ERROR)
    assert lo <= fixed["success_rate"] <= hi, (sim, fixed)
