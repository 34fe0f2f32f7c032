"""Evaluation under perturbation: a trained run's test success over a grid of observation and
action perturbations (mjx_envs/perturb.py) and physics randomization fields
(mjx_envs/randomize.py) at exact values.

``daddpg-evaluate RUN --perturb obs_noise=0,0.005,0.01,0.02 --perturb latency=0,1,2 --out DIR``
plays the same fixed-seed test episodes at every grid point (the product of the values given)
and writes DIR/perturbation.csv and .json (one row per grid point) and DIR/perturbation.png
(success against each perturbation, the others at their first value).
"""

from __future__ import annotations

import csv
import dataclasses
import itertools
import json
import os

from daddpg_jax.analysis import evaluation
from mjx_envs import perturb, registry, schema, settings

COLUMNS = ("success_rate", "success_ci95_low", "success_ci95_high", "arm_contact_rate",
           "final_distance_left", "final_distance_right", "physics_fault_rate", "episodes",
           "seed", "eval_seconds")
"""result columns of perturbation.csv, after one column per perturbation of the grid"""


AXIS_LABELS = {
    "obs_noise": "observation noise std (m)",
    "obs_dropout": "observation dropout (probability per step)",
    "obs_bias": "observation bias (m, one offset per episode)",
    "obs_period": "observation period (control steps)",
    "latency": "action latency (control steps)",
    "object_mass": "object mass change (fraction, x (1 + v))",
    "object_size": "object half-size change (m)",
    "object_friction": "object friction change (fraction, x (1 + v))",
    "table_height": "table height change (m)",
    "grasp_timeconst": "grip contact time-constant change (fraction, x (1 + v))",
    "base_offset": "arm base offset (m)",
    "base_yaw": "arm base yaw (degrees)",
    "finger_force": "finger force change (fraction, x (1 + v))",
    "action_scale": "action scale change (fraction, x (1 + v))",
}
"""x-axis label (with its unit) of each perturbation in perturbation.png; the fields' meaning:
mjx_envs/perturb.py and mjx_envs/randomize.py"""

ERROR_BARS = "error bars: 95% Wilson interval of the success rate"


def parse_grid(task: str, items: list[str]) -> dict[str, list]:
    """``KEY=V1,V2,...`` items -> {field: [values]} (each value checked against the task's
    schema); raises schema.ConfigError."""
    cls = type(registry.default_config(task))
    grid = {}
    for item in items:
        key, sep, values = item.partition("=")
        key = key.strip().replace("-", "_")
        if not sep or not values.strip():
            raise schema.ConfigError(f"--perturb {item!r}: expected KEY=V1,V2,...")
        names = [k for k in (*perturb.FIELDS, *settings.RANDOMIZATION_FIELDS)
                 if hasattr(registry.default_config(task), k)]
        if key not in names:
            raise schema.ConfigError(f"--perturb: {key!r} is not a perturbation of {task}; "
                                     f"choose from {', '.join(names)}")
        if key in grid:
            raise schema.ConfigError(f"--perturb: {key} given twice")
        grid[key] = [schema.parse_overrides(cls, [f"{key}={v.strip()}"], "--perturb")[key]
                     for v in values.split(",")]
    if not grid:
        raise schema.ConfigError("--perturb: no perturbation given")
    return grid


def grid_points(grid: dict[str, list]) -> list[dict]:
    """Every combination of the grid's values, in order (the last key varies fastest)."""
    keys = list(grid)
    return [dict(zip(keys, vals, strict=True)) for vals in itertools.product(*grid.values())]


def evaluate_grid(policy, grid: dict[str, list], episodes: int = 100, seed: int | None = None,
                  report=None, **eval_opts) -> list[dict]:
    """One row per grid point: the perturbation's values and the evaluation's results
    (`daddpg_jax.analysis.evaluation.evaluate` on the standard task with the perturbation at
    exact values; ``eval_opts``: its ``chunk`` / ``watchdog``). report: optional callable(row)
    after each point (progress)."""
    from daddpg_jax.running.runner import make_env  # lazy: imports JAX and MuJoCo

    cfg, payload = policy.cfg, policy.payload
    base = evaluation.standard_env_overrides(cfg.task, payload.get("env_overrides"))
    rows = []
    for point in grid_points(grid):
        env = make_env(cfg, {**base, **point, "perturb_exact": True})
        summary, _ = evaluation.evaluate(dataclasses.replace(policy, env=env), episodes, seed,
                                         **eval_opts)
        lo, hi = summary["success_ci95"]
        row = dict(point, success_rate=summary["success_rate"], success_ci95_low=lo,
                   success_ci95_high=hi, arm_contact_rate=summary["arm_contact_rate"],
                   final_distance_left=summary["final_distance_mean"]["left"],
                   final_distance_right=summary["final_distance_mean"]["right"],
                   physics_fault_rate=summary["physics_fault_rate"],
                   episodes=summary["episodes"], seed=summary["seed"],
                   eval_seconds=summary["eval_seconds"])
        rows.append(row)
        if report is not None:
            report(row)
    return rows


