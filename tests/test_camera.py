"""The camera path (daddpg_jax/deploy/camera): the render copy steps like the simulator, tag
poses, Reach targets and object estimates from small renders against the simulator's truth,
the tracking filter, the calibration and its refusals, the limits' ``[camera]`` table, and the
OpenCV and RealSense cameras (a generated video file; a fake ``pyrealsense2``). Renders are
small (at most 320x240, no shadows) with the camera close to what it looks at."""

from __future__ import annotations

import math
import os
import types

import cv2
import mujoco
import numpy as np
import pytest
from PIL import Image

from daddpg_jax.deploy.arms import ArmsEnv
from daddpg_jax.deploy.camera import calibration as cal
from daddpg_jax.deploy.camera import objects as ob
from daddpg_jax.deploy.camera import tags as tg
from daddpg_jax.deploy.camera.config import (
    CameraConfig,
    CameraConfigError,
    camera_from_limits,
    nominal_pose,
)
from daddpg_jax.deploy.camera.factory import make_camera
from daddpg_jax.deploy.camera.frames import (
    CameraError,
    Frame,
    Intrinsics,
    look_at,
    matrix_to_quat,
    matrix_to_rotvec,
    quat_to_matrix,
    rotvec_to_matrix,
    yaw_matrix,
    yaw_of,
)
from daddpg_jax.deploy.camera.opencv_camera import OpenCVCamera
from daddpg_jax.deploy.camera.realsense_camera import RealSenseCamera
from daddpg_jax.deploy.camera.sim_camera import (
    PERFECT,
    SensorModel,
    SimCamera,
    SimClock,
    build_render_model,
)
from daddpg_jax.deploy.ursim import SimArms, SimCell
from mjx_envs import observation as obs_lib
from mjx_envs.model import load_model
from mjx_envs.numpy_env import NumpyDualArmEnv
from mjx_envs.registry import saved_config


def _close_camera(env, centre, distance=0.55, size=(240, 180), sensor=PERFECT, seed=0,
                  elevation=60.0):
    """A small SimCamera ``distance`` m from ``centre`` (in front of it, looking down)."""
    T = cal.board_view_pose(distance, elevation, 0.0, centre)
    cfg = CameraConfig(T_world_cam=T, width=size[0], height=size[1], fovy_deg=45.0)
    return SimCamera(env, cfg, sensor, seed=seed, shadows=False)


def _truth(env):
    return obs_lib.read_object_sensors(np, env.sensors, env._sens)


# -- the render copy ----------------------------------------------------------------------------

@pytest.mark.parametrize("task,version", [("pickup", 3), ("pot", 1)])
def test_render_copy_steps_like_the_simulator(task, version):
    """~0.5 s: the copy (tags on the object, colours, Reach tags, board, camera) and the
    simulator's model, stepped 60 physics steps from one state with the arms moving and the
    fingers closing, keep identical qpos and qvel; the copy has every body of the simulator
    first, and the simulator's model is still the shipped scene's."""
    cfg = saved_config(task, {"physics_version": version})
    sim = load_model(cfg.scene, cfg.timestep, cfg.cone, version)
    ref = load_model(cfg.scene, cfg.timestep, cfg.cone, version)
    rm = build_render_model(cfg)
    assert rm.model.nq == sim.nq and rm.model.nv == sim.nv and rm.sim_nmocap == 2
    assert rm.model.ngeom > sim.ngeom and rm.model.nbody > sim.nbody
    for i in range(sim.nbody):
        assert rm.model.body(i).name == sim.body(i).name
    d1, d2 = mujoco.MjData(sim), mujoco.MjData(rm.model)
    key = sim.key("home")
    for m, d in ((sim, d1), (rm.model, d2)):
        d.qpos[:] = key.qpos
        d.mocap_pos[:2] = key.mpos.reshape(-1, 3)[:2]
        d.mocap_quat[:2] = key.mquat.reshape(-1, 4)[:2]
        mujoco.mj_forward(m, d)
    for k in range(60):
        for m, d in ((sim, d1), (rm.model, d2)):
            d.ctrl[:] = 0.02 if k < 30 else 0.0
            d.mocap_pos[0] = key.mpos[:3] + np.array([0.0, 0.0, -0.002 * k])
            d.mocap_pos[1] = key.mpos[3:6] + np.array([0.001 * k, 0.0, -0.002 * k])
            mujoco.mj_step(m, d)
    assert np.array_equal(d1.qpos, d2.qpos) and np.array_equal(d1.qvel, d2.qvel)
    assert np.array_equal(sim.body_mass, ref.body_mass) and sim.ngeom == ref.ngeom


