"""The camera in the closed loop: success with the camera against success with the ground
truth, paired over the same episodes, through the UR path on simulated controllers (``--arms
ur-sim``), in-process.

    MUJOCO_GL=egl python experiments/perception/closed_loop.py      # writes closed_loop.json

Each condition runs the robot client's loop (`daddpg_jax.deploy.robot.run_episodes`: the gate,
the safety layer, the UR driver path on simulated controllers, the episodes of one seed) with a
stand-in controller in place of a served policy (`daddpg_jax.deploy.stand_in`: Reach steps
towards the goal it is given; Pick up and Pot are the scripted two-arm grasp, which reads the
object's points from the observation, so it sees what the camera reports). No trained Pick up or Pot
policy ships with the project; the stand-ins are what is measured.

- Reach, ``--goals tags``: the per-arm Reach tags put where the sampler's goals are, read at
  reset (median of 3 frames, 640x480, 45 deg) with the arms parked behind the goal region;
  success judged against the true goals. Ground truth: the sampler's goals, the same parking.
- Pick up, ``--objects camera-tag`` (tag 20 on the bar) and ``camera-color`` (no tag: colour and
  depth): the bar from the camera every control period (256x192 at 26 deg: the pixels per
  radian of a 640x480 camera with a 60 deg field of view, cropped to the workspace), tracked in
  hold mode. Ground truth: the simulator's bar.
- Pot, ``--objects camera-tag`` (tag 21 on the lid) and ``camera-color`` (the lid's colour
  and depth, the yaw from the handles' colour): as Pick up, the same camera.
- Robustness: the camera moved after its calibration (1 cm along the world's y, turned 1 deg
  about the world's y: the limits keep the calibrated pose), 20 % of captures delivering the
  previous frame again, 100 ms capture latency (also with the tracker's ``predict`` mode).

Each condition is written to the JSON as it finishes; ``--only NAME...`` runs some again and
keeps the others.

A frame older than the limits' ``max_frame_age`` (0.15 s), a Reach tag not seen, or the bar
not seen for longer than ``max_object_lost`` (0.5 s) holds the arms; those episodes count as
failures. The simulated camera draws its noise, blur, exposure and lighting from its own
stream ([seed, CAMERA_STREAM]): goals and placements are those of the ground-truth run.
Paired 95 % interval of the difference: Newcombe's hybrid score interval for paired
proportions (method 10).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("LP_NUM_THREADS", "1")  # the CPU renderer on one thread: a shared machine

import numpy as np  # noqa: E402

from daddpg_jax.deploy import perception, robot  # noqa: E402
from daddpg_jax.deploy.limits import SHIPPED, RobotLimits  # noqa: E402
from daddpg_jax.deploy.robot_session import ENDS_RUN, arms_env, robot_task  # noqa: E402
from daddpg_jax.deploy.safety import SafetyFilter  # noqa: E402
from daddpg_jax.deploy.stand_in import client_for  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
OUT = os.path.join(ROOT, "docs", "results", "perception", "closed_loop.json")
CAMERAS = {"reach": {"width": 640, "height": 480, "fovy_deg": 45.0, "layout": "per-arm"},
           "pickup": {"width": 256, "height": 192, "fovy_deg": 26.0},
           "pot": {"width": 256, "height": 192, "fovy_deg": 26.0}}
MOVED = (0.0, 0.01, 0.0, 0.0, 1.0, 0.0)
"""the camera moved after calibration: dx, dy, dz (m), rx, ry, rz (deg, world frame)"""


class TruthGoals:
    """The ground truth's goal source: the sampler's goals, read with the arms parked as the
    camera's are (the same moves, so that the two runs stay paired)."""

    def __init__(self, park):
        self.park = park

    def read(self, goal, keepalive=None):
        for _ in range(perception.TAG_FRAMES):  # the arms hold as long as for the camera's
            if keepalive is not None:
                keepalive()
        return np.asarray(goal, np.float32), None


def limits_for(task: str) -> RobotLimits:
    import tomllib  # lazy: only here

    with open(os.path.join(SHIPPED, "sim.toml"), "rb") as f:
        d = tomllib.load(f)
    # unpaced on a shared CPU: the driver-call bound and the simulated controllers' watchdog
    # count wall time, so they get their largest values
    d.update(deadline=2.0, max_observation_age=2.0, call_timeout=2.0, watchdog=2.0,
             max_reading_gap=2.0, camera=dict(CAMERAS[task]))
    return RobotLimits.from_dict(d, source="sim.toml with a [camera] table")


