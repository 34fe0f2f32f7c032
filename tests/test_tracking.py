"""Live tracking and honest progress (daddpg_jax/running/tracking.py, cli/train.py): TensorBoard
event files read back, W&B offline, --video-every without a renderer, the progress lines, why a
run stopped, and each console script's --help. Toy-env runs of ~1 s per epoch unless marked."""

from __future__ import annotations

import importlib
import math
import os
import struct
import subprocess
import sys
import time
import tomllib

import pytest

from daddpg_jax.analysis import evaluation
from daddpg_jax.cli import train as train_cli
from daddpg_jax.running import runner, tracking
from daddpg_jax.running.metric_columns import METRIC_COLUMNS
from daddpg_jax.running.progress import Progress, epoch_line
from daddpg_jax.running.runner import train
from tests import conftest, toy_env
from tests.conftest import T, run_options

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TINY = conftest.TINY.replace(n_cycles=2, n_batches=3, n_test_episodes=8, seed=1)
ROW = dict(epoch=3, env_steps=1200, test_success_rate=0.5, test_arm_contact_rate=0.0,
           critic_loss=0.25, env_steps_per_s=900.0)
"""the fields of a metrics.csv row that the epoch line shows"""


@pytest.fixture(scope="module")
def env():
    return toy_env.make(episode_length=T)


def read_events(log_dir: str) -> list:
    """Every Event of the TensorBoard files in log_dir (TFRecord framing: length, its CRC,
    the Event proto, its CRC)."""
    from tensorboardX.proto.event_pb2 import Event

    events = []
    for name in sorted(os.listdir(log_dir)):
        with open(os.path.join(log_dir, name), "rb") as f:
            data = f.read()
        i = 0
        while i < len(data):
            (n,) = struct.unpack("<Q", data[i:i + 8])
            ev = Event()
            ev.ParseFromString(data[i + 12:i + 12 + n])
            events.append(ev)
            i += 12 + n + 4
    return events


def scalars(events) -> dict:
    """{tag: [(step, value)]} of the scalar summaries."""
    out: dict = {}
    for ev in events:
        for v in ev.summary.value:
            if v.HasField("simple_value"):
                out.setdefault(v.tag, []).append((ev.step, v.simple_value))
    return out


# -- TensorBoard ---------------------------------------------------------------------------

@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_tensorboard_event_file_holds_every_column_and_the_config(env, tmp_path):
    """one toy run of 3 epochs (~10 s, mostly compiling), then the event file is read back."""
    run = str(tmp_path / "run")
    res = train(TINY.replace(n_epochs=3), run_options(run, env))
    assert res.stopped == "epochs" and res.summary().endswith("stopped: all 3 epochs done")
    events = read_events(os.path.join(run, tracking.TB_DIR))
    got = scalars(events)
    nan = {c for c in METRIC_COLUMNS if math.isnan(float(res.rows[0][c]))}
    assert nan == {"bc_loss", "q_filter_pass", "train_physics_fault_rate",
                   "test_physics_fault_rate"}    # no demos; the toy env reports no faults
    want = {tracking.tag(c) for c in METRIC_COLUMNS if c != "env_steps" and c not in nan}
    assert set(got) == want, set(got) ^ want
    steps = [int(r["env_steps"]) for r in res.rows]
    for column in set(METRIC_COLUMNS) - nan - {"env_steps"}:
        series = got[tracking.tag(column)]
        assert [s for s, _ in series] == steps                       # x axis: env steps
        for (_, value), row in zip(series, res.rows, strict=True):   # the CSV's values
            assert value == pytest.approx(float(row[column]), rel=1e-6, abs=1e-6)
    assert tracking.tag("test_success_rate") == "test/success_rate"
    assert tracking.tag("critic_loss") == "losses/critic_loss"
    assert tracking.tag("rollout_time") == "time/rollout_time"
    text = [v for ev in events for v in ev.summary.value if v.tag.startswith("config")]
    assert text and '"n_cycles": 2' in text[0].tensor.string_val[0].decode()


@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_tensorboard_resume_continues_the_event_log(env, tmp_path):
    """two toy runs (~20 s, mostly compiling): a resume after a dropped epoch (its CSV row
    written, its checkpoint not) purges that epoch's events: each step once."""
    run = str(tmp_path / "run")
    train(TINY.replace(n_epochs=2), run_options(run, env))
    import shutil

    from daddpg_jax.running import checkpoint as ckpt

    shutil.rmtree(ckpt.step_dir(run, 2))          # as if killed while saving checkpoint 2
    res = train(TINY.replace(n_epochs=3), run_options(run, env, resume=True))
    events = read_events(os.path.join(run, tracking.TB_DIR))
    purge = int(res.rows[0]["env_steps"]) + 1
    assert [ev.step for ev in events if ev.HasField("session_log")] == [purge]
    got = scalars(events)
    # a reader that honours purge_step (TensorBoard) sees each epoch once: the last event of
    # each step is the resumed run's
    latest = {s: v for s, v in got["test/success_rate"]}
    assert sorted(latest) == [int(r["env_steps"]) for r in res.rows]
    assert [latest[int(r["env_steps"])] == pytest.approx(float(r["test_success_rate"]))
            for r in res.rows] == [True] * 3