# -- tags and targets ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def reach_env():
    env = NumpyDualArmEnv(task="reach")
    env.reset(np.random.default_rng(0))
    return env


def test_reach_tags_from_a_render_give_the_goal_samplers_targets(reach_env):
    """~1 s (one renderer, 3 renders of 320x240): the per-arm tags placed for a sampled goal
    are found within 5 mm and 3 deg of their true poses, the targets from them within 5 mm of
    the goal; the paper's one-tag layout gives the tag's offsets; a tag out of view leaves its
    arm's target NaN."""
    env = reach_env
    rng = np.random.default_rng(7)
    goal = env.sample_goal(rng)
    while goal[:, 2].max() > 0.50:  # a goal whose tags are not under the grippers at home
        goal = env.sample_goal(rng)
    cam = _close_camera(env, (0.26, 0.0, 0.45), distance=0.75, size=(320, 240))
    try:
        cam.place_targets(goal, tg.PER_ARM_LAYOUT)
        frame = cam.capture()
        assert frame.rgb.shape == (240, 320, 3) and frame.depth.shape == (240, 320)
        poses = tg.tag_poses(frame, tg.TagDetector(), cam.T_world_cam)
        for i in (1, 2):
            T = cam.tag_pose(i)
            assert np.linalg.norm(poses[i].position - T[:3, 3]) < 0.005
            cos = (np.trace(poses[i].rotation.T @ T[:3, :3]) - 1) / 2
            assert math.degrees(math.acos(min(1.0, cos))) < 3.0
        got = tg.targets_from_tags(poses, tg.PER_ARM_LAYOUT)
        assert got.complete and np.max(np.linalg.norm(got.targets - goal, axis=1)) < 0.005
        img = tg.draw_tags(frame.rgb, poses, frame.intrinsics, cam.T_world_cam, goal)
        assert img.shape == frame.rgb.shape and not np.array_equal(img, frame.rgb)
        cam.place_targets(goal, tg.PAPER_LAYOUT)
        one = tg.targets_from_camera(cam, cam.T_world_cam, tg.PAPER_LAYOUT, frames=1)
        centre = cam.tag_pose(0)[:3, 3]  # on the table: below the mean of the goals
        assert one.complete and centre[2] == pytest.approx(0.401)
        assert np.allclose(one.targets, centre + np.asarray(tg.PAPER_LAYOUT.offsets), atol=0.006)
        cam.place_tag(0, None)
        none = tg.targets_from_camera(cam, cam.T_world_cam, tg.PAPER_LAYOUT, frames=1)
        assert not none.found.any() and np.isnan(none.targets).all()
    finally:
        cam.close()


def test_tag_images_and_edge_refinement():
    """~0.1 s: a printable tag has the black square and white margin of its cells and is
    detected; refining already exact corners of a large synthetic tag moves them < 0.15 px,
    and corners off by 1 px come back within 0.2 px."""
    img = tg.tag_image(3, cell_px=10)
    assert img.shape == (100, 100) and img[:10].min() == 255 and img[10:20, 10:90].max() == 0
    big = np.pad(img, 40, constant_values=255)
    dets = tg.TagDetector().detect(big)
    assert [d.id for d in dets] == [3]
    true = np.array([[50, 50], [130, 50], [130, 130], [50, 130]], float) - 0.5
    assert np.max(np.abs(dets[0].corners - true)) < 0.15
    off = true + np.array([[1.0, -1.0], [-1.0, 1.0], [1.0, 1.0], [-1.0, -1.0]])
    assert np.max(np.abs(tg.refine_edges(big, off) - true)) < 0.2


def test_apriltag_backend_agrees_with_aruco():
    """~0.1 s (skipped without pupil_apriltags): both backends give the same corners."""
    pytest.importorskip("pupil_apriltags")
    img = np.pad(tg.tag_image(5, cell_px=8), 30, constant_values=255)
    img = cv2.warpAffine(img, np.array([[0.9, 0.2, 5.0], [-0.15, 0.95, 8.0]]), (150, 150),
                         flags=cv2.INTER_LINEAR, borderValue=255)
    a, b = tg.TagDetector("aruco").detect(img), tg.TagDetector("apriltag").detect(img)
    assert [d.id for d in a] == [d.id for d in b] == [5]
    assert np.max(np.abs(a[0].corners - b[0].corners)) < 0.3
    with pytest.raises(ValueError, match="backend"):
        tg.TagDetector("nope")


# -- objects ------------------------------------------------------------------------------------