def run(task: str, goals: str, objects: str, episodes: int, seed: int, sim=None,
        track: str = "hold") -> dict:
    """One condition: per-episode success (perception holds count as failures) and the
    run's summary."""
    limits = limits_for(task)
    safety = limits.safety_limits()
    sources = None
    if goals == "sampler" and objects == "sim":
        if task == "reach":
            park = perception.park_targets(limits)
            sources = lambda cell: (None, TruthGoals(park))  # noqa: E731
    else:
        sources = perception.Perception(goals, objects, "sim", limits, task, seed=seed,
                                        sim=sim or perception.SimOptions(), track=track)
    env = arms_env("ur-sim", robot_task(task), task, limits, safety=safety, sources=sources)
    logs = []
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        out = robot.run_episodes(env, client_for(task), SafetyFilter(safety), episodes,
                                 seed=seed, max_observation_age=limits.max_observation_age,
                                 on_log=lambda log: logs.append(log.get("summary", {})),
                                 ends_run=ENDS_RUN)
    finally:
        env.close()
    if out["aborted"]:
        raise SystemExit(f"{task} {goals} {objects}: aborted: {out['aborted']['reason']}")
    ok = [bool(s["success"] and not s["perception"] and not s["stops"]) for s in logs]
    faults = {}
    for s in logs:
        for e in s["errors"][:1] if s["perception"] else ():
            key = e.split("(")[0].strip()
            faults[key] = faults.get(key, 0) + 1
    return dict(success=ok, rate=float(np.mean(ok)), ci95=list(robot.wilson_interval(
        sum(ok), len(ok))), perception_held_episodes=out["perception_held_episodes"],
        excluded=out["excluded_episodes"], fault_kinds=faults,
        safety_counts=out["safety_counts"], wall_s=round(time.perf_counter() - t0, 1),
        cpu_s=round(time.process_time() - c0, 1))


