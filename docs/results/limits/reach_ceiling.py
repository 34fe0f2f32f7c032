"""Which reach goal pairs can be reached at all under the arm-clearance rule: the geometric
ceiling of reach's success under a limits file, for the 200 episodes (seed 5) of
straight_line_ceiling.py and the robot client (goal, then start, from one Generator).

1. Geometry. For each episode the NumPy simulator (contacts off, each tool centre welded to
   its mocap target), without limits, drives both targets to the goals in a straight line and
   lets the arms settle; then it places each target at 69 points of the success ball (the goal;
   at radii 0.0195 and 0.01 m the cube's 26 directions and four along and across the line
   joining the two goals; 8 points on the line from the other arm's nearest link point through
   the tool centre), settling each. The two arms move independently (no contacts), so every
   pair of points (left i, right j) is a configuration: its capsule gap is
   `mjx_envs.observation.arm_clearance` of the measured link points. An episode is reachable
   at a clearance c when some pair with both measured tool centres inside the success radius
   (`distance_threshold` 0.02 m, strict) has a gap >= c: c = 0.01 (sim.toml), 0 (the capsules
   themselves) and 0.05 m (ur3_cell.toml). Where the best pair's gap is within 1 cm below one
   of these, a random local search (500 joint moves, inside radius 0.0199 m) refines it. Each
   episode's best pair is placed again with both arms together (``pair_check_error``: the
   independence of the arms, ~0). The best gap over a finite set is a lower bound of
   the true best, so the fractions are lower bounds of the geometric ceiling; the geometric
   ceiling is an upper bound of what any controller reaches (a path must exist too).
2. Straight line. The straight-line controller of straight_line_ceiling.py through sim.toml's
   rules (`robot_limits`), for the per-episode successes.
3. Rule-aware controller (a lower bound that a smarter controller does better): each period it
   previews the rules (`mjx_envs.limit_rules.apply`, the env's own step) on 25 moves, each
   arm going 1, 1/2, 1/4, 1/8 or 0 of the way towards its aim point (at most max_delta per
   axis), and sends the move that passes unchanged and leaves the smallest summed distance to
   the aims (none passes: it holds). Aims: the grid's best pair of ball points from 1 (radius
   <= 0.0195 m) when its gap is >= 1 cm, else the refined pair when its gap is, else the goals;
   an episode that fails and has a refined pair >= 1 cm elsewhere runs again with that pair
   (success: either run). Through sim.toml, every episode.

Run from the repository root: python docs/results/limits/reach_ceiling.py
Output: reach_ceiling.json (per-episode gaps and the fractions; its wall time on a shared
2-core machine).
"""
import json
import os
import platform
import subprocess
import sys
import time

import numpy as np

from daddpg_jax.algo import resolve
from mjx_envs import limit_rules
from mjx_envs.numpy_env import NumpyDualArmEnv
from mjx_envs.observation import arm_clearance

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import straight_line_ceiling  # noqa: E402  (beside this file: the same controller)

EPISODES, SEED = 200, 5
SIM, CELL = "daddpg_jax/deploy/limits/sim.toml", "daddpg_jax/deploy/limits/ur3_cell.toml"
RADII = (0.0195, 0.01)  # inside the 0.02 m success radius (the tool trails its target < 1 mm)
REFINE_STEPS = 500  # local-search moves per borderline episode
REFINE_SIGMAS = (0.01, 0.005, 0.0025, 0.001, 0.0005)  # their spread, m, 100 moves each
REFINE_RADIUS = 0.0199
SETTLE = 12  # periods at each point (the tool is within 1 mm of its target after ~5)
APART = 27  # the point "apart" at the outer radius (after the goal and the cube's 26)
CLEARANCES = {"0 cm (capsules)": 0.0, "1 cm (sim.toml)": 0.01, "5 cm (ur3_cell.toml)": 0.05}


def directions(goal):
    """Unit offsets [K, 3] per arm [2, K, 3]: the cube's 26, then along (apart, together) and
    across (horizontal, vertical) the line joining the goals."""
    cube = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)
                     if (x, y, z) != (0, 0, 0)], float)
    cube /= np.linalg.norm(cube, axis=1, keepdims=True)
    u = goal[0] - goal[1]
    u /= np.linalg.norm(u)
    h = np.cross(u, [0.0, 0.0, 1.0])
    h = h / np.linalg.norm(h) if np.linalg.norm(h) > 1e-6 else np.array([1.0, 0.0, 0.0])
    v = np.cross(u, h)
    left = np.concatenate([cube, [u, -u, h, v]])
    right = np.concatenate([cube, [-u, u, h, v]])
    return np.stack([left, right])


def settle(env, target, ctrl):
    for _ in range(SETTLE):
        res = env.step_targets(target.astype(np.float32), ctrl)
    return res


def nearest_link_dirs(lp):
    """Per arm, the unit direction [2, 3] from its tool centre away from the other arm's
    nearest link point (the radial search of the docstring)."""
    out = np.zeros((2, 3))
    for a in range(2):
        tool, other = lp[a, 4], lp[1 - a]
        d = tool - other
        n = np.linalg.norm(d, axis=1)
        out[a] = d[np.argmin(n)] / max(n.min(), 1e-9)
    return out


