"""One checkpoint on two physics engines: the cross-engine check of ``daddpg-evaluate RUN
--physics c,mjx``.

    from daddpg_jax.analysis import engines, evaluation
    pols = {e: evaluation.load_policy("runs/pickup_s0", best=True, physics=e) for e in ("c", "mjx")}
    summary, trajs = engines.compare(pols, episodes=64, seed=2024)
    engines.write_divergence(engines.divergence_profile(trajs["c"], trajs["mjx"]), "out", ...)

Both engines play the same fixed episodes (the same reset keys, so the same starts and goals)
with the same deterministic actors, closed loop. The success difference between engine A and
engine B (A first) is the difference of paired proportions, with Newcombe's square-and-add
interval for paired data (`newcombe_paired_interval`). The divergence profile is, per control
step, how far apart the object centres and the grip points (tool centre points) are between the
engines' trajectories from the same start under the same policy (each engine closing its own
loop), over the episodes: mean, 90th percentile and maximum.
"""

from __future__ import annotations

import csv
import math
import os

import numpy as np

from daddpg_jax.analysis.evaluation import Z95, evaluate, wilson_interval
from mjx_envs.schema import ConfigError
from mjx_envs.settings import LATEST_PHYSICS_VERSION, PHYSICS

WARP = "warp"
"""MJX's Warp implementation (``mjx.put_model(..., impl="warp")``): CUDA only, not an engine here"""

ENGINE_FIELDS = ("physics", "success_rate", "successes", "success_ci95", "arm_contact_rate",
                 "arm_contact_episodes", "arm_contact_ci95", "final_distance_mean",
                 "final_distance_median", "physics_fault_rate", "physics_fault_episodes",
                 "eval_seconds")
"""the fields of one engine's evaluation summary kept under ``engines`` in a comparison"""

RUN_FIELDS = ("run_dir", "checkpoint", "best", "env_steps", "task", "algo", "episodes", "seed",
              "distance_threshold")
"""the fields a comparison shares between engines (taken from the first)"""

PROFILE_COLUMNS = ("step", "time_s", "episodes", "object_mean_m", "object_p90_m",
                   "object_max_m", "grip_mean_m", "grip_p90_m", "grip_max_m")


def check_request(physics: str | None, episodes: int, chunk: int | None = None,
                  watchdog: float | None = None, perturb=(), out: str | None = None,
                  video: str | None = None, physics_version: int | None = None,
                  divergence: str | None = None) -> tuple:
    """The engines a ``daddpg-evaluate`` request names (``(None,)``: the run's), after checking
    that its options fit together; raises ConfigError (one line naming the flag)."""
    if episodes < 1:
        raise ConfigError("--episodes must be >= 1")
    if chunk is not None and chunk < 1:
        raise ConfigError("--chunk must be >= 1")
    if watchdog is not None and watchdog < 0:
        raise ConfigError("--watchdog must be >= 0 (0: none)")
    if perturb and not out:
        raise ConfigError("--perturb needs --out DIR")
    if perturb and video:
        raise ConfigError("--perturb and --video exclude each other")
    names = (None,) if physics is None else parse_engines(physics)
    if len(names) > 1 and (perturb or video):
        raise ConfigError("--perturb and --video take one engine, not a comparison")
    if physics_version is not None and not 1 <= physics_version <= LATEST_PHYSICS_VERSION:
        raise ConfigError(f"--physics-version must be in [1, {LATEST_PHYSICS_VERSION}], got "
                          f"{physics_version}")
    if divergence and len(names) < 2:
        raise ConfigError("--divergence needs two engines, e.g. --physics c,mjx")
    return names


