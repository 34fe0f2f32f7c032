"""Accuracy and time per frame of the camera path against the simulator's ground truth.

    MUJOCO_GL=egl python experiments/perception/accuracy.py            # 500 frames, 640x480

Frames come in groups of ``--group`` frames with one camera pose: per group the mount is the
nominal one moved at random (position +-6/10/8 cm in x/y/z, the point it looks at +-5 cm), the
camera is calibrated from one frame of the tag board (`calibrate_camera_pose`), and that
calibration, not the true pose, serves the group's frames. The groups take turns over three
scenes: Reach (the per-arm tags placed by the goal sampler of a seeded stream), the bar (push
and pick up: on the table or lifted up to 8 cm, turned up to +-0.4 rad, tilted up to +-5 deg
when lifted) and the pot (lifted up to 4 cm). Every frame draws new lighting (intensity and
direction), exposure, blur and noise (`SensorModel()`), the arms stand at home (their grippers
hide what is under them). Measured: each arm's target error and detection rate; per object
and method (tag, colour + depth) the centre, object point and yaw errors and the detection
rate; the calibration's pose error; the time of each stage per frame on this machine.

Writes ``--out`` (JSON) and ``--image`` (one 640x480 frame with the detections drawn).
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

import cv2  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from daddpg_jax.deploy.camera import objects as ob  # noqa: E402
from daddpg_jax.deploy.camera import tags as tg  # noqa: E402
from daddpg_jax.deploy.camera.calibration import (  # noqa: E402
    CalibrationError,
    calibrate_camera_pose,
)
from daddpg_jax.deploy.camera.config import (  # noqa: E402
    NOMINAL_LOOK_AT,
    NOMINAL_POSITION,
    CameraConfig,
)
from daddpg_jax.deploy.camera.frames import (  # noqa: E402
    Frame,
    look_at,
    matrix_to_quat,
    matrix_to_rotvec,
    quat_to_matrix,
    rotvec_to_matrix,
    yaw_of,
)
from daddpg_jax.deploy.camera.sim_camera import SensorModel, SimCamera  # noqa: E402
from mjx_envs import observation as obs_lib  # noqa: E402
from mjx_envs.numpy_env import NumpyDualArmEnv  # noqa: E402

SCENES = ("reach", "bar", "pot")


def revision() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def random_mount(rng) -> np.ndarray:
    p = np.asarray(NOMINAL_POSITION) + rng.uniform([-0.06, -0.10, -0.08], [0.06, 0.10, 0.08])
    c = np.asarray(NOMINAL_LOOK_AT) + rng.uniform([-0.05, -0.05, 0.0], [0.05, 0.05, 0.0])
    return look_at(p, c)


def place_object(env, rng, lift_max: float, tilt_deg: float) -> None:
    """The object at a random pose (the arms at home)."""
    qpos = env.home_qpos.copy()
    adr = env.rules.qpos_adr
    lifted = rng.uniform() < 0.5
    z = env.rules.rest_z + (rng.uniform(0.01, lift_max) if lifted else 0.0)
    tilt = np.radians(tilt_deg) * rng.uniform(-1, 1, 2) if lifted else np.zeros(2)
    yaw = rng.uniform(-0.4, 0.4)
    R = rotvec_to_matrix([0.0, 0.0, yaw]) @ rotvec_to_matrix([tilt[0], tilt[1], 0.0])
    qpos[adr:adr + 3] = [rng.uniform(0.18, 0.36), rng.uniform(-0.10, 0.10), z]
    qpos[adr + 3:adr + 7] = matrix_to_quat(R)
    env.reset(goal=np.zeros((2, 3), np.float32), qpos=qpos)


def timed_capture(cam: SimCamera, times: dict) -> Frame:
    """`SimCamera.capture` in stages (render; sensor effects), each timed."""
    t0 = time.perf_counter()
    stamp = cam.sync()
    rgb, depth = cam.render()
    t1 = time.perf_counter()
    rgb, depth = cam.degrade(rgb, depth)
    t2 = time.perf_counter()
    times["render"].append(t1 - t0)
    times["sensor"].append(t2 - t1)
    return Frame(rgb=rgb, stamp=stamp, intrinsics=cam.intrinsics, depth=depth)


def calibrate(cam: SimCamera, detector, rng, stats: dict) -> np.ndarray | None:
    """The group's camera pose from one frame of the board (the Reach tags parked)."""
    for tid in (0, 1, 2):
        cam.place_tag(tid, None)
    cam.reset()
    frame = cam.capture()
    try:
        c = calibrate_camera_pose([frame], detector=detector)
    except CalibrationError as e:
        stats["refused"].append(str(e))
        return None
    T = cam.T_world_cam
    stats["pos_mm"].append(1000 * float(np.linalg.norm(c.T_world_cam[:3, 3] - T[:3, 3])))
    stats["rot_deg"].append(math.degrees(float(np.linalg.norm(
        matrix_to_rotvec(c.T_world_cam[:3, :3].T @ T[:3, :3])))))
    stats["rms_px"].append(c.rms_px)
    stats["tags"].append(len(c.residual_px))
    return c.T_world_cam


