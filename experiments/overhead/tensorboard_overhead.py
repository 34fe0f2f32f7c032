"""TensorBoard's cost on a reach run (CPU preset, C engine): runs with and without the
TensorBoard logger in one process, in the order none, TB, TB, none; prints env steps per
wall-clock second over epochs 2..N of each (epoch 1 holds the compile) and the time spent in the
logger itself per epoch, and the ratio of env steps/s with / without it within the same runs.

    python experiments/overhead/tensorboard_overhead.py [EPOCHS] # default 5 epochs per run

Measured figures: docs/TOOLS.md (TensorBoard's cost).
"""

import os
import statistics as st
import sys
import tempfile
import time

from daddpg_jax.algo.config import build_config
from daddpg_jax.analysis import plotting
from daddpg_jax.running import runner, tracking
from mjx_envs.settings import DEFAULT_TASK


def steps_per_s(rows) -> float:
    """Env steps per wall-clock second from the first to the last metrics row."""
    a, b = rows[0], rows[-1]
    return ((int(b["env_steps"]) - int(a["env_steps"]))
            / (float(b["wall_time"]) - float(a["wall_time"])))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    epochs = int(argv[0]) if argv else 5
    cfg = build_config(DEFAULT_TASK, device="cpu").replace(n_epochs=epochs, physics="c")
    spent = []

    class Timed(tracking.TensorBoardLogger):
        def log_row(self, row):
            t = time.perf_counter()
            super().log_row(row)
            spent.append(time.perf_counter() - t)

    base = tempfile.mkdtemp(prefix="tb-overhead-")
    walls = []
    for i, mode in enumerate(["none", "tb", "tb", "none"]):
        d = os.path.join(base, f"{mode}{i}")
        r = runner.train(cfg, runner.RunOptions(
            d, loggers=[Timed(d)] if mode == "tb" else [],
            plot=plotting.plot_learning_curve))
        walls.append(float(r.rows[-1]["wall_time"]) / epochs)
        print(f"{mode}: {steps_per_s(r.rows):.1f} env steps/s (epochs 2..{epochs}, wall clock)",
              flush=True)
    per_epoch, epoch_s = st.mean(spent), st.mean(walls)
    print(f"TensorBoard logging per epoch: mean {1e3 * per_epoch:.2f} ms, max "
          f"{1e3 * max(spent):.2f} ms over {len(spent)} epochs; epoch ~{epoch_s:.2f} s")
    print(f"env steps/s with / without TensorBoard in the same runs: "
          f"{(epoch_s - per_epoch) / epoch_s:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