@pytest.mark.parametrize("task", ["pickup", "pot"])
def test_objects_from_tag_and_colour_against_the_truth(task):
    """~0.5 s each (one renderer, 2 renders of 240x180 with the sensor's noise): the object's
    centre and object points within 10 mm and its yaw within 3 deg, from its tag and from
    colour and depth, at a drawn placement turned by 0.2 rad."""
    env = NumpyDualArmEnv(task=task)
    qpos = env.sample_qpos(np.random.default_rng(3))
    adr = env.rules.qpos_adr
    qpos[adr + 3:adr + 7] = matrix_to_quat(yaw_matrix(0.2))
    env.reset(goal=np.zeros((2, 3)), qpos=qpos)
    truth = _truth(env)
    cam = _close_camera(env, truth["pos"], distance=0.5, sensor=SensorModel(), seed=1)
    try:
        g = ob.geometry_for_task(task)
        frame = cam.capture()
        true_yaw = math.atan2(*quat_to_matrix(truth["quat"])[[1, 0], 0])
        for est in (ob.TagObjectEstimator(g, cam.T_world_cam),
                    ob.ColourObjectEstimator(g, cam.T_world_cam)):
            e = est.estimate(frame)
            assert e is not None, est.source
            assert np.linalg.norm(e.pos - truth["pos"]) < 0.010, est.source
            assert np.max(np.linalg.norm(e.points - truth["object_point"], axis=1)) < 0.010
            assert abs(math.degrees(e.yaw - true_yaw)) < 3.0, est.source
    finally:
        cam.close()


def test_camera_object_source_in_an_arms_env():
    """~1 s (one renderer, ~8 renders of 200x150): an `ArmsEnv` on the simulated arms whose
    object comes from the camera (the bar's tag) resets and steps; the observed object points
    stay within 10 mm of the truth, every reading is a fresh sighting (age 0)."""
    env = NumpyDualArmEnv(task="pickup")
    spec = NumpyDualArmEnv(task="pickup")
    cell = SimCell(env)
    cam = _close_camera(env, (0.25, 0.0, 0.42), distance=0.55, size=(200, 150))
    try:
        source = ob.make_object_source(cam, "pickup", cam.T_world_cam, "tag", place=cell.reset)
        arms = ArmsEnv(spec, SimArms(cell), objects=source, truth=cell.truth)
        res = arms.reset(np.random.default_rng(0))
        for _ in range(3):
            res = arms.step_targets(arms.target, np.zeros(4, np.float32))
            reading = source.tracker.update(None, cam.now())
            assert reading["seen"] is False and reading["age"] == pytest.approx(0.0)
        obs_point = res.observation[:, 3:6]
        assert np.max(np.linalg.norm(obs_point - _truth(env)["object_point"], axis=1)) < 0.010
    finally:
        cam.close()


def _estimate(t, pos, yaw=0.0):
    R = yaw_matrix(yaw)
    p = np.asarray(pos, float)
    return ob.ObjectEstimate(p, R, ob.BAR.object_points(p, R), t, "tag")


def test_tracker_holds_while_hidden_and_reports_the_age():
    """~0.01 s: a bar moving at 0.1 m/s along x is tracked with its velocity; hidden, "hold"
    keeps its last pose with zero velocity and the age grows, "predict" extrapolates for up to
    predict_s and then holds that pose; a new sighting after a long gap restarts without a
    velocity."""
    for mode in ("hold", "predict"):
        tr = ob.ObjectTracker(ob.BAR, mode=mode, predict_s=0.2)
        assert tr.update(None, 0.0)["age"] == math.inf
        for k in range(20):
            r = tr.update(_estimate(0.04 * k, (0.25 + 0.004 * k, 0.0, 0.42)))
        assert r["seen"] and r["age"] == 0.0
        assert r["linvel"][0] == pytest.approx(0.1, abs=0.01)
        last = np.array(r["pos"])
        hidden = [tr.update(None, 0.76 + 0.04 * k) for k in range(1, 11)]
        ages = [h["age"] for h in hidden]
        assert np.allclose(ages, 0.04 * np.arange(1, 11)) and not any(h["seen"] for h in hidden)
        if mode == "hold":
            for h in hidden:
                assert np.allclose(h["pos"], last) and not np.any(h["linvel"])
        else:
            assert hidden[2]["pos"][0] == pytest.approx(last[0] + 0.1 * 0.12, abs=0.002)
            assert hidden[-1]["pos"][0] == pytest.approx(last[0] + 0.1 * 0.2, abs=0.002)
            assert not np.any(hidden[-1]["linvel"])
            last = np.array(hidden[-1]["pos"])
        assert np.allclose(hidden[-1]["object_point"], ob.BAR.object_points(last, np.eye(3)),
                           atol=1e-4)
        r = tr.update(_estimate(2.0, (0.30, 0.0, 0.42)))
        assert r["age"] == 0.0 and not np.any(r["linvel"])
    with pytest.raises(ValueError):
        ob.ObjectTracker(ob.BAR, mode="guess")


