"""Files written by earlier versions still load: a run directory (config.json + orbax checkpoint)
and an exported policy .npz, both written by the flat-layout version of the package (before the
subpackages and the field schema). tests/data/legacy_reach holds them, and the actions that
version's NumPy policy computed for fixed inputs."""

import os
import shutil

import numpy as np
import pytest

from daddpg_jax.cli import export as export_cli
from daddpg_jax.cli import train as train_cli
from daddpg_jax.deploy import NumpyPolicy
from daddpg_jax.running import checkpoint as ckpt

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "legacy_reach")


@pytest.fixture(scope="module")
def reference():
    with np.load(os.path.join(DATA, "reference_actions.npz")) as f:
        return {k: f[k] for k in f.files}


def test_old_policy_file_gives_the_old_actions(reference):
    pol = NumpyPolicy.load(os.path.join(DATA, "policy.npz"))
    got = pol.act(reference["observation"], reference["desired_goal"])
    # float32 matrix products round differently on different CPUs (BLAS kernels): 1e-6 apart
    np.testing.assert_allclose(got, reference["action"], rtol=0, atol=1e-5)


@pytest.fixture
def old_run(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(os.path.join(DATA, "run"), run)
    return str(run)


@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_old_run_exports_and_resumes(old_run, tmp_path, reference):
    cfg, _ = ckpt.load_config(old_run)
    assert cfg.hidden == (16,) and cfg.task == "reach"
    out = str(tmp_path / "policy.npz")
    assert export_cli.main([old_run, "--out", out]) == 0
    exported = NumpyPolicy.load(out)
    got = exported.act(reference["observation"], reference["desired_goal"])
    np.testing.assert_allclose(got, reference["action"], atol=1e-6)
    # it acts with the physics it was trained on (no record: version 1), and keeps it
    assert exported.meta["physics_version"] == exported.env["physics_version"] == 1
    assert train_cli.main(["--resume", old_run, "--epochs", "2", "--no-progress"]) == 0
    assert ckpt.all_steps(old_run)[-1] == 2
    _, payload = ckpt.load_config(old_run)
    assert payload.get("physics_version", 1) == payload["env_overrides"]["physics_version"] == 1
