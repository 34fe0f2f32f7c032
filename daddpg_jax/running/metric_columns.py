"""The columns of metrics.csv, one row per epoch (standard library only: the JAX-free loggers of
`daddpg_jax.running.tracking` read them, and `daddpg_jax.running.run_record` writes the file)."""

METRIC_COLUMNS = (
    "epoch", "env_steps", "updates", "wall_time", "test_success_rate", "test_arm_contact_rate",
    "test_final_distance_left", "test_final_distance_right", "train_success_rate",
    "train_arm_contact_rate", "critic_loss", "actor_loss", "mean_q", "env_steps_per_s",
    "updates_per_s", "bc_loss", "q_filter_pass", "rollout_time", "update_time", "eval_time",
    "train_physics_fault_rate", "test_physics_fault_rate",
)
"""Columns of metrics.csv. bc_loss and q_filter_pass (behaviour-cloning term and Q-filter pass
rate, mean over the epoch's updates and the agents) are NaN without demonstrations.
rollout_time, update_time and eval_time split the epoch's wall seconds, measured on the host:
rollout_time sums, over the epoch's cycles, the time from the previous cycle's end to the
cycle's rollout done (envs and actors); update_time the time from there to its updates done
(buffer insert, normalizer update, gradient updates). Both come from host calls ordered inside
the compiled cycle (``algo.train.StageClock``; on several devices, device 0's); the first
epoch's rollout_time holds the compilation. eval_time: the evaluation after the epoch.
train_/test_physics_fault_rate: the fraction of the epoch's training / test episodes with a
step whose ``metrics["physics_ok"]`` is 0 (the engine froze or diverged; NaN for an env that
does not report it). CSVs written before a column existed lack it and are rewritten with it
(blank) on --resume."""

CROSS_COLUMNS = ("test_success_best", "cross_success_best", "cross_best_epoch",
                 "cross_eval_time")
"""The columns a run with ``cross_check`` (daddpg-train --cross-check ENGINE) adds after
METRIC_COLUMNS (`daddpg_jax.running.cross_check`): test_success_best = the best test success so
far (that of the checkpoint in checkpoints_best/, this epoch's included), cross_success_best =
that checkpoint's success on the other engine over the same test episodes (the same reset
keys), cross_best_epoch = its epoch, cross_eval_time = the seconds that evaluation took this
epoch (0 when the best did not change: the same parameters over the same episodes are not
played again). A run without cross_check writes none of them."""


def metric_columns(cross_check: str = "") -> tuple:
    """The columns of a run's metrics.csv: METRIC_COLUMNS, and CROSS_COLUMNS when the run has
    a cross-check engine."""
    return METRIC_COLUMNS + CROSS_COLUMNS if cross_check else METRIC_COLUMNS