@pytest.mark.e2e
def test_wandb_offline_logs_the_columns(env, tmp_path, monkeypatch):
    """~10 s (wandb starts a service process): WANDB_MODE=offline, 2 toy epochs; the W&B run's
    summary (its last logged values) holds the columns, and its files are in RUN_DIR/wandb."""
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    run = str(tmp_path / "run")
    seen = {}

    class Recording(tracking.WandbLogger):
        def close(self):
            seen.update(dict(self.run.summary))
            super().close()

    res = train(TINY.replace(n_epochs=2),
                run_options(run, env, loggers=[Recording(run, project="test")]))
    assert {"test/success_rate", "losses/critic_loss", "time/rollout_time",
            "train/success_rate", "progress/epoch"} <= set(seen)
    assert seen["env_steps"] == int(res.rows[-1]["env_steps"])
    assert seen["losses/critic_loss"] == pytest.approx(float(res.rows[-1]["critic_loss"]))
    offline = [n for n in os.listdir(os.path.join(run, "wandb")) if n.startswith("offline-run")]
    assert len(offline) == 1
    assert [n for n in os.listdir(os.path.join(run, "wandb", offline[0])) if n.endswith(".wandb")]


def test_wandb_flag_without_wandb_is_one_line(tmp_path, monkeypatch, capsys):
    """in-process, < 1 s"""
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "wandb" else real(name, *a))
    with pytest.raises(SystemExit) as e:
        train_cli.main(["--task", "reach", "--wandb", "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "daddpg-jax[wandb]" in err and "Traceback" not in err


@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_video_every_without_a_renderer_warns_once(env, tmp_path, capfd):
    """one toy run (~10 s, mostly compiling): the toy env has no MuJoCo scene to render: one
    warning, the run goes on."""
    runner._VIDEO_WARNED.clear()
    res = train(TINY.replace(n_epochs=2),
                run_options(str(tmp_path / "run"), env, video=evaluation.train_video,
                            video_every=1, loggers=[]))
    err = capfd.readouterr().err
    assert res.epochs == 2 and err.count("--video-every: no video") == 1, err
    assert "Traceback" not in err
    assert not os.path.exists(os.path.join(res.run_dir, tracking.TB_DIR))   # loggers=[]


# -- progress and the closing line ---------------------------------------------------------

@pytest.mark.e2e  # a whole training run (default tier kept under 5 min)
def test_why_a_run_stopped(env, tmp_path):
    """two toy runs (~20 s, mostly compiling): time budget, --stop-at-success (all epochs
    done: test_tensorboard_event_file_holds_every_column_and_the_config)."""
    b = train(TINY.replace(n_epochs=5), run_options(str(tmp_path / "b"), env, time_budget_s=0.0))
    assert (b.stopped, b.epochs) == ("time_budget", 1)
    assert "stopped: time budget of 0 s used" in b.summary()
    c = train(TINY.replace(n_epochs=5), run_options(str(tmp_path / "c"), env, stop_at_success=0.0))
    assert (c.stopped, c.epochs) == ("stop_at_success", 1)
    assert "test success reached 0 (--stop-at-success)" in c.summary()


def test_progress_without_a_terminal_prints_plain_lines(capsys):
    """in-process, no training: the calls the trainer makes, stderr not a TTY."""
    cfg = TINY.replace(n_epochs=4)
    p = Progress(cfg, T, tty=False)
    assert p.cycle is None                  # no per-cycle callback compiled without a terminal
    p.start(2)
    p.epoch(ROW)
    p.close()
    out, err = capsys.readouterr()
    assert out == epoch_line(ROW) + "\n"
    assert out.startswith("epoch    3  env_steps      1,200  test_success 0.500")
    assert err.splitlines() == ["resuming from epoch 2 of 4",
                                "compiling the training epoch (the first one takes longer)..."]
    assert "\r" not in err


def test_progress_bar_counts_whole_cycles_from_the_resumed_position(capsys):
    """in-process, no training: a bar on a (pretended) terminal."""
    cfg = TINY.replace(n_epochs=4, n_cycles=5, n_batches=400)
    p = Progress(cfg, T, tty=True)
    p.start(2)
    assert p.bar.n == 10 and "compiling" in str(p.bar.postfix)
    p.cycle({"success": 0.25})
    assert p.bar.n == 11 and "compiling" not in str(p.bar.postfix)
    p.epoch(ROW)
    assert p.bar.n == 15
    p.close()
    assert capsys.readouterr().out == epoch_line(ROW) + "\n"


def test_progress_with_no_progress_prints_epoch_lines_only(capsys):
    """in-process, no training: daddpg-train --no-progress (live=False), a resumed run."""
    p = Progress(TINY.replace(n_epochs=4), T, live=False, tty=True)
    assert p.cycle is None
    p.start(2)
    p.epoch(ROW)
    p.close()
    out, err = capsys.readouterr()
    assert out == epoch_line(ROW) + "\n" and err == "resuming from epoch 2 of 4\n"


def test_interrupt_says_why(tmp_path, monkeypatch, capsys):
    """in-process, < 1 s (training replaced by a KeyboardInterrupt)."""
    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "train", interrupted)
    assert train_cli.main(["--task", "reach", "--no-progress", "--no-tensorboard",
                           "--out", str(tmp_path / "r")]) == 130
    assert "stopped: interrupted; resume with: daddpg-train --resume" in capsys.readouterr().err


def _scripts() -> dict:
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        return tomllib.load(f)["project"]["scripts"]


@pytest.mark.parametrize("name", sorted(_scripts()))
def test_each_console_script_help_names_itself(name, capsys):
    """in-process, < 1 s each"""
    module, func = _scripts()[name].split(":")
    with pytest.raises(SystemExit) as e:
        getattr(importlib.import_module(module), func)(["--help"])
    out = capsys.readouterr().out
    assert e.value.code == 0 and out.startswith(f"usage: {name} "), out[:200]
    if name == "daddpg-scripted-demo":   # every flag has help text
        for flag in ("--task", "--episodes", "--seed", "--physics", "--width", "--height"):
            block = out.split(flag, 1)[1].split("\n  -", 1)[0]
            assert len(block.split()) > 3, (flag, block)


@pytest.mark.e2e
def test_train_help_and_argument_errors_do_not_import_jax():
    """~1 s: a fresh interpreter (jax not yet imported)."""
    code = ("import sys\nfrom daddpg_jax.cli.train import main\n"
            "for argv in (['--help'], ['--epochs', 'x'], ['--set', 'nope=1']):\n"
            "    try:\n        main(argv)\n    except SystemExit as e:\n"
            "        assert e.code in (0, 2), e.code\n"
            "assert 'jax' not in sys.modules, 'jax imported'\n")
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, timeout=60, env=dict(os.environ, PYTHONPATH=ROOT))
    assert out.returncode == 0, out.stderr[-2000:]
    assert "unknown" in out.stderr and time.perf_counter() - t0 < 30