def yaw_error_deg(R_est, R_true) -> float:
    d = yaw_of(R_est) - yaw_of(R_true)
    return abs(math.degrees((d + math.pi) % (2 * math.pi) - math.pi))


def reach_frame(cam, env, detector, T_cal, rng, times, out) -> None:
    goal = env.sample_goal(rng)
    cam.place_targets(goal, tg.PER_ARM_LAYOUT)
    cam.reset()
    frame = timed_capture(cam, times)
    t0 = time.perf_counter()
    dets = detector.detect(frame.gray)
    t1 = time.perf_counter()
    poses = tg.tag_poses(frame, detector, T_cal, detections=dets)
    got = tg.targets_from_tags(poses, tg.PER_ARM_LAYOUT)
    t2 = time.perf_counter()
    times["detect"].append(t1 - t0)
    times["pose"].append(t2 - t1)
    for i in range(2):
        out["found"].append(bool(got.found[i]))
        if got.found[i]:
            out["err_mm"].append(1000 * float(np.linalg.norm(got.targets[i] - goal[i])))


def object_frame(cam, env, detector, T_cal, rng, times, out, lift_max) -> None:
    for tid in (0, 1, 2):
        cam.place_tag(tid, None)
    place_object(env, rng, lift_max, 5.0)
    cam.reset()
    truth = obs_lib.read_object_sensors(np, env.sensors, env._sens)
    R_true = quat_to_matrix(truth["quat"])
    frame = timed_capture(cam, times)
    g = ob.geometry_for_scene(env.config.scene)
    t0 = time.perf_counter()
    dets = detector.detect(frame.gray)
    t1 = time.perf_counter()
    poses = tg.tag_poses(frame, detector, T_cal, {g.tag_id: g.tag_size}, detections=dets)
    est_tag = ob.TagObjectEstimator(g, T_cal, detector).estimate(frame, poses)
    t2 = time.perf_counter()
    est_col = ob.ColourObjectEstimator(g, T_cal).estimate(frame)
    t3 = time.perf_counter()
    times["detect"].append(t1 - t0)
    times["pose"].append(t2 - t1)
    times["colour"].append(t3 - t2)
    for name, est in (("tag", est_tag), ("colour", est_col)):
        o = out[name]
        o["found"].append(est is not None)
        if est is None:
            continue
        o["centre_mm"].append(1000 * float(np.linalg.norm(est.pos - truth["pos"])))
        o["with_yaw"].append(est.has_yaw)
        if not est.has_yaw:  # the pot's lid alone (handles hidden): a position, no yaw
            continue
        o["points_mm"] += [1000 * float(x) for x in
                           np.linalg.norm(est.points - truth["object_point"], axis=1)]
        o["yaw_deg"].append(yaw_error_deg(est.R, R_true))


def summary(values) -> dict:
    v = np.asarray(values, float)
    if v.size == 0:
        return {"n": 0}
    return {"n": int(v.size), "median": round(float(np.median(v)), 2),
            "p95": round(float(np.percentile(v, 95)), 2), "max": round(float(v.max()), 2)}


def rate(found) -> dict:
    return {"n": len(found), "rate": round(float(np.mean(found)), 4) if found else None}