def parse_engines(spec: str, backend: str | None = None) -> tuple[str, ...]:
    """``--physics`` value -> engine names: one (as given, ``auto`` included) or two distinct
    engines to compare (``auto`` resolved). Raises ConfigError (one line) for unknown or
    repeated names, more than two, and ``warp`` (CUDA only; refused on a CPU)."""
    # lazy: backends imports JAX (daddpg-evaluate --help stays JAX-free)
    import jax

    from mjx_envs.physics.backends import default_physics

    backend = backend or jax.default_backend()
    names = [x.strip() for x in str(spec).split(",")]
    if any(not x for x in names):
        raise ConfigError(f"--physics '{spec}': an empty engine name")
    for x in names:
        if x == WARP:
            if backend == "cpu":
                raise ConfigError("physics 'warp' (MJX's Warp implementation) needs a CUDA GPU; "
                                  "on a CPU use --physics c or mjx")
            raise ConfigError("physics 'warp' is not supported by this version; use --physics "
                              "mjx on an accelerator")
        if x not in PHYSICS:
            raise ConfigError(f"--physics: unknown engine '{x}' (choose from "
                              f"{', '.join(PHYSICS)}; two to compare, e.g. c,mjx)")
    if len(names) == 1:
        return (names[0],)
    if len(names) > 2:
        raise ConfigError(f"--physics '{spec}': give one engine, or two to compare (e.g. c,mjx)")
    resolved = tuple(default_physics() if x == "auto" else x for x in names)
    if resolved[0] == resolved[1]:
        raise ConfigError(f"--physics '{spec}' names the engine '{resolved[0]}' twice")
    return resolved


def newcombe_paired_interval(both: int, first_only: int, second_only: int, neither: int,
                             z: float = Z95) -> tuple[float, float]:
    """95 % interval (default) of p1 - p2 for paired binary outcomes: Newcombe's square-and-add
    interval for paired data (Newcombe 1998, method 10; Fagerland, Lydersen & Laake 2017,
    "Statistical analysis of contingency tables", ch. 8).

    With counts a = both, b = first only, c = second only, d = neither (n = a+b+c+d),
    p1 = (a+b)/n, p2 = (a+c)/n and their Wilson intervals (l1, u1), (l2, u2):
        L = (p1-p2) - sqrt((p1-l1)² + (u2-p2)² - 2 φ (p1-l1)(u2-p2))
        U = (p1-p2) + sqrt((p2-l2)² + (u1-p1)² - 2 φ (p2-l2)(u1-p1))
    where φ estimates the correlation of the pair, with Newcombe's continuity correction:
    A = ad - bc; φ = (A - n/2)/√((a+b)(c+d)(a+c)(b+d)) if A > n/2, 0 if 0 <= A <= n/2,
    A/√(...) if A < 0, and 0 when a margin is empty. Clipped to [-1, 1]."""
    counts = (both, first_only, second_only, neither)
    if any(int(x) != x or x < 0 for x in counts):
        raise ValueError(f"counts must be integers >= 0, got {counts}")
    a, b, c, d = (int(x) for x in counts)
    n = a + b + c + d
    if n == 0:
        return (math.nan, math.nan)
    p1, p2 = (a + b) / n, (a + c) / n
    l1, u1 = wilson_interval(a + b, n, z)
    l2, u2 = wilson_interval(a + c, n, z)
    margins = (a + b) * (c + d) * (a + c) * (b + d)
    phi = 0.0
    if margins > 0:
        big_a = a * d - b * c
        if big_a > n / 2:
            phi = (big_a - n / 2) / math.sqrt(margins)
        elif big_a < 0:
            phi = big_a / math.sqrt(margins)
    diff = p1 - p2
    down = (p1 - l1) ** 2 + (u2 - p2) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2)
    up = (p2 - l2) ** 2 + (u1 - p1) ** 2 - 2 * phi * (p2 - l2) * (u1 - p1)
    return (max(-1.0, diff - math.sqrt(max(down, 0.0))),
            min(1.0, diff + math.sqrt(max(up, 0.0))))


def paired_counts(first, second) -> dict:
    """Per-episode booleans of two engines -> {both, first_only, second_only, neither}."""
    x, y = np.asarray(first, bool), np.asarray(second, bool)
    if x.shape != y.shape:
        raise ValueError(f"paired outcomes need the same episodes: {x.shape} vs {y.shape}")
    return {"both": int(np.sum(x & y)), "first_only": int(np.sum(x & ~y)),
            "second_only": int(np.sum(~x & y)), "neither": int(np.sum(~x & ~y))}