def paired_interval(cam, truth, z: float = 1.96):
    """(difference cam - truth, Newcombe's 95 % interval) of paired binary outcomes."""
    cam, truth = np.asarray(cam, bool), np.asarray(truth, bool)
    n = len(cam)
    e, f = int(np.sum(cam & truth)), int(np.sum(cam & ~truth))
    g, h = int(np.sum(~cam & truth)), int(np.sum(~cam & ~truth))
    p1, p2 = (e + f) / n, (e + g) / n
    (l1, u1), (l2, u2) = robot.wilson_interval(e + f, n, z), robot.wilson_interval(e + g, n, z)
    den = (e + f) * (g + h) * (e + g) * (f + h)
    num = e * h - f * g
    num = max(num - n / 2.0, 0.0) if num > 0 else num  # Newcombe's correction of phi
    phi = num / math.sqrt(den) if den > 0 else 0.0
    d = p1 - p2
    lo = d - math.sqrt(max((p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2,
                           0.0))
    hi = d + math.sqrt(max((u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2,
                           0.0))
    return round(d, 4), [round(max(lo, -1.0), 4), round(min(hi, 1.0), 4)], \
        dict(both=e, camera_only=f, truth_only=g, neither=h)


def compare(name: str, cam: dict, truth: dict) -> dict:
    n = len(cam["success"])
    d, ci, table = paired_interval(cam["success"], truth["success"][:n])
    print(f"{name}: camera {cam['rate']:.3f} vs truth {np.mean(truth['success'][:n]):.3f} over "
          f"{n} episodes: difference {d:+.3f}, 95 % [{ci[0]:+.3f}, {ci[1]:+.3f}]; held "
          f"{cam['perception_held_episodes']} ({cam['fault_kinds']}); {cam['wall_s']} s",
          flush=True)
    return dict(episodes=n, camera_rate=cam["rate"], truth_rate=float(np.mean(
        truth["success"][:n])), difference=d, paired_ci95=ci, pairs=table,
        camera=cam, meets_target=ci[0] >= -0.10)


ROBUST = {"moved_1cm_1deg": dict(pose_error=MOVED), "dropped_20pc": dict(drop=0.2),
          "latency_100ms": dict(latency=0.1)}
"""what goes wrong after the calibration: the mount moved, dropped captures, a late frame"""


def conditions(n: int, n_colour: int, n_robust: int) -> dict:
    """name -> (task, goals, objects, episodes, robustness key or None, tracker mode), the
    ground truth of each task first."""
    c = {"truth_reach": ("reach", "sampler", "sim", n, None, "hold"),
         "truth_pickup": ("pickup", "sampler", "sim", n, None, "hold"),
         "reach_tags": ("reach", "tags", "sim", n, None, "hold"),
         "pickup_tag": ("pickup", "sampler", "camera-tag", n, None, "hold"),
         "pickup_colour": ("pickup", "sampler", "camera-color", n_colour, None, "hold"),
         "truth_pot": ("pot", "sampler", "sim", n, None, "hold"),
         "pot_tag": ("pot", "sampler", "camera-tag", n, None, "hold"),
         "pot_colour": ("pot", "sampler", "camera-color", n_colour, None, "hold")}
    for key in ROBUST:
        c[f"reach_tags_{key}"] = ("reach", "tags", "sim", n_robust, key, "hold")
        c[f"pickup_tag_{key}"] = ("pickup", "sampler", "camera-tag", n_robust, key, "hold")
    # the tracker's prediction carries a late frame to the present
    c["pickup_tag_latency_100ms_predict"] = ("pickup", "sampler", "camera-tag", n_robust,
                                             "latency_100ms", "predict")
    return c


def sim_options(key):
    from daddpg_jax.deploy.camera.sim_camera import SensorModel  # lazy: MuJoCo's renderer

    o = dict(ROBUST[key]) if key else {}
    lat = o.pop("latency", None)
    if lat is not None:
        o["sensor"] = SensorModel(latency=(lat, lat))
    return perception.SimOptions(**o)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=200, help="paired episodes per task")
    p.add_argument("--colour-episodes", type=int, default=200)
    p.add_argument("--robust-episodes", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--only", nargs="*", default=None, metavar="NAME",
                   help="run these conditions only (the ground truth they need too), keeping "
                        "the others already in --out")
    p.add_argument("--out", default=OUT)
    a = p.parse_args(argv)
    table = conditions(a.episodes, a.colour_episodes, a.robust_episodes)
    names = list(table) if a.only is None else a.only
    unknown = sorted(set(names) - set(table))
    if unknown:
        p.error(f"unknown conditions {unknown}; known: {sorted(table)}")
    res: dict = {}
    if a.only is not None and os.path.exists(a.out):
        with open(a.out) as f:
            res = json.load(f)
    res.setdefault("truth", {})
    rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                         text=True, cwd=ROOT).stdout.strip()
    t0 = time.perf_counter()
    for name in names:  # the truths first: each camera condition is compared with its task's
        task = table[name][0]
        truth = res["truth"].get(task)
        if truth is None or len(truth["success"]) < table[name][3]:
            print(f"ground truth, {task}: {max(table[f'truth_{task}'][3], table[name][3])} "
                  f"episodes", flush=True)
            res["truth"][task] = run(task, "sampler", "sim", max(table[f"truth_{task}"][3],
                                                                   table[name][3]), a.seed)
        if name.startswith("truth_"):
            continue
        task, goals, objects, n, key, track = table[name]
        cam = run(task, goals, objects, n, a.seed, sim_options(key), track=track)
        out = compare(name, cam, res["truth"][task])
        out.update(robustness=key, track=track, revision=rev)
        res.setdefault("conditions", {})[name] = out
        _write(a.out, res, a, rev, t0)  # each condition kept as it finishes
    _write(a.out, res, a, rev, t0)
    print(f"written {a.out} in {time.perf_counter() - t0:.1f} s", flush=True)
    return 0


def _write(path, res, a, rev, t0) -> None:
    res["meta"] = dict(command=" ".join(["python", "experiments/perception/closed_loop.py",
                                         *sys.argv[1:]]),
                       seed=a.seed, cameras=CAMERAS, moved=MOVED, revision=rev,
                       machine=f"{platform.machine()}, {os.cpu_count()} CPUs, no GPU; "
                               f"Python {platform.python_version()}",
                       wall_s=round(time.perf_counter() - t0, 1),
                       cpu_s=round(time.process_time(), 1))
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(res, f, indent=1)
    os.replace(tmp, path)


if __name__ == "__main__":
    sys.exit(main())