def write_outputs(rows: list[dict], grid: dict[str, list], out_dir: str, meta: dict) -> dict:
    """perturbation.csv, perturbation.json (meta + rows) and perturbation.png in out_dir;
    returns their paths."""
    from daddpg_jax.running.checkpoint import write_atomic  # lazy: imports JAX

    os.makedirs(out_dir, exist_ok=True)
    paths = {ext: os.path.join(out_dir, f"perturbation.{ext}") for ext in ("csv", "json", "png")}
    with open(paths["csv"], "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=[*grid, *COLUMNS])
        w.writeheader()
        w.writerows(rows)
    write_atomic(paths["json"], json.dumps(dict(meta, grid=grid, rows=rows), indent=2))
    _plot(rows, grid, paths["png"], meta.get("title", ""))
    return paths


def run_grid(policy, grid: dict[str, list], episodes: int, seed: int | None, out_dir: str,
             log=None, **eval_opts) -> dict:
    """Evaluates `policy` at every point of `grid` (`evaluate_grid`) and writes the outputs
    (`write_outputs`) to out_dir; returns their paths. log: optional callable(line), one
    progress line per point."""
    n = len(grid_points(grid))
    done = []

    def report(row):
        done.append(row)
        if log is not None:
            point = ", ".join(f"{k}={row[k]}" for k in grid)
            log(f"[{len(done)}/{n}] {point}: success {row['success_rate']:.3f}")

    rows = evaluate_grid(policy, grid, episodes, seed, report=report, **eval_opts)
    run = os.path.basename(os.path.abspath(policy.run_dir))
    meta = dict(run_dir=os.path.abspath(policy.run_dir), checkpoint=policy.step,
                best=policy.best, task=policy.cfg.task, algo=policy.cfg.algo,
                title=f"{policy.cfg.task} / {run} / {'best ' if policy.best else ''}"
                      f"checkpoint {policy.step}")
    return write_outputs(rows, grid, out_dir, meta)


def run_items(policy, items: list[str], episodes: int, seed: int | None, out_dir: str,
              log=None, **eval_opts) -> dict:
    """`run_grid` over the grid of ``--perturb KEY=V1,V2,...`` items (`parse_grid`; raises
    ConfigError); returns the paths written."""
    grid = parse_grid(policy.cfg.task, items)
    return run_grid(policy, grid, episodes, seed, out_dir, log=log, **eval_opts)


def perturbation_figure(rows: list[dict], grid: dict[str, list], title: str = ""):
    """Success (with its 95 % Wilson interval) against each perturbation, the others at their
    first value; axes with units, integer ticks for integer fields."""
    # lazy: matplotlib loads only when a figure is drawn (daddpg-evaluate --help stays light)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after the backend is chosen
    from matplotlib.ticker import MaxNLocator

    keys = list(grid)
    fig, axes = plt.subplots(1, len(keys), figsize=(3.6 * len(keys), 3.2), squeeze=False)
    for ax, key in zip(axes[0], keys, strict=True):
        others = {k: grid[k][0] for k in keys if k != key}
        sel = [r for r in rows if all(r[k] == v for k, v in others.items())]
        x = [r[key] for r in sel]
        y = [r["success_rate"] for r in sel]
        err = [[r["success_rate"] - r["success_ci95_low"] for r in sel],
               [r["success_ci95_high"] - r["success_rate"] for r in sel]]
        ax.errorbar(x, y, yerr=err, marker="o", capsize=3)
        ax.set_xlabel(AXIS_LABELS.get(key, key), fontsize=8)
        if all(isinstance(v, int) and not isinstance(v, bool) for v in grid[key]):
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
        if others:
            ax.set_title(", ".join(f"{k}={v}" for k, v in others.items()), fontsize=8)
    axes[0][0].set_ylabel("test success rate")
    fig.suptitle(f"{title}\n{ERROR_BARS}" if title else ERROR_BARS, fontsize=9)
    fig.tight_layout()
    return fig


def _plot(rows: list[dict], grid: dict[str, list], path: str, title: str) -> None:
    import matplotlib.pyplot as plt  # lazy: as in perturbation_figure

    fig = perturbation_figure(rows, grid, title)
    fig.savefig(path, dpi=100)
    plt.close(fig)