def refine(env, goal, aim, gap, ctrl, rng):
    """A random local search from the grid's best pair when its gap is within 1 cm below a
    clearance of `CLEARANCES`: both targets moved together, each kept inside radius
    ``REFINE_RADIUS`` of its goal; a point counts when both measured tool centres are inside the
    success radius. Returns (best gap, its aims [2, 3])."""
    if not any(c - 0.01 <= gap < c for c in CLEARANCES.values()):
        return gap, aim
    for sigma in np.repeat(REFINE_SIGMAS, REFINE_STEPS // len(REFINE_SIGMAS)):
        off = aim - goal + rng.normal(0.0, sigma, (2, 3))
        n = np.linalg.norm(off, axis=1, keepdims=True)
        off *= np.minimum(1.0, REFINE_RADIUS / np.maximum(n, 1e-12))
        res = settle(env, goal + off, ctrl)
        if np.all(res.goal_distance < env.threshold) and res.arm_clearance > gap:
            gap, aim = float(res.arm_clearance), goal + off
    return gap, aim


def geometry(env, rng):
    """Per-episode best gaps over the success balls (see the module doc)."""
    ctrl = env.finger_ctrl(np.zeros(2, np.float32))
    rows = []
    for k in range(EPISODES):
        res = env.reset(rng)
        goal = res.desired_goal.astype(float)
        tgt = res.target.astype(float)
        for _ in range(env.episode_length):  # straight line, no limits: every episode succeeds
            tgt = tgt + np.clip(goal - tgt, -env.max_delta, env.max_delta)
            res = env.step_targets(tgt.astype(np.float32), ctrl)
        res = settle(env, goal, ctrl)
        gap_centre = float(res.arm_clearance)
        dirs = directions(goal)
        radial = nearest_link_dirs(res.link_points)  # away from the other arm, and towards
        offsets = [np.zeros((2, 3))] + [r * dirs[:, i] for r in RADII
                                        for i in range(dirs.shape[1])]
        offsets += [s * r * radial for r in RADII + (0.015, 0.005) for s in (1, -1)]
        links, dist, aims = [], [], []
        for off in offsets:
            aim = goal + off
            res = settle(env, aim, ctrl)
            links.append(res.link_points.astype(np.float64))
            dist.append(res.goal_distance.astype(float))
            aims.append(aim)
        links, dist, aims = np.array(links), np.array(dist), np.array(aims)  # [P, 2, ...]
        pair = np.stack(np.broadcast_arrays(links[:, None, 0], links[None, :, 1]), axis=2)
        gaps = arm_clearance(np, pair)  # [P left, P right]
        ok = (dist[:, None, 0] < env.threshold) & (dist[None, :, 1] < env.threshold)
        gaps = np.where(ok, gaps, -np.inf)
        i, j = np.unravel_index(np.argmax(gaps), gaps.shape)
        grid_aim = best_aim = np.stack([aims[i, 0], aims[j, 1]])
        best_gap, best_aim = refine(env, goal, best_aim, float(gaps[i, j]), ctrl,
                                    np.random.default_rng([SEED, k]))
        res = settle(env, best_aim, ctrl)  # both arms there together: the pair's gap again
        rows.append(dict(
            episode=k, goal=np.round(goal, 5).tolist(),
            goal_separation=round(float(np.linalg.norm(goal[0] - goal[1])), 5),
            gap_at_goals=round(gap_centre, 5),
            gap_apart=round(float(gaps[APART, APART]), 5) if np.isfinite(gaps[APART, APART])
            else None,
            grid_gap=round(float(gaps[i, j]), 5),
            grid_aim=np.round(grid_aim, 5).tolist(),
            best_gap=round(best_gap, 5),
            best_aim=np.round(best_aim, 5).tolist(),
            best_aim_distance=np.round(res.goal_distance.astype(float), 5).tolist(),
            pair_check_error=float(f"{abs(float(res.arm_clearance) - best_gap):.2g}"),
            points_inside=[int((dist[:, a] < env.threshold).sum()) for a in range(2)],
        ))
    return rows


def straight_line(env, rng):
    """(success, final gap, final distances) per episode of straight_line_ceiling.py."""
    out = []
    for _ in range(EPISODES):
        res = straight_line_ceiling.episode(env, rng)
        out.append((bool(res.success), float(res.arm_clearance),
                    res.goal_distance.astype(float).tolist()))
    return out


FRACTIONS = (1.0, 0.5, 0.25, 0.125, 0.0)


def rule_aware(env, rng, aims, only=None):
    """Per-episode success of the rule-aware controller (module doc, 3) through env's rules
    (False without a run for the episodes not in ``only``, when given)."""
    out = []
    for k in range(EPISODES):
        res = env.reset(rng)
        if only is not None and not only[k]:
            out.append(False)
            continue
        aim = np.asarray(aims[k], np.float32)
        for _ in range(env.episode_length):
            links, tool = limit_rules.measured(np, env.sensors, env._sens, env.dt)
            want = np.clip((aim - res.achieved_goal) / env.max_delta, -1, 1)
            moves = []
            for fl in FRACTIONS:
                for fr in FRACTIONS:
                    a = np.zeros((2, 4), np.float32)
                    a[0, :3], a[1, :3] = fl * want[0], fr * want[1]
                    proposed, _ = env.command_targets(a.reshape(-1))
                    moves.append((float(np.linalg.norm(aim - proposed, axis=-1).sum()),
                                  a.reshape(-1), proposed))
            best = np.zeros(8, np.float32)
            for _, a, proposed in sorted(moves, key=lambda m: m[0]):  # stable: ties in order
                t, _, flags = limit_rules.apply(np, env.limits, env.target, proposed, links,
                                                tool, np.zeros(2, np.float32))
                if not any(bool(v) for v in flags.values()) and np.allclose(t, proposed):
                    best = a
                    break
            res = env.step(best)
        out.append(bool(res.success))
    return out


def main():
    t0 = time.time()
    sim = resolve.limits_values(SIM, 1.0, "reach", {})
    free = NumpyDualArmEnv({}, task="reach")
    rows = geometry(free, np.random.default_rng(SEED))
    print(f"geometry {time.time() - t0:.0f} s", flush=True)
    limited = NumpyDualArmEnv({"robot_limits": sim}, task="reach")
    sl = straight_line(limited, np.random.default_rng(SEED))
    print(f"straight line {time.time() - t0:.0f} s", flush=True)
    aims = [r["grid_aim"] if r["grid_gap"] >= 0.01 else r["best_aim"] if r["best_gap"] >= 0.01
            else r["goal"] for r in rows]
    ra_grid = rule_aware(limited, np.random.default_rng(SEED), aims)
    again = [not ok and r["best_gap"] >= 0.01 and r["best_aim"] != a
             for ok, r, a in zip(ra_grid, rows, aims)]
    ra_refined = rule_aware(limited, np.random.default_rng(SEED),
                            [r["best_aim"] for r in rows], only=again)
    ra = [a or b for a, b in zip(ra_grid, ra_refined)]
    print(f"rule-aware {time.time() - t0:.0f} s", flush=True)
    for r, (ok, gap, dist), ok2, ok3, ok4 in zip(rows, sl, ra, ra_grid, ra_refined):
        r.update(straight_line_success=ok, straight_line_final_gap=round(gap, 5),
                 straight_line_final_distance=np.round(dist, 5).tolist(),
                 rule_aware_success=ok2, rule_aware_grid_aim=ok3, rule_aware_refined_aim=ok4)
    best = np.array([r["best_gap"] for r in rows])
    centre = np.array([r["gap_at_goals"] for r in rows])
    sl_ok = np.array([s[0] for s in sl])
    ra_ok = np.array(ra)
    fails = ~sl_ok
    out = dict(
        question="fraction of reach episodes whose goals can be reached at all under the "
                 "arm-clearance rule (a configuration inside the success ball with capsule gap "
                 ">= min_clearance)",
        episodes=EPISODES, seed=SEED, distance_threshold=free.threshold,
        ball_points_per_arm=1 + 30 * len(RADII) + 8,
        ceiling_grid_only={name: float(np.mean(np.array([r["grid_gap"] for r in rows]) >= c))
                           for name, c in CLEARANCES.items()},
        ceiling={name: float(np.mean(best >= c)) for name, c in CLEARANCES.items()},
        at_goal_centres={name: float(np.mean(centre >= c)) for name, c in CLEARANCES.items()},
        borderline_below={name: int(np.sum((best >= c - 0.003) & (best < c)))
                          for name, c in CLEARANCES.items()},
        crossed_goals=int(sum(r["goal"][0][1] < r["goal"][1][1] for r in rows)),
        crossed_goals_reachable={name: int(sum(r["goal"][0][1] < r["goal"][1][1]
                                               and r["best_gap"] >= c for r in rows))
                                 for name, c in CLEARANCES.items()},
        straight_line_sim_toml=float(sl_ok.mean()),
        straight_line_failures=int(fails.sum()),
        straight_line_failures_reachable_1cm=int((fails & (best >= 0.01)).sum()),
        straight_line_failures_reachable_0cm=int((fails & (best >= 0.0)).sum()),
        straight_line_successes_below_1cm=int((sl_ok & (best < 0.01)).sum()),
        rule_aware_sim_toml=float(ra_ok.mean()),
        rule_aware_refined_aim_reruns=int(sum(again)),
        rule_aware_or_straight_line=float((ra_ok | sl_ok).mean()),
        rule_aware_on_straight_line_failures=int((ra_ok & fails).sum()),
        revision=subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, check=False).stdout.strip(),
        machine=f"{platform.machine()} {platform.processor() or ''} "
                f"{os.cpu_count()} cores".replace("  ", " "),
        wall_s=round(time.time() - t0, 1),
        episodes_detail=rows,
    )
    with open("docs/results/limits/reach_ceiling.json", "w") as f:
        json.dump(out, f, indent=1)
    print(json.dumps({k: v for k, v in out.items() if k != "episodes_detail"}, indent=1))


if __name__ == "__main__":
    main()
