"""What a training run shows while it trains: `Progress`, the hooks object of `runner.train`
(``RunOptions.hooks``) that daddpg-train uses.

On a terminal (stderr a TTY): a bar of whole cycles (train success, env steps/s) that starts at
the resumed position and reads "compiling" until the first cycle ends, and one line per epoch
on stdout. Elsewhere (a log file, a pipe): no bar and no per-cycle callback; a "compiling"
line, then one line per epoch. With live=False (daddpg-train --no-progress): the epoch lines
only.
"""

from __future__ import annotations

import os
import sys
import time

from tqdm import tqdm

from daddpg_jax.algo.config import TrainConfig


def header(cfg: TrainConfig, run_dir: str) -> str:
    """The lines printed before training: the run directory and the run's size."""
    lines = [f"run dir: {os.path.abspath(run_dir)}",
             f"task {cfg.task}, algo {cfg.algo}, her {cfg.her}, num_envs {cfg.num_envs}, batch "
             f"{cfg.batch_size} x {cfg.n_batches} updates/cycle, {cfg.n_cycles} cycles/epoch, "
             f"{cfg.n_epochs} epochs"]
    if cfg.n_demos > 0:
        lines.append(f"demonstrations: {cfg.n_demos} scripted episodes (not counted in env "
                     f"steps), {cfg.demo_batch} demo transitions per update, bc_weight "
                     f"{cfg.bc_weight}, q_filter {cfg.q_filter}")
    return "\n".join(lines)


def epoch_line(row: dict) -> str:
    """The line printed after each epoch (with --cross-check: and the best checkpoint's test
    success on both engines, ``best a/b``)."""
    cross = ""
    if "cross_success_best" in row:
        cross = f"  best {row['test_success_best']:.3f}/{row['cross_success_best']:.3f}"
    return (f"epoch {row['epoch']:4d}  env_steps {row['env_steps']:>10,}  "
            f"test_success {row['test_success_rate']:.3f}  "
            f"arm_contact {row['test_arm_contact_rate']:.3f}  "
            f"critic_loss {row['critic_loss']:.4f}  {row['env_steps_per_s']:,.0f} steps/s{cross}")


class Progress:
    """Hooks of `runner.train` (``RunOptions.hooks``): `start(epoch)`, `cycle(metrics)` (from
    inside the compiled epoch, `algo.train.EpochHooks`), `epoch(row)`, and `close()` for the
    caller.

    show: draw the bar (False on the processes other than 0 of a multi-process job, where the
    runner makes no `start`/`epoch` call).
    live: the bar and the "compiling" line; False: epoch lines only, no per-cycle callback.
    tty: stderr is a terminal (default: asked).
    same_program: compile the per-cycle callback even without a terminal (a multi-process job:
    every process's compiled program must be the same).
    """

    def __init__(self, cfg: TrainConfig, episode_length: int, show: bool = True,
                 live: bool = True, tty: bool | None = None, same_program: bool = False):
        self.cfg = cfg
        self.live = live
        self.tty = sys.stderr.isatty() if tty is None else tty
        self.bar = tqdm(total=cfg.n_epochs * cfg.n_cycles, unit="cycle", dynamic_ncols=True,
                        desc=f"{cfg.task}/{cfg.algo}", disable=not (show and live and self.tty),
                        file=sys.stderr)
        if not (live and (self.tty or same_program)):
            self.cycle = None   # no per-cycle callback compiled into the epoch
        self.steps_per_cycle = cfg.num_envs * episode_length
        self.t_last = time.perf_counter()
        self.compiling = False
        if live and self.tty:
            self.bar.set_postfix_str("starting (env, networks)...", refresh=True)

    def start(self, epoch: int) -> None:
        """Before the first cycle: the resumed position, and the compiling phase."""
        if epoch > 0:
            print(f"resuming from epoch {epoch} of {self.cfg.n_epochs}", file=sys.stderr,
                  flush=True)
        if not self.live:
            return
        self.bar.n = epoch * self.cfg.n_cycles
        self.bar.initial = self.bar.n   # rates count this process's cycles only
        self.compiling = True
        if self.tty:
            self.bar.set_postfix_str("compiling...", refresh=True)
        else:
            print("compiling the training epoch (the first one takes longer)...",
                  file=sys.stderr, flush=True)

    def cycle(self, metrics) -> None:
        """Once per cycle, with that cycle's metrics: the bar moves by one cycle."""
        now = time.perf_counter()
        sps = self.steps_per_cycle / max(now - self.t_last, 1e-9)
        self.t_last = now
        if self.compiling:
            self.compiling = False
            sps_text = "-"   # the first cycle's time is mostly compilation
        else:
            sps_text = f"{sps:,.0f}"
        self.bar.set_postfix(train_success=f"{float(metrics['success']):.2f}",
                             steps_s=sps_text, refresh=False)
        self.bar.update(1)

    def epoch(self, row: dict) -> None:
        """After each epoch, with its metrics.csv row: the epoch line on stdout."""
        msg = epoch_line(row)
        if self.live and self.tty:
            self.bar.n = row["epoch"] * self.cfg.n_cycles
            self.bar.refresh()
            self.bar.write(msg, file=sys.stdout)
        else:
            print(msg, flush=True)

    def close(self) -> None:
        self.bar.close()
