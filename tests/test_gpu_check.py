"""The GPU check (experiments/gpu_check.sh, daddpg_jax.tools.gpu_check) in its --smoke mode
on the CPU: every stage leaves figures in the JSON and the markdown; a failed or cut-off stage
is recorded and the next one runs."""

import json
import os
import subprocess
import sys

import pytest

from daddpg_jax.tools import gpu_check

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STAGES = ["env", "train_epoch", "learn_reach", "learn_push"]


def _env():
    env = dict(os.environ, PYTHON=sys.executable, JAX_PLATFORMS="cpu")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)   # compile times measured, not cache loads
    return env


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    out = tmp_path_factory.mktemp("gpu_check")
    proc = subprocess.run(["bash", os.path.join(ROOT, "experiments", "gpu_check.sh"), "--smoke",
                           "--out", str(out)], env=_env(), capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    report = json.loads((out / gpu_check.JSON_NAME).read_text())
    return report, (out / gpu_check.MD_NAME).read_text(), out


@pytest.mark.e2e
def test_smoke_json_has_every_stage_with_figures(smoke):
    report, _, out = smoke
    assert report["smoke"] is True and report["finished"] and report["wall_s"] < 120
    dev = report["device"]
    assert dev["device_kind"] and dev["backend"] == "cpu" and dev["jax"] and dev["mujoco"]
    assert "git_revision" in report
    assert list(report["stages"]) == STAGES
    for name, st in report["stages"].items():
        assert st["status"] == "ok", (name, st)
        assert st["rows"] and st["wall_s"] > 0 and st["cap_s"] > 0
    env_rows = report["stages"]["env"]["rows"]
    assert {(r["task"], r["num_envs"]) for r in env_rows} == {
        (t, n) for t in ("push", "pickup") for n in (2, 8)}
    for r in env_rows:
        assert r["env_steps_per_s"] > 0 and r["physics_steps_per_s"] == pytest.approx(
            r["env_steps_per_s"] * r["n_substeps"])
        assert r["compile_s"] >= 0 and r["call_s"] > 0 and r["physics_ok"] == 1.0
    (t,) = report["stages"]["train_epoch"]["rows"]
    assert t["task"] == "reach" and t["num_envs"] == 4 and t["n_cycles"] == 2 and t["finite"]
    assert t["compile_s"] > 0 and t["env_steps_per_s"] > 0 and t["updates_per_s"] > 0
    assert 0 < t["rollout_share"]
    for task in ("reach", "push"):
        (r,) = report["stages"][f"learn_{task}"]["rows"]
        assert r["task"] == task and r["epochs"] == 1 and len(r["curve"]) == 1
        assert r["env_steps"] == r["epoch_env_steps"] > 0 and 0 <= r["best_success"] <= 1
        assert r["reached"] in (True, False) and r["train_wall_s"] > 0
        assert (out / "runs" / task / "metrics.csv").exists()


@pytest.mark.e2e
def test_smoke_markdown_has_every_table(smoke):
    _, md, _ = smoke
    assert md.startswith("# GPU check (smoke run")
    for heading in ("## 1. Env throughput", "## 2. train_epoch", "## 3. Training to 0.9"):
        assert heading in md
    for stage in STAGES:
        assert f"| {stage} | ok |" in md
    assert "| push | c | 8 |" in md and "| pickup | c | 2 |" in md
    assert "| reach | 4 | 32 × 4 | 2 |" in md


@pytest.mark.e2e
def test_failed_and_cut_off_stages_are_recorded(tmp_path, monkeypatch):
    """MJX at 256 envs on a CPU is refused (a recorded error, no hang) and the next stage runs;
    a stage past its time cap is stopped; a failed stage sets the exit code."""
    for k, v in _env().items():
        monkeypatch.setenv(k, v)
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setenv("PYTHONPATH", ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    rc = gpu_check.main(["--smoke", "--out", str(tmp_path / "a"), "--stages", "env",
                         "train_epoch", "--env-tasks", "push", "--env-physics", "mjx",
                         "--env-sizes", "256"])
    assert rc == 1
    report = json.loads((tmp_path / "a" / gpu_check.JSON_NAME).read_text())
    env, tr = report["stages"]["env"], report["stages"]["train_epoch"]
    assert env["status"] == "error" and "256" in env["rows"][0]["error"]
    assert tr["status"] == "ok" and tr["rows"][0]["env_steps_per_s"] > 0
    assert "| env | error |" in (tmp_path / "a" / gpu_check.MD_NAME).read_text()
    # compiling train_epoch alone takes longer than 2 s
    rc = gpu_check.main(["--smoke", "--out", str(tmp_path / "b"), "--stages", "train_epoch",
                         "--stage-seconds", "train_epoch=2"])
    assert rc == 0
    tr = json.loads((tmp_path / "b" / gpu_check.JSON_NAME).read_text())["stages"]["train_epoch"]
    assert tr["status"] == "timeout" and "time cap" in tr["error"] and tr["wall_s"] < 10
    assert "| train_epoch | timeout |" in (tmp_path / "b" / gpu_check.MD_NAME).read_text()


def test_records_merge_and_markdown_of_a_cut_off_stage(tmp_path):
    path = tmp_path / "r.jsonl"
    lines = [{"kind": "device", "device_kind": "NVIDIA H200", "backend": "gpu"},
             {"kind": "plan", "rows": {"push/4096": {"task": "push", "physics": "mjx",
                                                     "num_envs": 4096},
                                       "push/8192": {"task": "push", "physics": "mjx",
                                                     "num_envs": 8192}}},
             {"kind": "row", "key": "push/4096", "task": "push", "num_envs": 4096,
              "compile_s": 12.0, "note": "compiled; timing"}]
    path.write_text("".join(json.dumps(x) + "\n" for x in lines) + '{"kind": "row", "ke')
    records = gpu_check.read_records(str(path))
    assert len(records) == 3   # the torn last line is left out
    args = gpu_check.parse_args(["--out", str(tmp_path)])
    report = gpu_check.new_report(args, ["--out", str(tmp_path)])
    gpu_check.merge_records(report, "env", records)
    gpu_check._set_status(report["stages"]["env"], -15, True, [])
    rows = {r["key"]: r for r in report["stages"]["env"]["rows"]}
    assert rows["push/4096"]["compile_s"] == 12.0 and "skipped" not in rows["push/4096"]
    assert rows["push/8192"]["skipped"]
    md = gpu_check.markdown(report)
    assert "NVIDIA H200" in md and "| env | timeout |" in md
    assert "| push | mjx | 8192 |" in md and "not run: stage ended first" in md
    assert "| learn_push | pending |" in md