def compare(policies: dict, episodes: int = 100, seed: int | None = None, chunk="auto",
            watchdog="auto", report=None):
    """Evaluates one checkpoint loaded once per engine (``{engine: Policy}``, two engines, the
    first is A) over the same episodes. Returns (summary, {engine: trajectory}): the summary
    holds the run's fields, ``engines: {name: {success_rate, successes, success_ci95,
    final_distance_* (and final_distance_mean_without_faults: over the episodes without a
    physics fault), arm_contact_*, physics_fault_*, ...}}`` and ``difference: {engines: [A,
    B], value: success A - success B, ci95, paired: {both, first_only, second_only, neither}}``.
    ``report(name, summary)`` is called after each engine."""
    names = list(policies)
    if len(names) != 2:
        raise ValueError(f"compare needs two engines, got {names}")
    runs, trajs = {}, {}
    for name in names:
        runs[name], trajs[name] = evaluate(policies[name], episodes, seed, chunk=chunk,
                                           watchdog=watchdog)
        if report is not None:
            report(name, runs[name])
    first = runs[names[0]]
    counts = paired_counts(trajs[names[0]]["success"], trajs[names[1]]["success"])
    value = runs[names[0]]["success_rate"] - runs[names[1]]["success_rate"]
    summary = {k: first[k] for k in RUN_FIELDS if k in first}
    summary["engines"] = {name: {k: runs[name][k] for k in ENGINE_FIELDS if k in runs[name]}
                          for name in names}
    for name in names:   # a faulted episode's distance is NaN: the mean over the others too
        ok = ~np.asarray(trajs[name]["physics_fault"], bool)
        dist = np.asarray(trajs[name]["final_distance"])[ok]
        summary["engines"][name]["final_distance_mean_without_faults"] = (
            {arm: float(dist[:, i].mean()) if len(dist) else math.nan
             for i, arm in enumerate(("left", "right"))})
    summary["difference"] = {
        "engines": names, "value": value,
        "ci95": list(newcombe_paired_interval(counts["both"], counts["first_only"],
                                              counts["second_only"], counts["neither"])),
        "paired": counts}
    return summary, trajs


def compare_report(policies: dict, episodes: int = 100, seed: int | None = None,
                   divergence_dir: str | None = None, report=None, **eval_opts):
    """`compare`, and with divergence_dir the divergence profile of the two engines'
    trajectories written there (`write_divergence`; its paths in summary["divergence"]).
    Returns (summary, text): the text is `format_comparison` plus the divergence files."""
    summary, trajs = compare(policies, episodes, seed, report=report, **eval_opts)
    if divergence_dir:
        a, b = summary["difference"]["engines"]
        first = policies[a]
        profile = divergence_profile(trajs[a], trajs[b], dt=first.env.dt)
        title = (f"{first.cfg.task} / {os.path.basename(os.path.abspath(first.run_dir))} / "
                 f"checkpoint {first.step}: {a} vs {b}, {episodes} episodes")
        summary["divergence"] = {k: os.path.abspath(v) for k, v in
                                 write_divergence(profile, divergence_dir, title).items()}
    text = format_comparison(summary)
    if divergence_dir:
        text += f"\ndivergence: {summary['divergence']['csv']}, {summary['divergence']['png']}"
    return summary, text


def format_comparison(s: dict) -> str:
    """The text summary of `compare`."""
    a, b = s["difference"]["engines"]
    lines = [f"run {s['run_dir']}",
             f"checkpoint {s['checkpoint']}; task {s['task']}, algo {s['algo']}; "
             f"{s['episodes']} episodes, seed {s['seed']}, deterministic actors, the same "
             "episodes on each engine"]
    for name, e in s["engines"].items():
        lo, hi = e["success_ci95"]
        fd = e.get("final_distance_mean_without_faults", e["final_distance_mean"])
        lines.append(
            f"{name:>4}: success {e['success_rate']:.3f} ({e['successes']}/{s['episodes']}; "
            f"95% Wilson {lo:.3f}-{hi:.3f}); final goal distance mean left {fd['left']:.4f} "
            f"right {fd['right']:.4f} m (episodes without a physics fault); arm contact "
            f"{e['arm_contact_rate']:.3f}; physics faults {e['physics_fault_rate']:.3f}")
    d = s["difference"]
    p = d["paired"]
    lines.append(f"difference {a} - {b}: {d['value']:+.3f} (paired 95% Newcombe interval "
                 f"{d['ci95'][0]:+.3f} to {d['ci95'][1]:+.3f}; episodes solved by both "
                 f"{p['both']}, {a} only {p['first_only']}, {b} only {p['second_only']}, "
                 f"neither {p['neither']})")
    return "\n".join(lines)


