"""Multi-process training (daddpg_jax/running/distributed.py): two processes on localhost, one
CPU device each, exchanging data through JAX's CPU collectives (gloo).

The reference is one process with two forced host devices: the same mesh of two devices, so
the same algorithm and random streams; the two runs' final parameters must agree.
"""

import json
import os
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from daddpg_jax.running import distributed as dist

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TINY_ARGS = ["--task", "reach", "--num-envs", "4", "--physics", "c", "--set", "n_cycles=1",
             "--set", "n_batches=2", "--set", "hidden=16", "--set", "batch_size=32",
             "--set", "n_test_episodes=6", "--set", "buffer_size=2000", "--save-buffer",
             "--no-progress"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def _env(devices: int = 1) -> dict:
    env = dict(os.environ, JAX_PLATFORMS="cpu",
               PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for name in dist.CLUSTER_SIZE_VARS:
        env.pop(name, None)
    if devices > 1:
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    return env


def _train(args, devices: int = 1, **kw):
    return subprocess.Popen([sys.executable, "-m", "daddpg_jax.cli.train", *args], cwd=ROOT,
                            env=_env(devices), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, **kw)


def _job(args, n: int = 2, timeout: float = 240, per_process=None):
    """Runs `args` as an n-process job on localhost; [(returncode, stdout, stderr)] by id."""
    port = _free_port()
    procs = []
    for i in range(n):
        extra = per_process(i) if per_process else []
        procs.append(_train([*args, *extra, "--coordinator", f"localhost:{port}",
                             "--num-processes", str(n), "--process-id", str(i),
                             "--distributed-timeout", "60"]))
    out = []
    try:
        for p in procs:
            so, se = p.communicate(timeout=timeout)
            out.append((p.returncode, so, se))
    finally:
        for p in procs:
            p.kill()
    return out


def _ok(results):
    for i, (rc, so, se) in enumerate(results):
        assert rc == 0, f"process {i} failed (rc {rc}):\n{so[-2000:]}\n{se[-4000:]}"


def _params(run_dir, tmp_path, name):
    from daddpg_jax.running.export import export_run

    path = export_run(run_dir, tmp_path / f"{name}.npz")
    with np.load(path) as z:
        return {k: z[k] for k in z.files if z[k].dtype.kind == "f"}


@pytest.mark.e2e
def test_two_processes_train_like_one_process_with_two_devices_and_resume(tmp_path):
    job, ref = tmp_path / "job", tmp_path / "ref"
    results = _job([*TINY_ARGS, "--epochs", "2", "--out", str(job)])
    _ok(results)
    (_, so0, _), (_, so1, _) = results
    assert "process 0 of 2, 1 local device" in so0 and "process 1 of 2, 1 local device" in so1
    assert "epoch    2" in so0 and "run dir" in so0   # process 0 reports ...
    assert "epoch" not in so1 and "run dir" not in so1   # ... and process 1 does not
    p = _train([*TINY_ARGS, "--epochs", "2", "--out", str(ref)], devices=2)
    so, se = p.communicate(timeout=240)
    assert p.returncode == 0, se[-4000:]

    a, b = _params(job, tmp_path, "job"), _params(ref, tmp_path, "ref")
    assert a.keys() == b.keys() and a
    assert max(float(np.max(np.abs(a[k] - b[k]))) for k in a) <= 1e-5
    rows = lambda d: (d / "metrics.csv").read_text().splitlines()
    same_cols = [0, 1, 2, 4, 5, 6, 7, 8, 9, 10, 11]   # all but timing
    cut = lambda r: [r.split(",")[i] for i in same_cols]
    assert [cut(r) for r in rows(job)] == [cut(r) for r in rows(ref)]
    cfg = json.loads((job / "config.json").read_text())
    assert cfg["distributed"] == {"num_processes": 2, "process_devices": [1, 1],
                                  "global_devices": 2}
    assert "distributed" not in json.loads((ref / "config.json").read_text())

    # resume on the same layout: one more epoch, on every process from the same step
    _ok(_job(["--resume", str(job), "--epochs", "3", "--no-progress"]))
    assert [int(r.split(",")[0]) for r in rows(job)[1:]] == [1, 2, 3]
    assert sorted(os.listdir(job / "checkpoints")) == ["1", "2", "3"]
    # ... and not on another one
    p = _train(["--resume", str(job), "--epochs", "4", "--no-progress"])
    _, se = p.communicate(timeout=120)
    assert p.returncode == 2 and "resume it on the same layout" in se


@pytest.mark.e2e
def test_processes_with_different_configs_stop_with_an_error(tmp_path):
    out = tmp_path / "run"
    results = _job([*TINY_ARGS, "--epochs", "1", "--out", str(out)], timeout=120,
                   per_process=lambda i: ["--seed", str(i)])
    for rc, _, se in results:
        assert rc == 2, se[-3000:]
        assert "differs from process 0's" in se
    assert not (out / "checkpoints").exists()


@pytest.mark.e2e
def test_unreachable_coordinator_is_a_clear_error_not_a_hang(tmp_path):
    t0 = time.monotonic()
    p = _train([*TINY_ARGS, "--out", str(tmp_path / "run"), "--coordinator",
                f"localhost:{_free_port()}", "--num-processes", "2", "--process-id", "1",
                "--distributed-timeout", "3"])
    _, se = p.communicate(timeout=120)
    assert p.returncode == 2
    assert "no coordinator answered at localhost:" in se and "within 3 s" in se
    assert "Traceback" not in se
    assert time.monotonic() - t0 < 60


def test_cluster_variables_decide_only_above_one_process():
    assert dist.cluster_size({}) == 1
    assert dist.cluster_size({"SLURM_STEP_NUM_TASKS": "1"}) == 1
    assert dist.cluster_size({"SLURM_STEP_NUM_TASKS": "4", "OMPI_COMM_WORLD_SIZE": "x"}) == 4
    assert dist.cluster_size({"OMPI_COMM_WORLD_SIZE": "2"}) == 2
    # a batch script's own process (no srun step) is one process whatever the allocation
    assert dist.cluster_size({"SLURM_NTASKS": "8", "SLURM_JOB_ID": "1"}) == 1
    # a plain run, or a cluster of one, stays single-process (returns before touching JAX)
    assert dist.join(environ={}) is None
    assert dist.join(environ={"SLURM_STEP_NUM_TASKS": "1"}) is None
    assert dist.join("localhost:1234", 1, 0) is None


@pytest.mark.parametrize("kw, match", [
    (dict(coordinator="localhost:1234"), "go together"),
    (dict(coordinator="localhost:1234", num_processes=2), "go together"),
    (dict(coordinator="localhost", num_processes=2, process_id=0), "HOST:PORT"),
    (dict(coordinator="localhost:99999", num_processes=2, process_id=0), "HOST:PORT"),
    (dict(coordinator="localhost:1234", num_processes=2, process_id=2), "process id"),
    (dict(coordinator="localhost:1234", num_processes=2, process_id=0, timeout=0), "> 0"),
])
def test_join_flags_are_checked(kw, match):
    with pytest.raises(dist.DistributedError, match=match):
        dist.join(**kw, environ={})


def test_single_process_helpers_are_no_ops():
    assert not dist.is_multiprocess() and dist.is_primary()
    assert dist.from_primary({"a": [1, 2]}) == {"a": [1, 2]}
    assert dist.agree_ok(True) == [] and dist.agree_ok(False) == [0]
    dist.check_same_config({"x": 1})
    dist.barrier("x")
    assert dist.on_primary(lambda a: a + 1, 1) == 2
    assert dist.config_digest({"a": 1, "b": 2}) == dist.config_digest({"b": 2, "a": 1})
    layout = dist.Layout(num_processes=2, process_id=1, process_devices=(4, 4),
                         global_devices=8)
    assert layout.to_dict() == {"num_processes": 2, "process_devices": [4, 4],
                                "global_devices": 8}