def test_pot_yaw_from_one_handle_and_held_while_both_are_hidden():
    """~0.01 s: the handles' axis seen from the lid's centre: one handle alone (a short bar
    across the axis) still gives the axis, not the handle's own length; a sighting of the
    lid alone (no yaw) cannot start a track, and later moves the position while the track's
    yaw is held."""
    rng = np.random.default_rng(0)
    yaw = np.radians(30.0)
    axis = np.array([-np.sin(yaw), np.cos(yaw), 0.0])  # the object's y axis (the handles)
    across = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    centre = np.array([0.3, 0.0, 0.45])
    handle = centre + 0.095 * axis + rng.uniform(-0.03, 0.03, (200, 1)) * across \
        + rng.uniform(-0.005, 0.005, (200, 1)) * axis
    a = ob._radial_axis(handle, centre, np.array([0.0, 0.0, 1.0]))
    assert abs(a @ axis) > 0.999
    tr = ob.ObjectTracker(ob.POT)
    R = yaw_matrix(yaw)
    lid_only = ob.ObjectEstimate(centre, np.eye(3), ob.POT.object_points(centre, np.eye(3)),
                                 0.0, "colour", has_yaw=False)
    assert tr.update(lid_only)["age"] == math.inf  # no track from a position alone
    tr.update(ob.ObjectEstimate(centre, R, ob.POT.object_points(centre, R), 0.04, "colour"))
    moved = centre + np.array([0.0, 0.0, 0.02])
    lid_only.pos, lid_only.stamp = moved, 0.08
    r = tr.update(lid_only)
    assert r["seen"] and r["pos"][2] > centre[2] + 0.01
    assert yaw_of(quat_to_matrix(r["quat"])) == pytest.approx(yaw, abs=1e-3)


def test_tracker_ignores_a_frame_delivered_again_and_predicts_over_latency():
    """~0.01 s: a dropped capture delivers the previous frame again (same capture time): the
    velocity estimate is kept, not reset; a frame older than the last one changes nothing;
    "predict" reads a late frame (100 ms) at the present, "hold" at its capture time."""
    for mode, lead in (("hold", 0.0), ("predict", 0.1)):
        tr = ob.ObjectTracker(ob.BAR, mode=mode)
        for k in range(20):
            est = _estimate(0.04 * k, (0.25 + 0.004 * k, 0.0, 0.42))
            r = tr.update(est, 0.04 * k + 0.1)  # every frame 100 ms late
        again = tr.update(est, 0.04 * 20 + 0.1)  # the same frame once more, 40 ms later
        assert again["linvel"][0] == pytest.approx(0.1, abs=0.01)
        older = tr.update(_estimate(0.5, (0.0, 0.0, 0.42)), 0.04 * 21 + 0.1)
        assert older["pos"][0] > 0.3  # not pulled back to x = 0
        truth = 0.25 + 0.1 * (0.04 * 19 + lead)  # where the bar is (predict) / was (hold)
        assert r["pos"][0] == pytest.approx(truth, abs=0.002), mode


class _Stub:
    """A camera whose frames carry only a stamp, and an estimator that sees the object in
    the first ``n`` frames only."""

    def __init__(self, n):
        self.n, self.t, self.geometry, self.placed = n, 0.0, ob.BAR, []
        self.intrinsics = Intrinsics.from_fovy(8, 6, 45.0)

    def capture(self):
        self.t += 0.04
        return Frame(np.zeros((6, 8, 3), np.uint8), self.t, self.intrinsics)

    def now(self):
        return self.t

    def estimate(self, frame):
        return _estimate(frame.stamp, (0.25, 0.0, 0.42)) if frame.stamp < 0.04 * self.n + 1e-9 \
            else None


def test_camera_object_source_holds_under_occlusion():
    """~0.01 s: the source places the object at reset, reads until a first sighting, then
    holds the bar's pose while the estimator loses it, with the sighting's age."""
    stub = _Stub(2)
    src = ob.CameraObjectSource(stub, stub, place=stub.placed.append)
    src.reset("qpos")
    assert stub.placed == ["qpos"]
    first = src.read()
    assert first["seen"] and first["object_point"][0, 1] == pytest.approx(0.135)
    later = [src.read() for _ in range(3)]
    assert [round(r["age"], 3) for r in later] == [0.04, 0.08, 0.12]
    assert all(np.allclose(r["pos"], first["pos"]) for r in later)


