"""Learning-curve plots (PNG) from metrics rows (dicts as read from metrics.csv).

``plot_learning_curve``: one run (written by the runner after every epoch).
``plot_runs``: several runs grouped by label (e.g. seeds of one configuration), mean line and a
min-max (or +-std) band per group, in three panels: test success vs env steps, test success vs
wall clock, arm-contact rate vs env steps (``experiments/plot.py``).
``group_summary``: per group, the mean and standard deviation over its runs of the end-of-run
figures (the error bars of a comparison between variants).
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Sequence

import numpy as np

from daddpg_jax.running.levels import first_reaching

#: per-run figures that ``group_summary`` averages over a group's runs
SUMMARY_METRICS = ("final_test_success", "last_test_success", "best_test_success",
                   "env_steps_to_0.5", "env_steps_to_0.9", "last_arm_contact_rate",
                   "mean_arm_contact_rate")


def _mpl():
    import matplotlib  # lazy: loads only when a figure is drawn (CLI --help stays light)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # after the backend is chosen

    return plt


def _col(rows: Sequence[dict], key: str) -> np.ndarray:
    def num(v):
        try:
            return float(v)
        except (TypeError, ValueError):
            return math.nan

    return np.array([num(r.get(key)) for r in rows])


def learning_curve_figure(rows: Sequence[dict], title: str = ""):
    """The figure of ``plot_learning_curve``: a success panel (test and train success, test
    arm-contact rate) over a losses panel (critic and actor loss, mean Q on its own axis), both
    against env steps, with a second x axis (top) in wall-clock seconds."""
    plt = _mpl()
    x, wall = _col(rows, "env_steps"), _col(rows, "wall_time")
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6.4), dpi=110, sharex=True)
    top.plot(x, _col(rows, "test_success_rate"), "o-", label="test success rate",
             color="tab:blue", ms=3)
    top.plot(x, _col(rows, "train_success_rate"), "-", label="train success rate (exploring)",
             color="tab:blue", alpha=0.4)
    top.plot(x, _col(rows, "test_arm_contact_rate"), "s--", label="arm-contact rate (test)",
             color="tab:red", alpha=0.7, ms=3)
    top.set_ylabel("rate (fraction of episodes)")
    top.set_ylim(-0.02, 1.02)
    top.legend(loc="best", fontsize=8)
    bottom.plot(x, _col(rows, "critic_loss"), "-", label="critic loss", color="tab:purple")
    bottom.plot(x, _col(rows, "actor_loss"), "-", label="actor loss (= -Q of its actions)",
                color="tab:green")
    bottom.set_ylabel("loss (mean over the epoch's updates)")
    bottom.set_xlabel("env steps")
    q_ax = bottom.twinx()
    q_ax.plot(x, _col(rows, "mean_q"), ":", label="mean Q", color="tab:gray")
    q_ax.set_ylabel("mean Q")
    lines = bottom.get_legend_handles_labels()
    q_lines = q_ax.get_legend_handles_labels()
    bottom.legend(lines[0] + q_lines[0], lines[1] + q_lines[1], loc="best", fontsize=8)
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
    if len(x) >= 2 and np.all(np.diff(x) > 0) and np.all(np.isfinite(wall)):
        # wall clock as a second x axis: the epochs' (env steps, wall time) pairs, interpolated
        sec = top.secondary_xaxis("top", functions=(lambda v: np.interp(v, x, wall),
                                                    lambda v: np.interp(v, wall, x)))
        sec.set_xlabel("wall clock (s)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def plot_learning_curve(rows: Sequence[dict], out: str, title: str = "") -> str:
    """One run's learning curve (``learning_curve_figure``) as a PNG."""
    plt = _mpl()
    fig = learning_curve_figure(rows, title)
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out


# -- several runs: mean and band per group (seeds), three panels ------------------------------

def read_metrics(path: str) -> list[dict]:
    """Rows of ``metrics.csv`` from a run directory (or the CSV path itself)."""
    csv_path = os.path.join(path, "metrics.csv") if os.path.isdir(path) else path
    if not os.path.exists(csv_path):
        raise FileNotFoundError(f"{path}: no metrics.csv")
    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{csv_path} has no rows yet")
    return rows


