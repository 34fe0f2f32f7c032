"""Experiment sets of the paper's section 4.1: curves per task over seeds and the cooperation
ablations, each run capped by an env-step and a wall-clock budget and resumable.

``experiments/reproduce.py`` parses flags and calls :func:`run_set`. Layout of ``OUT/<task>/``::

    runs/<label>_s<seed>/   one run directory per experiment (see daddpg_jax.running.runner)
    final.csv               one row per run (FINAL_COLUMNS)
    curves.png              the main variant over seeds: success vs env steps and wall clock,
                            arm-contact rate (mean and min-max band)
    ablations.png           every variant (when ablations ran)
    summary.json            the set's settings and the final rows
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from daddpg_jax.algo.config import TrainConfig, preset, preset_env
from daddpg_jax.analysis.plotting import plot_learning_curve, plot_runs, read_metrics, run_figures
from daddpg_jax.running import checkpoint as ckpt
from daddpg_jax.running.levels import first_reaching
from daddpg_jax.running.runner import RunOptions, train

FINAL_COLUMNS = (
    "task", "label", "algo", "her", "seed", "epochs", "env_steps", "wall_time",
    "final_test_success", "best_test_success", "env_steps_to_0.5", "wall_time_to_0.5",
    "env_steps_to_0.9", "wall_time_to_0.9", "final_arm_contact_rate", "mean_arm_contact_rate",
)


@dataclass(frozen=True)
class Experiment:
    label: str
    algo: str
    her: str


MAIN = Experiment("daddpg", "daddpg", "future")
ABLATIONS = (
    Experiment("maddpg", "maddpg", "future"),
    Experiment("ddpg", "ddpg", "future"),
    Experiment("single", "single", "future"),
    Experiment("daddpg_noher", "daddpg", "none"),
)


def experiments(seeds: int, algos: Sequence[str] | None = None, ablations: bool = False,
                ablation_seeds: int = 1, first_seed: int = 0) -> list[tuple[Experiment, int]]:
    """(experiment, seed) pairs: the main variant (or ``algos``) over ``seeds`` seeds starting at
    ``first_seed``, plus the ablations over ``ablation_seeds`` seeds from the same start."""
    out = []
    mains = [MAIN] if not algos else [Experiment(a, a, "future") for a in algos]
    for e in mains:
        out += [(e, s) for s in range(first_seed, first_seed + seeds)]
    if ablations:
        for e in ABLATIONS:
            if all(e.label != m.label for m in mains):
                out += [(e, s) for s in range(first_seed, first_seed + ablation_seeds)]
    return out


def final_row(task: str, exp: Experiment, seed: int, rows: Sequence[dict]) -> dict:
    figs = run_figures(rows) if rows else {}
    last = rows[-1] if rows else {}
    return {
        "task": task, "label": exp.label, "algo": exp.algo, "her": exp.her, "seed": seed,
        "epochs": int(last.get("epoch", 0)), "env_steps": int(last.get("env_steps", 0)),
        "wall_time": float(last.get("wall_time", 0.0)),
        "final_test_success": figs.get("final_test_success", math.nan),
        "best_test_success": figs.get("best_test_success", math.nan),
        "env_steps_to_0.5": figs.get("env_steps_to_0.5", math.nan),
        "wall_time_to_0.5": first_reaching(rows, 0.5, "wall_time"),
        "env_steps_to_0.9": figs.get("env_steps_to_0.9", math.nan),
        "wall_time_to_0.9": first_reaching(rows, 0.9, "wall_time"),
        "final_arm_contact_rate": float(last.get("test_arm_contact_rate", math.nan)),
        "mean_arm_contact_rate": figs.get("mean_arm_contact_rate", math.nan),
    }


def run_one(task: str, exp: Experiment, seed: int, run_dir: str, env_steps: int,
            budget_s: float, num_envs: int | None = None, overrides: dict | None = None,
            env_overrides: dict | None = None, log: Callable[[str], None] = print) -> list:
    """Trains (or resumes) one run until ``env_steps`` or ``budget_s`` of its wall clock."""
    base = preset(task, num_envs)
    per_epoch = base["n_cycles"] * base["num_envs"] * 50
    cfg = TrainConfig(**{**base, "n_epochs": max(1, math.ceil(env_steps / per_epoch)),
                         "algo": exp.algo, "her": exp.her, "seed": seed, **(overrides or {})})
    if overrides and ("n_cycles" in overrides or "num_envs" in overrides):
        per_epoch = cfg.n_cycles * cfg.num_envs * 50
        cfg = cfg.replace(n_epochs=max(1, math.ceil(env_steps / per_epoch)))
    resume = ckpt.latest_step(run_dir) is not None
    used = 0.0
    if resume:
        path = os.path.join(run_dir, "metrics.csv")
        rows = read_metrics(path) if os.path.exists(path) else []
        used = float(rows[-1]["wall_time"]) if rows else 0.0
        done_epochs = int(rows[-1]["epoch"]) if rows else 0
        if done_epochs >= cfg.n_epochs or used >= budget_s:
            log(f"  {exp.label} seed {seed}: done ({done_epochs} epochs, {used:.0f} s)")
            return rows
    log(f"  {exp.label} seed {seed}: {'resuming' if resume else 'starting'} "
        f"({cfg.n_epochs} epochs max, {budget_s - used:.0f} s left)")
    env_overrides = {**preset_env(task), **(env_overrides or {})}
    res = train(cfg, RunOptions(run_dir, env_overrides=env_overrides, resume=resume,
                                plot=plot_learning_curve,
                                time_budget_s=max(budget_s - used, 1.0),
                                command="reproduce.py"))
    log(f"  {res.summary()}")
    return res.rows


def run_set(task: str, out_dir: str, seeds: int = 3, algos: Sequence[str] | None = None,
            ablations: bool = False, env_steps: int = 200_000, budget_minutes: float = 30.0,
            num_envs: int | None = None, overrides: dict | None = None,
            env_overrides: dict | None = None, log: Callable[[str], None] = print,
            first_seed: int = 0) -> dict:
    """Runs the set and writes final.csv, curves.png, ablations.png and summary.json."""
    task_dir = os.path.join(out_dir, task)
    os.makedirs(os.path.join(task_dir, "runs"), exist_ok=True)
    finals, groups = [], {}
    t0 = time.time()
    for exp, seed in experiments(seeds, algos, ablations, first_seed=first_seed):
        run_dir = os.path.join(task_dir, "runs", f"{exp.label}_s{seed}")
        rows = run_one(task, exp, seed, run_dir, env_steps, budget_minutes * 60.0, num_envs,
                       overrides, env_overrides, log)
        finals.append(final_row(task, exp, seed, rows))
        groups.setdefault(exp.label, []).append(rows)
    with open(os.path.join(task_dir, "final.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=FINAL_COLUMNS)
        w.writeheader()
        w.writerows(finals)
    main_label = (algos[0] if algos else MAIN.label)
    demos = int((overrides or {}).get("n_demos", 0))
    plot_runs({main_label: groups[main_label]}, os.path.join(task_dir, "curves.png"),
              title=f"{task}: {main_label}{f' + {demos} demos' if demos else ''} "
                    f"over {seeds} seed(s)")
    if len(groups) > 1:
        plot_runs(groups, os.path.join(task_dir, "ablations.png"), title=f"{task}: variants")
    summary = {"task": task, "seeds": seeds, "first_seed": first_seed, "ablations": ablations,
               "env_steps": env_steps,
               "budget_minutes": budget_minutes, "num_envs": num_envs,
               "overrides": overrides or {}, "env_overrides": env_overrides or {},
               "elapsed_s": round(time.time() - t0, 1), "final": finals}
    with open(os.path.join(task_dir, "summary.json"), "w") as f:
        json.dump(summary, f, indent=2, default=float)
    return summary