def test_writing_a_video_gives_no_fork_warning(tmp_path):
    """~1 s: ffmpeg is started without running JAX's fork hook (no 'os.fork() was called')."""
    pytest.importorskip("imageio_ffmpeg")
    import warnings

    import jax
    import numpy as np

    from daddpg_jax.analysis.evaluation import write_frames

    jax.devices()   # JAX's backend (and its fork hook) is up, as in a training process
    frames = [np.full((64, 64, 3), 20 * i, np.uint8) for i in range(5)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = write_frames(str(tmp_path / "v.mp4"), frames, 25)
    assert out.endswith(".mp4") and os.path.getsize(out) > 0
    assert not [w for w in caught if "fork" in str(w.message)], [str(w.message) for w in caught]


@pytest.mark.e2e
def test_video_every_writes_videos_and_tensorboard_images(tmp_path):
    """~30-60 s: a tiny reach run with --video-every 1 in a fresh process (MUJOCO_GL=egl set
    before MuJoCo loads); skipped without EGL."""
    from tests.test_reliability import REACH_ARGS, RUN_PY

    run = str(tmp_path / "run")
    out = subprocess.run([sys.executable, RUN_PY, *REACH_ARGS, "--epochs", "2", "--video-every",
                          "1", "--out", run], capture_output=True, text=True, cwd=ROOT,
                         timeout=600, env=dict(os.environ, MUJOCO_GL="egl"))
    assert out.returncode == 0, out.stderr[-2000:]
    if "--video-every: no video" in out.stderr:
        pytest.skip(f"no OpenGL renderer (EGL) here: {out.stderr.strip()[-300:]}")
    assert "Traceback" not in out.stderr and "fork" not in out.stderr
    videos = sorted(os.listdir(os.path.join(run, "videos")))
    assert videos == ["epoch_0001.mp4", "epoch_0002.mp4"]
    events = read_events(os.path.join(run, tracking.TB_DIR))
    images = [(ev.step, v.image) for ev in events for v in ev.summary.value
              if v.tag == "eval/video"]
    assert len(images) == 2 and images[0][1].encoded_image_string[:6] == b"GIF89a"
    assert images[0][1].width == 320 and images[0][1].height == 240