def truncate(rows: Sequence[dict], max_wall: float | None = None,
             max_env_steps: float | None = None) -> list[dict]:
    """The epochs of a run that ended within ``max_wall`` seconds of its wall clock and
    ``max_env_steps`` env steps (None: no limit): a longer run cut to a shorter budget."""
    return [r for r in rows
            if (max_wall is None or float(r["wall_time"]) <= max_wall)
            and (max_env_steps is None or float(r["env_steps"]) <= max_env_steps)]


def repeated_seeds(runs: dict[str, Sequence[str]]) -> list[str]:
    """One message per group (label -> run paths) in which two runs have the same seed (from
    their config.json): such a group's band and mean are not over independent seeds."""
    out = []
    for label, paths in runs.items():
        by_seed: dict = {}
        for p in paths:
            seed = run_config(p).get("seed")
            if seed is not None:
                by_seed.setdefault(seed, []).append(p)
        for seed, ps in by_seed.items():
            if len(ps) > 1:
                out.append(f"group {label!r} has {len(ps)} runs with seed {seed} "
                           f"({', '.join(ps)}): its mean and band are not over independent "
                           "seeds")
    return out


def run_config(path: str) -> dict:
    """The ``config`` section of a run's config.json ({} when it has none)."""
    run_dir = path if os.path.isdir(path) else os.path.dirname(os.path.abspath(path))
    try:
        with open(os.path.join(run_dir, "config.json")) as f:
            return dict(json.load(f)["config"])
    except (OSError, ValueError, KeyError, TypeError):
        return {}


def run_label(path: str) -> str:
    """Default label of a run: ``task/algo`` (+ ``/N envs`` when not 2, + ``+N demos`` with
    demonstrations) from its config.json, else the directory name. Runs that differ only in
    seed get the same label."""
    run_dir = path if os.path.isdir(path) else os.path.dirname(os.path.abspath(path))
    cfg_path = os.path.join(run_dir, "config.json")
    try:
        with open(cfg_path) as f:
            c = json.load(f)["config"]
    except (OSError, ValueError, KeyError):
        return os.path.basename(os.path.normpath(run_dir))
    label = f"{c.get('task', '?')}/{c.get('algo', '?')}"
    if int(c.get("num_envs", 2)) != 2:
        label += f"/{c['num_envs']} envs"
    if int(c.get("n_demos", 0)) > 0:
        label += f"+{c['n_demos']} demos"
    return label


def aggregate(runs: Sequence[Sequence[dict]], band: str = "minmax") -> dict:
    """Aligns runs of one group by epoch (row index) and returns per-epoch arrays: x values
    ``env_steps`` and ``wall_time`` (mean over the runs that reached that epoch), and for
    ``test_success_rate`` / ``test_arm_contact_rate`` the mean with a band (``minmax``: min and
    max over runs; ``std``: mean ± one standard deviation), plus ``n`` runs per epoch."""
    if band not in ("minmax", "std"):
        raise ValueError("band must be 'minmax' or 'std'")
    n_max = max(len(r) for r in runs)
    out = {k: [] for k in ("env_steps", "wall_time", "n")}
    for key in ("test_success_rate", "test_arm_contact_rate"):
        out[key] = {"mean": [], "lo": [], "hi": []}
    for i in range(n_max):
        present = [r[i] for r in runs if len(r) > i]
        out["n"].append(len(present))
        out["env_steps"].append(np.mean([float(r["env_steps"]) for r in present]))
        out["wall_time"].append(np.mean([float(r["wall_time"]) for r in present]))
        for key in ("test_success_rate", "test_arm_contact_rate"):
            v = np.array([float(r[key]) for r in present])
            m = float(np.mean(v))
            if band == "minmax":
                lo, hi = float(v.min()), float(v.max())
            else:
                sd = float(np.std(v))
                lo, hi = m - sd, m + sd
            out[key]["mean"].append(m)
            out[key]["lo"].append(lo)
            out[key]["hi"].append(hi)
    for k in ("env_steps", "wall_time", "n"):
        out[k] = np.asarray(out[k])
    for key in ("test_success_rate", "test_arm_contact_rate"):
        out[key] = {k: np.asarray(v) for k, v in out[key].items()}
    return out