class _Late(_Stub):
    """Frames 100 ms old: the bar at rest until 0.2 s, then lifted at 0.5 m/s."""

    def capture(self):  # the present is advanced by the test's loop, as by a control period
        return Frame(np.zeros((6, 8, 3), np.uint8), self.t - 0.1, self.intrinsics)

    def estimate(self, frame):
        return _estimate(frame.stamp, (0.25, 0.0, 0.42 + 0.5 * max(frame.stamp - 0.2, 0.0)))


def test_predict_carries_a_held_object_with_the_grippers():
    """~0.01 s: with frames 100 ms late, "predict" moves a bar held at both necks as the
    grippers moved since the frame's capture (the arms' readings are not late): the reading
    is where the bar is now, not where it was; grippers away from the necks carry nothing."""
    for held, mode in ((True, "predict"), (False, "predict"), (True, "hold")):
        cam = _Late(0)
        src = ob.CameraObjectSource(cam, cam, ob.ObjectTracker(ob.BAR, mode))
        for _ in range(20):
            cam.t += 0.04
            z = 0.42 + 0.5 * max(cam.t - 0.2, 0.0)  # the bar (and grippers) at the present
            necks = ob.BAR.object_points(np.array([0.25, 0.0, z]), np.eye(3))
            src.observe_arms(necks if held else necks + [[0, 0.1, 0], [0, -0.1, 0]])
            r = src.read()
        z_now = 0.42 + 0.5 * (cam.t - 0.2)
        z_seen = z_now - 0.5 * 0.1
        want = z_now if held and mode == "predict" else z_seen
        if mode == "predict" and not held:  # the velocity's own prediction, not the grippers'
            assert abs(r["pos"][2] - z_now) < abs(z_seen - z_now)
        else:
            assert r["pos"][2] == pytest.approx(want, abs=0.005), (held, mode)


# -- calibration --------------------------------------------------------------------------------

INTR = Intrinsics.from_fovy(640, 480, 45.0)


def test_calibration_from_synthetic_detections_and_its_refusals():
    """~0.1 s: the board seen from the nominal mount with 0.2 px corner noise gives the pose
    within 3 mm and 0.2 deg; refused: too few tags, a mirrored layout, tags printed 10 %
    larger than the layout says, a tag moved from its place (named), a large reprojection
    error."""
    T = nominal_pose()
    dets = cal.synthetic_detections(cal.NOMINAL_BOARD, T, INTR, noise_px=0.2)
    frame = Frame(np.zeros((480, 640, 3), np.uint8), 0.0, INTR)
    c = cal.calibrate_camera_pose([frame], detections=[dets])
    assert np.linalg.norm(c.T_world_cam[:3, 3] - T[:3, 3]) < 0.003
    assert np.linalg.norm(matrix_to_rotvec(c.T_world_cam[:3, :3].T @ T[:3, :3])) < 0.0035
    assert set(c.residual_px) == set(cal.NOMINAL_BOARD.tags) and c.rms_px < 0.5
    assert "tag 10" in "\n".join(c.report_lines())
    with pytest.raises(cal.CalibrationError, match="at least 3"):
        cal.calibrate_camera_pose([frame], detections=[dets[:2]])
    with pytest.raises(cal.CalibrationError, match="mirrored"):
        cal.calibrate_camera_pose([frame], cal.NOMINAL_BOARD.mirrored(), detections=[dets])
    with pytest.raises(cal.CalibrationError, match="scaled by 0.9"):
        cal.calibrate_camera_pose([frame], cal.NOMINAL_BOARD.scaled(1.1), detections=[dets])
    moved = dict(cal.NOMINAL_BOARD.tags)
    c13, yaw, size = moved[13]
    moved[13] = ((c13[0] + 0.04, c13[1], c13[2]), yaw, size)
    with pytest.raises(cal.CalibrationError, match="tag 13|RMS"):
        cal.calibrate_camera_pose([frame], cal.BoardLayout(moved), detections=[dets])
    noisy = cal.synthetic_detections(cal.NOMINAL_BOARD, T, INTR, noise_px=4.0)
    with pytest.raises(cal.CalibrationError, match="RMS"):
        cal.calibrate_camera_pose([frame], detections=[noisy])
    with pytest.raises(cal.CalibrationError, match="no frame"):
        cal.calibrate_camera_pose([])


def test_calibration_from_a_render(reach_env):
    """~0.6 s (one 320x240 render from the nominal mount, tags 8 cm): the board's fit puts
    the camera within 10 mm and 0.5 deg of its true pose."""
    cfg = CameraConfig(width=320, height=240)
    cam = SimCamera(reach_env, cfg, PERFECT, shadows=False)
    try:
        c = cal.calibrate_camera_pose([cam.capture()])
    finally:
        cam.close()
    T = cfg.T_world_cam
    assert len(c.residual_px) >= 5
    assert np.linalg.norm(c.T_world_cam[:3, 3] - T[:3, 3]) < 0.010
    assert math.degrees(np.linalg.norm(matrix_to_rotvec(c.T_world_cam[:3, :3].T @ T[:3, :3]))) \
        < 0.5


