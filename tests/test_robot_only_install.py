"""The robot side stands alone: `.ci/robot_only.sh` installs the package with ``pip install
--no-deps`` into a fresh venv holding only NumPy, h11 and MuJoCo, and from outside the
repository runs daddpg-serve and daddpg-robot-client (--arms sim and ur-sim, two episodes each);
no JAX, Flax, Optax or Orbax is installed there. Needs the package registry (as CI's install
does). Cost: ~35 s (venv, three installs, two short runs), e2e tier."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.e2e
def test_serve_and_robot_client_run_in_a_venv_without_jax():
    r = subprocess.run(["bash", os.path.join(ROOT, ".ci", "robot_only.sh")],
                       capture_output=True, text=True, timeout=900,
                       env=dict(os.environ, PYTHON=sys.executable))
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "--arms sim: 2 episodes" in r.stdout and "--arms ur-sim: 2 episodes" in r.stdout
    assert "ran without JAX" in r.stdout
