"""Live experiment tracking: TensorBoard event files (every run) and Weights & Biases (--wandb).

The runner (``daddpg_jax.running.runner.train``) gives each logger the run's config once
(``start``), then every metrics.csv row as it is written (``log_row``) and, with
``--video-every``, the evaluation videos (``log_video``). Every column of ``METRIC_COLUMNS``
(`daddpg_jax.running.metric_columns`), and with ``--cross-check`` of ``CROSS_COLUMNS``, is
logged against ``env_steps`` under the tag ``tag(column)`` (``test/success_rate``,
``losses/critic_loss``, ``time/rollout_time``, ``cross/success_best``, ...); a value that is
NaN (``bc_loss`` and ``q_filter_pass`` without demonstrations, the stage times on several
devices, a fault rate an env does not report) is left out.

    tensorboard --logdir runs/            # RUN_DIR/tensorboard/ of every run

On ``--resume`` the TensorBoard writer purges the events of epochs after the restored
checkpoint (``purge_step``), so the curves never hold a dropped epoch twice.

tensorboardX is a dependency; wandb is the optional extra ``[wandb]`` (imported only when
asked for).
"""

from __future__ import annotations

import hashlib
import importlib.util
import io
import json
import math
import os

from daddpg_jax.running.metric_columns import CROSS_COLUMNS, METRIC_COLUMNS
from mjx_envs.schema import ConfigError

TB_DIR = "tensorboard"
"""RUN_DIR/tensorboard: the run's TensorBoard event files"""

_GROUPS = {
    "losses": ("critic_loss", "actor_loss", "mean_q", "bc_loss", "q_filter_pass"),
    "time": ("wall_time", "env_steps_per_s", "updates_per_s", "rollout_time", "update_time",
             "eval_time"),
    "progress": ("epoch", "env_steps", "updates"),
}


def tag(column: str) -> str:
    """The TensorBoard / W&B tag of a metrics.csv column: test_* -> test/*, train_* ->
    train/*, cross_* -> cross/* (--cross-check), losses and Q -> losses/*, timings and rates
    -> time/*, counters -> progress/*."""
    for prefix in ("test", "train", "cross"):
        if column.startswith(prefix + "_"):
            return f"{prefix}/{column[len(prefix) + 1:]}"
    for group, cols in _GROUPS.items():
        if column in cols:
            return f"{group}/{column}"
    return f"metrics/{column}"


def _value(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def row_scalars(row: dict) -> dict[str, float]:
    """{tag: value} of a metrics.csv row: every column of METRIC_COLUMNS (and of CROSS_COLUMNS
    that the row has) but env_steps (the x axis), except those that are NaN in this row (e.g.
    bc_loss without demonstrations)."""
    values = {tag(c): _value(row.get(c)) for c in METRIC_COLUMNS + CROSS_COLUMNS
              if c != "env_steps"}
    return {k: v for k, v in values.items() if not math.isnan(v)}


def config_text(cfg, env_overrides: dict | None) -> str:
    """The run's config as Markdown (a JSON code block): training fields and env overrides."""
    body = json.dumps(dict(config=cfg.to_dict(), env_overrides=env_overrides or {}), indent=2,
                      sort_keys=True)
    return "\n".join("    " + line for line in body.splitlines())


def gif_bytes(frames, fps: int) -> bytes:
    """Frames (H x W x 3 uint8) as an animated GIF, the format of TensorBoard's image plugin."""
    import imageio.v2 as imageio  # optional extra [video]

    buf = io.BytesIO()
    imageio.mimsave(buf, frames, format="GIF", duration=1000.0 / fps, loop=0)
    return buf.getvalue()


class TensorBoardLogger:
    """Event files in RUN_DIR/tensorboard (tensorboardX), flushed after every epoch."""

    def __init__(self, run_dir: str):
        self.dir = os.path.join(os.fspath(run_dir), TB_DIR)
        self.writer = None

    def start(self, cfg, env_overrides: dict | None, resumed_rows: list | None = None):
        from tensorboardX import SummaryWriter  # imported with the first run that logs

        purge = None
        if resumed_rows is not None and os.path.isdir(self.dir):
            purge = int(resumed_rows[-1]["env_steps"]) + 1 if resumed_rows else 0
        self.writer = SummaryWriter(self.dir, purge_step=purge, flush_secs=30)
        self.writer.add_text("config", config_text(cfg, env_overrides), 0)
        self.writer.flush()

    def log_row(self, row: dict):
        step = int(row["env_steps"])
        for name, value in row_scalars(row).items():
            self.writer.add_scalar(name, value, step)
        self.writer.flush()

    def log_video(self, frames, fps: int, step: int, path: str | None = None):
        """The video as an animated GIF in the image plugin (tag ``eval/video``), encoded with
        imageio (tensorboardX's own add_video needs moviepy)."""
        from tensorboardX.proto.summary_pb2 import Summary  # lazy: as SummaryWriter above

        h, w = frames[0].shape[:2]
        image = Summary.Image(height=h, width=w, colorspace=3,
                              encoded_image_string=gif_bytes(frames, fps))
        summary = Summary(value=[Summary.Value(tag="eval/video", image=image)])
        self.writer._get_file_writer().add_summary(summary, step)
        self.writer.flush()

    def close(self):
        if self.writer is not None:
            self.writer.close()
            self.writer = None


class WandbLogger:
    """Weights & Biases: the config, every metrics.csv column against env steps, and the
    videos. Files go to RUN_DIR/wandb; ``WANDB_MODE=offline`` needs no account (``wandb sync``
    uploads them later). The W&B run id is derived from the run directory, so a --resume
    continues the same W&B run."""

    def __init__(self, run_dir: str, project: str = "daddpg-jax"):
        if importlib.util.find_spec("wandb") is None:
            raise ConfigError("--wandb needs the wandb package: pip install 'daddpg-jax[wandb]'")
        self.run_dir = os.path.abspath(os.fspath(run_dir))
        self.project = project
        self.run = None

    def start(self, cfg, env_overrides: dict | None, resumed_rows: list | None = None):
        import wandb  # optional extra

        run_id = hashlib.sha1(self.run_dir.encode()).hexdigest()[:16]
        os.makedirs(os.path.join(self.run_dir, "wandb"), exist_ok=True)
        self.run = wandb.init(project=self.project, dir=self.run_dir, id=run_id,
                              name=os.path.basename(self.run_dir), resume="allow",
                              config=dict(cfg.to_dict(), env_overrides=env_overrides or {}))
        self.run.define_metric("env_steps")
        self.run.define_metric("*", step_metric="env_steps")

    def log_row(self, row: dict):
        self.run.log({"env_steps": int(row["env_steps"]), **row_scalars(row)})

    def log_video(self, frames, fps: int, step: int, path: str | None = None):
        import wandb  # optional extra [wandb]

        if path and os.path.exists(path):
            self.run.log({"env_steps": int(step), "eval/video": wandb.Video(path)})

    def close(self):
        if self.run is not None:
            self.run.finish()
            self.run = None


def loggers(run_dir: str, tensorboard: bool = True, wandb_project: str | None = None) -> list:
    """The experiment trackers of a run: TensorBoard unless `tensorboard` is False, W&B when a
    project is named (ConfigError when wandb is not installed)."""
    out = [TensorBoardLogger(run_dir)] if tensorboard else []
    if wandb_project:
        out.append(WandbLogger(run_dir, project=wandb_project))
    return out