def picture(cams, envs, detector, path, seed) -> None:
    """One 640x480 frame of the bar with the Reach tags placed, detections drawn."""
    rng = np.random.default_rng(seed)
    cam, env = cams["bar"], envs["bar"]
    cam.set_pose(CameraConfig().T_world_cam)
    env.reset(np.random.default_rng(seed))
    for _ in range(50):  # a goal whose two tags are in view (not behind the bar or a gripper)
        goal = envs["reach"].sample_goal(rng)
        cam.place_targets(goal, tg.PER_ARM_LAYOUT)
        cam.reset()
        frame = cam.capture()
        poses = tg.tag_poses(frame, detector, cam.T_world_cam)
        if {1, 2, ob.BAR.tag_id} <= set(poses):
            break
    targets = tg.targets_from_tags(poses, tg.PER_ARM_LAYOUT).targets
    est = ob.TagObjectEstimator(ob.BAR, cam.T_world_cam, detector).estimate(frame, poses)
    points = [t for t in targets if np.all(np.isfinite(t))]
    if est is not None:
        points += list(est.points)
    img = tg.draw_tags(frame.rgb, poses, frame.intrinsics, cam.T_world_cam, np.asarray(points))
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    cv2.imwrite(path, cv2.cvtColor(img, cv2.COLOR_RGB2BGR))


def run(args) -> dict:
    rng = np.random.default_rng(args.seed)
    cfg = CameraConfig(width=args.width, height=args.height)
    envs = {"reach": NumpyDualArmEnv(task="reach"), "bar": NumpyDualArmEnv(task="pickup"),
            "pot": NumpyDualArmEnv(task="pot")}
    cams = {k: SimCamera(e, cfg, SensorModel(), seed=args.seed + i)
            for i, (k, e) in enumerate(envs.items())}
    for e in envs.values():
        e.reset(np.random.default_rng(0))
    detector = tg.TagDetector(args.backend)
    times = {k: [] for k in ("render", "sensor", "detect", "pose", "colour")}
    cal = {"pos_mm": [], "rot_deg": [], "rms_px": [], "tags": [], "refused": []}
    reach = {"found": [], "err_mm": []}
    objs = {s: {m: {"found": [], "centre_mm": [], "with_yaw": [], "points_mm": [],
                    "yaw_deg": []}
                for m in ("tag", "colour")} for s in ("bar", "pot")}
    frames, group = 0, 0
    t_start = time.perf_counter()
    while frames < args.frames:
        scene = SCENES[group % len(SCENES)]
        cam, env = cams[scene], envs[scene]
        cam.set_pose(random_mount(rng))
        T_cal = calibrate(cam, detector, rng, cal)
        group += 1
        if T_cal is None:
            continue
        for _ in range(min(args.group, args.frames - frames)):
            if scene == "reach":
                reach_frame(cam, env, detector, T_cal, rng, times, reach)
            else:
                object_frame(cam, env, detector, T_cal, rng, times, objs[scene],
                             0.08 if scene == "bar" else 0.04)
            frames += 1
        print(f"{frames}/{args.frames} frames, {time.perf_counter() - t_start:.0f} s",
              file=sys.stderr, flush=True)
    if args.image:
        picture(cams, envs, detector, args.image, args.seed)
    for c in cams.values():
        c.close()
    return {
        "frames": frames, "groups": group, "size": [args.width, args.height],
        "seed": args.seed, "backend": args.backend,
        "calibration": {"pos_mm": summary(cal["pos_mm"]), "rot_deg": summary(cal["rot_deg"]),
                        "rms_px": summary(cal["rms_px"]), "tags": summary(cal["tags"]),
                        "refused": cal["refused"]},
        "reach_targets": {"detection": rate(reach["found"]), "err_mm": summary(reach["err_mm"])},
        "objects": {s: {m: {"detection": rate(v["found"]), "centre_mm": summary(v["centre_mm"]),
                            "with_yaw": rate(v["with_yaw"]),
                            "points_mm": summary(v["points_mm"]),
                            "yaw_deg": summary(v["yaw_deg"])} for m, v in d.items()}
                    for s, d in objs.items()},
        "time_ms": {k: summary(1000 * np.asarray(v)) for k, v in times.items()},
        "wall_s": round(time.perf_counter() - t_start, 1),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "python": platform.python_version(), "mujoco": mujoco.__version__,
                    "opencv": cv2.__version__, "gl": os.environ.get("MUJOCO_GL")},
        "revision": revision(),
        "command": " ".join(["python"] + sys.argv),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=500)
    p.add_argument("--group", type=int, default=10, help="frames per camera pose")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--backend", default="aruco", choices=("aruco", "apriltag"))
    p.add_argument("--out", default="docs/results/perception/accuracy.json")
    p.add_argument("--image", default="docs/perception_frame.png")
    args = p.parse_args(argv)
    result = run(args)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps({k: result[k] for k in ("reach_targets", "objects", "calibration",
                                             "time_ms")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