def _chessboard_views(K, n=6, size=(320, 240), pattern=(7, 5), square=0.03):
    """Views of a chessboard (``pattern`` inner corners) by a camera K from ``n`` poses."""
    cols, rows = pattern
    px = 20  # board pixels per square in the flat image
    board = np.kron((np.indices((rows + 1, cols + 1)).sum(0) % 2) * 255,
                    np.ones((px, px))).astype(np.uint8)
    board = np.pad(board, px, constant_values=255)
    S = np.array([[square / px, 0, -square], [0, square / px, -square], [0, 0, 1]])
    views = []
    for k in range(n):
        R = rotvec_to_matrix([0.35 * math.cos(k), 0.35 * math.sin(k), 0.1 * k])
        t = np.array([-0.10 + 0.01 * k, -0.07, 0.45 + 0.03 * k])
        H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ S
        views.append(cv2.warpPerspective(board, H, size, flags=cv2.INTER_LINEAR,
                                         borderValue=128))
    return views


def test_intrinsics_from_a_chessboard():
    """~1 s: six synthetic 320x240 views of a chessboard give fx, fy within 2 % and the
    principal point within 4 px of the camera that made them; too few views are refused."""
    K = np.array([[300.0, 0, 161.0], [0, 300.0, 118.0], [0, 0, 1]])
    views = _chessboard_views(K)
    intr, rms = cal.intrinsics_from_chessboard(views, (7, 5), 0.03)
    assert rms < 1.0 and (intr.width, intr.height) == (320, 240)
    assert abs(intr.fx / 300 - 1) < 0.02 and abs(intr.fy / 300 - 1) < 0.02
    assert abs(intr.cx - 161) < 4 and abs(intr.cy - 118) < 4
    with pytest.raises(cal.CalibrationError, match="at least 5"):
        cal.intrinsics_from_chessboard(views[:2], (7, 5), 0.03)


# -- the simulated camera -----------------------------------------------------------------------

def test_sim_camera_own_stream_latency_and_clock(reach_env):
    """~2 s (two renderers, 8 renders of 64x48): two cameras of one seed give identical
    frames and leave the episode's random stream alone; with 80 ms latency a frame shows the
    state of two control steps before; the clock keeps counting over resets."""
    env = reach_env
    cfg = CameraConfig(width=64, height=48)
    sensor = SensorModel(latency=(0.08, 0.08))
    a, b = (SimCamera(env, cfg, sensor, seed=5, shadows=False) for _ in range(2))
    try:
        rng = np.random.default_rng(11)
        env.reset(rng)
        state = rng.bit_generator.state
        a.reset()
        b.reset()
        fa, fb = a.capture(), b.capture()
        assert np.array_equal(fa.rgb, fb.rgb) and np.array_equal(fa.depth, fb.depth)
        assert rng.bit_generator.state == state
        stamps = [fa.stamp]
        for _ in range(3):
            env.step(np.ones(8, np.float32))
            stamps.append(a.capture().stamp)
        assert a.now() - stamps[-1] == pytest.approx(0.08, abs=1e-6)
        assert stamps == pytest.approx([0.0, 0.0, 0.0, 0.04], abs=1e-6)
        env.reset(rng)
        assert a.now() >= stamps[-1]
    finally:
        a.close()
        b.close()
    clock = SimClock()
    assert [clock(t) for t in (0.0, 0.5, 1.0, 0.0, 0.2)] == [0.0, 0.5, 1.0, 1.0, 1.2]