def divergence_profile(traj_a: dict, traj_b: dict, dt: float = 1.0) -> dict:
    """Per control step t = 0..T (0 = the start), over the episodes: mean, 90th percentile and
    maximum of the object-centre distance ||object_A - object_B|| and of the grip-point
    distance (the larger of the two arms') between two engines' trajectories of the same
    episodes (`evaluation.evaluate`'s ``object`` [N, T+1, 3] and ``grip`` [N, T+1, 2, 3]).
    An episode whose state is not finite on either engine (a physics fault) is left out from
    that step on; ``episodes`` counts the ones kept (NaN statistics when none is).
    Returns {column: array [T+1]} with the columns of ``PROFILE_COLUMNS`` (metres)."""
    for k in ("object", "grip"):
        if np.shape(traj_a[k]) != np.shape(traj_b[k]):
            raise ValueError(f"{k}: the trajectories differ in shape "
                             f"{np.shape(traj_a[k])} vs {np.shape(traj_b[k])}")
    obj = np.linalg.norm(np.asarray(traj_a["object"], np.float64)
                         - np.asarray(traj_b["object"], np.float64), axis=-1)        # [N, T+1]
    grip = np.linalg.norm(np.asarray(traj_a["grip"], np.float64)
                          - np.asarray(traj_b["grip"], np.float64), axis=-1).max(-1)  # [N, T+1]
    kept = np.logical_and.accumulate(np.isfinite(obj) & np.isfinite(grip), axis=1)  # [N, T+1]
    steps = np.arange(obj.shape[1])
    out = {"step": steps, "time_s": steps * float(dt), "episodes": kept.sum(0)}
    for name, x in (("object", obj), ("grip", grip)):
        for col, stat in (("mean", np.mean), ("p90", lambda v: np.percentile(v, 90)),
                          ("max", np.max)):
            out[f"{name}_{col}_m"] = np.array([stat(x[kept[:, t], t]) if kept[:, t].any()
                                               else np.nan for t in steps])
    return out


def write_divergence(profile: dict, out_dir: str, title: str = "") -> dict:
    """OUT_DIR/divergence.csv (one row per control step, ``PROFILE_COLUMNS``) and
    OUT_DIR/divergence.png (object and grip-point distances against the control step).
    Returns {"csv": path, "png": path}."""
    os.makedirs(out_dir, exist_ok=True)
    paths = {"csv": os.path.join(out_dir, "divergence.csv"),
             "png": os.path.join(out_dir, "divergence.png")}
    with open(paths["csv"], "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(PROFILE_COLUMNS)
        for i in range(len(profile["step"])):
            w.writerow([int(profile["step"][i]), f"{float(profile['time_s'][i]):.6g}",
                        int(profile["episodes"][i])]
                       + [f"{float(profile[c][i]):.6g}" for c in PROFILE_COLUMNS[3:]])
    _plot_divergence(profile, paths["png"], title)
    return paths


def _plot_divergence(profile: dict, path: str, title: str) -> None:
    import matplotlib  # lazy: plotting only when a profile is written

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), sharex=True)
    for ax, name, label in ((axes[0], "object", "object centre"),
                            (axes[1], "grip", "grip point (worse arm)")):
        x = profile["step"]
        ax.plot(x, 1000 * profile[f"{name}_mean_m"], label="mean")
        ax.plot(x, 1000 * profile[f"{name}_p90_m"], "--", label="90th percentile")
        ax.plot(x, 1000 * profile[f"{name}_max_m"], ":", label="max")
        ax.set_yscale("symlog", linthresh=1.0)   # linear below 1 mm: outliers stay readable
        ax.set_xlabel("control step")
        ax.set_ylabel(f"{label} distance, mm")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