def plot_runs(groups: dict[str, Sequence[Sequence[dict]]], out: str, title: str = "",
              band: str = "minmax") -> str:
    """Three panels: test success vs env steps, test success vs wall clock, arm-contact rate vs
    env steps; one line (mean over the group's runs) and a shaded band per group."""
    plt = _mpl()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2), dpi=110)
    panels = (("env_steps", "test_success_rate", "env steps", "test success rate"),
              ("wall_time", "test_success_rate", "wall clock (s)", "test success rate"),
              ("env_steps", "test_arm_contact_rate", "env steps", "arm-contact rate (test)"))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    band_name = "min–max" if band == "minmax" else "±1 std"
    for gi, (label, runs) in enumerate(groups.items()):
        agg = aggregate(runs, band)
        color = colors[gi % len(colors)]
        n = len(runs)
        name = f"{label} (n={n})" if n > 1 else label
        fewer = agg["n"] < n     # epochs that not every run of the group reached
        for ax, (xk, yk, _, _) in zip(axes, panels):
            x, y = agg[xk], agg[yk]
            ax.plot(x, y["mean"], "-", color=color, lw=1.8, label=name,
                    marker="o" if len(x) <= 30 else None, ms=3)
            if fewer.any():
                ax.plot(x[fewer], y["mean"][fewer], linestyle="none", marker="o", ms=6,
                        mfc="white", mec=color, mew=1.5)
            if n > 1:
                ax.fill_between(x, np.clip(y["lo"], 0, 1), np.clip(y["hi"], 0, 1), color=color,
                                alpha=0.2, lw=0)
    for ax, (_, _, xl, yl) in zip(axes, panels):
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    several = any(len(r) > 1 for r in groups.values())
    partial = any((aggregate(r, band)["n"] < len(r)).any() for r in groups.values())
    note = "; open circles: mean of fewer runs" if partial else ""
    axes[0].legend(loc="lower right", fontsize=8,
                   title=f"mean, band {band_name}{note}" if several else None, title_fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out


def run_figures(rows: Sequence[dict], last: int = 5) -> dict:
    """One run's end-of-run figures: final, mean of the last ``last`` and best test success; env
    steps to 0.5 and 0.9 (NaN if not reached); arm-contact rate over the last ``last`` tests
    and over the whole run."""
    if not rows:
        raise ValueError("run_figures needs at least one epoch")
    if last < 1:
        raise ValueError(f"last must be >= 1, got {last}")
    succ = np.array([float(r["test_success_rate"]) for r in rows])
    contact = np.array([float(r["test_arm_contact_rate"]) for r in rows])
    return {"final_test_success": float(succ[-1]), "last_test_success": float(succ[-last:].mean()),
            "best_test_success": float(succ.max()),
            "env_steps_to_0.5": first_reaching(rows, 0.5, "env_steps"),
            "env_steps_to_0.9": first_reaching(rows, 0.9, "env_steps"),
            "last_arm_contact_rate": float(contact[-last:].mean()),
            "mean_arm_contact_rate": float(contact.mean())}


def group_summary(groups: dict[str, Sequence[Sequence[dict]]], last: int = 5) -> list[dict]:
    """One row per group: ``runs``, and for each of ``SUMMARY_METRICS`` its mean and sample
    standard deviation (ddof 1; NaN for a single run) over the group's runs. Env steps to a
    level average over the runs that reached it; ``reached_0.5`` / ``reached_0.9`` count them."""
    out = []
    for label, runs in groups.items():
        figs = [run_figures(r, last) for r in runs]
        row: dict = {"label": label, "runs": len(figs)}
        for m in SUMMARY_METRICS:
            v = np.array([f[m] for f in figs], dtype=np.float64)
            v = v[~np.isnan(v)]
            row[f"{m}_mean"] = float(v.mean()) if len(v) else math.nan
            row[f"{m}_std"] = float(v.std(ddof=1)) if len(v) > 1 else math.nan
        for level in ("0.5", "0.9"):
            row[f"reached_{level}"] = int(sum(not math.isnan(f[f"env_steps_to_{level}"])
                                              for f in figs))
        out.append(row)
    return out


def summary_columns() -> tuple[str, ...]:
    """Column order of ``group_summary`` rows (the CSV that ``plot.py --summary`` writes)."""
    stats = tuple(f"{m}_{s}" for m in SUMMARY_METRICS for s in ("mean", "std"))
    return ("label", "runs", *stats, "reached_0.5", "reached_0.9")