def test_make_camera_and_the_limits_table(tmp_path, reach_env):
    """~0.5 s: no ``[camera]`` table gives the nominal simulated mount and the paper's
    layout; a full table is read; bad values are refused in one line; `make_camera` builds
    each kind."""
    nominal = camera_from_limits(None)
    assert nominal.kind == "sim" and not nominal.mounted and nominal.layout == "paper"
    assert np.allclose(nominal.T_world_cam, nominal_pose())
    c = camera_from_limits({"camera": {
        "kind": "opencv", "position": [1.0, 0.1, 1.3], "look_at": [0.3, 0.0, 0.4],
        "width": 320, "height": 240, "device": 2, "layout": "per-arm",
        "fx": 300.0, "fy": 301.0, "cx": 160.0, "cy": 120.0, "dist": [0.1, 0, 0, 0, 0]}})
    assert c.mounted and c.device == "2" and c.target_layout is tg.PER_ARM_LAYOUT
    assert nominal.target_layout is tg.PAPER_LAYOUT
    assert c.intrinsics.fy == 301.0 and c.intrinsics.dist[0] == 0.1
    assert np.allclose(c.T_world_cam[:3, 3], [1.0, 0.1, 1.3])
    rv = camera_from_limits({"camera": {"position": [1, 0, 1], "rotvec": [3.0, 0.0, 0.0]}})
    assert np.allclose(matrix_to_rotvec(rv.T_world_cam[:3, :3]), [3.0, 0.0, 0.0])
    for bad, msg in [({"kind": "kinect"}, "kind"), ({"colour": 1}, "unknown"),
                     ({"position": [1, 0]}, "position"), ({"look_at": [0, 0, 0]}, "without"),
                     ({"position": [1, 0, 1]}, "exactly one"), ({"width": 0}, "width"),
                     ({"fx": 300.0}, "all of"), ({"layout": "x"}, "layout"),
                     ({"position": [1, 0, 1], "look_at": [1, 0, 1.01]}, "5 cm")]:
        with pytest.raises(CameraConfigError, match=msg):
            camera_from_limits({"camera": bad})
    sim = make_camera(CameraConfig(width=32, height=24), reach_env, seed=1)
    assert isinstance(sim, SimCamera) and sim.intrinsics.width == 32
    sim.close()
    with pytest.raises(CameraConfigError, match="env"):
        make_camera(CameraConfig())
    video = _write_video(tmp_path / "v.avi", 2)
    cam = make_camera(CameraConfig(kind="opencv", device=str(video), width=64, height=48))
    assert isinstance(cam, OpenCVCamera)
    cam.close()
    with pytest.raises(CameraError, match="pyrealsense2"):
        make_camera(CameraConfig(kind="realsense"))


def test_frames_helpers():
    """~0.01 s: rotations round-trip through quaternions and rotation vectors (also near pi),
    `look_at` looks along +z with the image's up towards the world's up."""
    for rv in ([0.1, -0.2, 0.3], [math.pi - 1e-4, 0, 0], [0, 0, 0]):
        R = rotvec_to_matrix(rv)
        assert np.allclose(quat_to_matrix(matrix_to_quat(R)), R)
        assert np.allclose(rotvec_to_matrix(matrix_to_rotvec(R)), R, atol=1e-6)
    T = look_at((1, 0, 1), (0, 0, 0))
    assert np.allclose(T[:3, 2], np.array([-1, 0, -1]) / math.sqrt(2))
    assert T[:3, 1] @ np.array([0, 0, 1]) < 0
    with pytest.raises(ValueError):
        look_at((0, 0, 1), (0, 0, 0))
    f = Frame(np.full((2, 2, 3), 200, np.uint8), 0.0, Intrinsics.from_fovy(2, 2, 90.0))
    assert f.gray.dtype == np.uint8 and int(f.gray[0, 0]) == 200


# -- OpenCV and RealSense cameras ---------------------------------------------------------------

def _write_video(path, n, size=(64, 48)):
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, size)
    assert w.isOpened()
    for k in range(n):
        img = np.zeros((size[1], size[0], 3), np.uint8)
        img[..., 2] = 200  # red in BGR
        img[:, : 8 * (k + 1)] = 255
        w.write(img)
    w.release()
    return path


def test_opencv_camera_reads_a_video_file(tmp_path):
    """~0.1 s: a 3-frame MJPG file is read as RGB frames with a monotonic stamp and no depth;
    its end raises CameraError (or starts again with loop=True)."""
    path = _write_video(tmp_path / "clip.avi", 3)
    cam = OpenCVCamera(str(path))
    frames = [cam.capture() for _ in range(3)]
    assert all(f.depth is None and f.rgb.shape == (48, 64, 3) for f in frames)
    assert frames[0].rgb[40, 60, 0] > 150 and frames[0].rgb[40, 60, 2] < 60  # RGB order
    assert [f.index for f in frames] == [0, 1, 2] and frames[2].stamp >= frames[0].stamp
    with pytest.raises(CameraError, match="no frame"):
        cam.capture()
    cam.close()
    looped = OpenCVCamera(str(path), loop=True)
    assert [looped.capture().index for _ in range(4)] == [0, 1, 2, 3]
    looped.close()
    with pytest.raises(CameraError, match="cannot open"):
        OpenCVCamera(str(tmp_path / "missing.avi"))
    wrong = OpenCVCamera(str(path), intrinsics=Intrinsics.from_fovy(32, 24, 45.0))
    with pytest.raises(CameraError, match="intrinsics"):
        wrong.capture()
    wrong.close()


def _fake_rs(depth_units=0.001, timestamp_ms=None):
    """A stand-in for ``pyrealsense2`` with the calls `RealSenseCamera` makes."""
    rs = types.SimpleNamespace()
    rs.stream = types.SimpleNamespace(color="color", depth="depth")
    rs.format = types.SimpleNamespace(rgb8="rgb8", z16="z16")
    rs.timestamp_domain = types.SimpleNamespace(global_time="global", system_time="system",
                                                hardware_clock="hw")
    calls = []

    class Data:
        def __init__(self, a):
            self.a, self.ts = a, timestamp_ms

        def get_data(self):
            return self.a

        def get_timestamp(self):
            return self.ts

        def get_frame_timestamp_domain(self):
            return "system" if self.ts is not None else "hw"

    class FrameSet:
        def get_color_frame(self):
            return Data(np.full((4, 6, 3), 7, np.uint8))

        def get_depth_frame(self):
            return Data(np.full((4, 6), 1500, np.uint16))

    class Pipeline:
        def start(self, cfg):
            calls.append(("start", cfg.streams, cfg.device))
            intr = types.SimpleNamespace(width=6, height=4, fx=5.0, fy=5.5, ppx=2.5, ppy=1.5,
                                         coeffs=[0.1, 0.0, 0.0, 0.0, 0.0])
            video = types.SimpleNamespace(get_intrinsics=lambda: intr)
            stream = types.SimpleNamespace(as_video_stream_profile=lambda: video)
            sensor = types.SimpleNamespace(get_depth_scale=lambda: depth_units)
            device = types.SimpleNamespace(first_depth_sensor=lambda: sensor)
            return types.SimpleNamespace(get_device=lambda: device,
                                         get_stream=lambda s: stream)

        def wait_for_frames(self, timeout_ms):
            calls.append(("wait", timeout_ms))
            return FrameSet()

        def stop(self):
            calls.append(("stop",))

    class Config:
        def __init__(self):
            self.streams, self.device = [], None

        def enable_stream(self, *a):
            self.streams.append(a)

        def enable_device(self, serial):
            self.device = serial

    class Align:
        def __init__(self, to):
            calls.append(("align", to))

        def process(self, frames):
            return frames

    rs.pipeline, rs.config, rs.align = Pipeline, Config, Align
    return rs, calls


def test_realsense_camera_against_a_fake_module():
    """~0.01 s: against a fake ``pyrealsense2`` the camera asks for RGB and Z16 streams of
    the size given, aligns depth to colour, reports the colour stream's intrinsics and
    distortion, depth in metres, and maps a system-clock timestamp onto the monotonic clock."""
    rs, calls = _fake_rs(timestamp_ms=1000.0 * 99.95)
    cam = RealSenseCamera(6, 4, 15, serial="123", rs=rs, clock=lambda: 50.0, wall=lambda: 100.0)
    assert calls[0] == ("start", [("color", 6, 4, "rgb8", 15), ("depth", 6, 4, "z16", 15)],
                        "123")
    assert ("align", "color") in calls
    assert cam.intrinsics == Intrinsics(6, 4, 5.0, 5.5, 2.5, 1.5, (0.1, 0.0, 0.0, 0.0, 0.0))
    f = cam.capture()
    assert f.rgb.shape == (4, 6, 3) and f.depth.dtype == np.float32
    assert np.allclose(f.depth, 1.5) and f.stamp == pytest.approx(49.95)
    cam.close()
    assert calls[-1] == ("stop",)
    rs2, _ = _fake_rs()
    assert RealSenseCamera(6, 4, rs=rs2, clock=lambda: 7.0).capture().stamp == 7.0


def test_shipped_tag_files_match_the_tag_table():
    """~0.3 s: assets/tags/ has one printable file per shipped tag, named with its size,
    whose tag decodes to its id and whose black square is its size at the file's DPI."""
    folder = os.path.join(os.path.dirname(__file__), "..", "assets", "tags")
    for tag_id, (size, _) in tg.SHIPPED_TAGS.items():
        path = os.path.join(folder, f"tag36h11_id{tag_id}_{round(size * 1000)}mm.png")
        im = Image.open(path)
        img = np.asarray(im.convert("L"))
        dets = tg.TagDetector().detect(cv2.resize(img, (300, 300), interpolation=cv2.INTER_AREA))
        assert [d.id for d in dets] == [tag_id]
        black = np.nonzero(img.min(axis=0) < 128)[0]
        side_m = (black[-1] - black[0] + 1) / im.info["dpi"][0] * 0.0254
        assert side_m == pytest.approx(size, rel=1e-3)
