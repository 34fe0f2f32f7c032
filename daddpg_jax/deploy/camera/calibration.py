"""Camera calibration (NumPy + OpenCV): the camera's pose in the world frame from a board of
AprilTags lying on the table at known places, and the camera's intrinsics (the device's, or
from views of a chessboard with ``cv2.calibrateCamera``).

    board = NOMINAL_BOARD                                       # id -> tag pose on the table
    cal = calibrate_camera_pose(frames, board)                  # CameraCalibration
    print("\n".join(cal.report_lines()))                        # each tag's residual
    intr, rms = intrinsics_from_chessboard(images, (9, 6), 0.025)

The pose is a least-squares fit over every corner of every board tag seen (``cv2.solvePnP``,
Levenberg-Marquardt from a start given by the tags' own poses); each tag's residual is reported
in pixels (reprojection) and in millimetres (its centre seen on its own, by IPPE, against its
known place). Refused (`CalibrationError`, one line): fewer than ``min_tags`` board tags, a fit
that needs a reflection (the board's layout is mirrored against what the camera sees) or a
scale off 1 by more than ``max_scale_error`` (a tag size or a board printed at the wrong
scale), an RMS reprojection error over ``max_rms_px``, or a tag's residual over
``max_residual_mm`` (that tag is named).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from daddpg_jax.deploy.camera.frames import (
    Intrinsics,
    apply,
    invert,
    look_at,
    transform,
    yaw_matrix,
)
from daddpg_jax.deploy.camera.tags import (
    SHIPPED_TAGS,
    TagDetection,
    TagDetector,
    corner_points,
    estimate_pose,
    project,
)

TABLE_Z = 0.40
"""the table top's height in the world frame, m"""
MIN_TAGS = 3
MAX_RMS_PX = 2.0
MAX_RESIDUAL_MM = 15.0
MAX_SCALE_ERROR = 0.03
TAG_THICKNESS = 0.001
"""a printed tag's thickness above the table (the tag's face is this much higher), m"""


class CalibrationError(ValueError):
    """A calibration that is refused (one line saying why)."""


@dataclass(frozen=True)
class BoardLayout:
    """The board's tags: id -> (centre [3] in the world frame, yaw about the vertical, rad,
    size m); each lies flat, facing up."""

    tags: dict

    def pose(self, tag_id: int) -> np.ndarray:
        centre, yaw, _ = self.tags[tag_id]
        return transform(yaw_matrix(yaw), centre)

    def corners(self, tag_id: int) -> np.ndarray:
        """The tag's four corners [4, 3] in the world frame (TL, TR, BR, BL)."""
        return apply(self.pose(tag_id), corner_points(self.tags[tag_id][2]))

    def sizes(self) -> dict:
        return {i: s for i, (_, _, s) in self.tags.items()}

    def mirrored(self) -> BoardLayout:
        """The layout mirrored left-right (y -> -y), as a wrongly entered board would be."""
        return BoardLayout({i: ((c[0], -c[1], c[2]), -yaw, s)
                            for i, (c, yaw, s) in self.tags.items()})

    def scaled(self, factor: float) -> BoardLayout:
        """The layout with every tag's size scaled (tags printed at the wrong scale)."""
        return BoardLayout({i: (c, yaw, s * factor) for i, (c, yaw, s) in self.tags.items()})


_Z = TABLE_Z + TAG_THICKNESS
NOMINAL_BOARD = BoardLayout({
    10: ((0.56, 0.30, _Z), 0.0, SHIPPED_TAGS[10][0]),
    11: ((0.56, 0.00, _Z), 0.0, SHIPPED_TAGS[11][0]),
    12: ((0.56, -0.30, _Z), 0.0, SHIPPED_TAGS[12][0]),
    13: ((0.38, 0.40, _Z), 0.0, SHIPPED_TAGS[13][0]),
    14: ((0.38, -0.40, _Z), 0.0, SHIPPED_TAGS[14][0]),
    15: ((0.16, 0.42, _Z), 0.0, SHIPPED_TAGS[15][0]),
})
"""The shipped board: six 8 cm tags (ids 10-15) lying on the table around the workspace, each
printed x axis along the world's x (yaw 0), each printed top edge towards +y."""


@dataclass
class CameraCalibration:
    """A camera pose (``T_world_cam``) fitted to a board, with each tag's residuals."""

    T_world_cam: np.ndarray
    rms_px: float
    residual_px: dict = field(default_factory=dict)
    residual_mm: dict = field(default_factory=dict)
    scale: float = 1.0
    frames: int = 1

    def report_lines(self) -> list[str]:
        p = self.T_world_cam[:3, 3]
        lines = [f"camera at ({p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}) m, "
                 f"{len(self.residual_px)} tags over {self.frames} frame(s), "
                 f"RMS {self.rms_px:.2f} px, scale {self.scale:.4f}"]
        for i in sorted(self.residual_px):
            lines.append(f"  tag {i}: {self.residual_px[i]:.2f} px, "
                         f"{self.residual_mm[i]:.1f} mm")
        return lines


def _umeyama(src, dst):
    """(scale, R, t, reflected) of the similarity dst ~ s R src + t; ``reflected``: the best
    fit needs det(R) < 0 (R is then the proper rotation closest to it)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.diag([1.0, 1.0, d])
    R = U @ D @ Vt
    var = float(np.mean(np.sum(a * a, axis=1)))
    s = float(np.sum(S * np.diag(D)) / var) if var > 0 else 1.0
    return s, R, mu_d - s * R @ mu_s, bool(d < 0)


def _collect(frames, board, detector, detections):
    """[(frame index, TagDetection, intrinsics)] of the board tags seen (each frame's ids
    once)."""
    out = []
    for k, frame in enumerate(frames):
        dets = detector.detect(frame.gray) if detections is None else detections[k]
        ids = [d.id for d in dets]
        for d in dets:
            if d.id in board.tags and ids.count(d.id) == 1:
                out.append((k, d, frame.intrinsics))
    return out


def calibrate_camera_pose(frames, board: BoardLayout = NOMINAL_BOARD,
                          detector: TagDetector | None = None, detections=None,
                          min_tags: int = MIN_TAGS, max_rms_px: float = MAX_RMS_PX,
                          max_residual_mm: float = MAX_RESIDUAL_MM,
                          max_scale_error: float = MAX_SCALE_ERROR) -> CameraCalibration:
    """The camera's pose from one or more frames of a still camera seeing the board
    (``frames``: `Frame` objects; ``detections``: per frame, the `TagDetection` list to use
    instead of detecting). See the module doc for what is refused."""
    frames = list(frames)
    if not frames:
        raise CalibrationError("no frame to calibrate from")
    seen = _collect(frames, board, TagDetector() if detector is None else detector, detections)
    ids = sorted({d.id for _, d, _ in seen})
    if len(ids) < min_tags:
        raise CalibrationError(f"{len(ids)} board tag(s) seen ({ids}); at least {min_tags} "
                               f"are needed (board ids {sorted(board.tags)})")
    intr = seen[0][2]
    # each tag on its own: its corners in the camera frame, against their known places
    cam_pts, world_pts, img_pts, obj_pts, owner = [], [], [], [], []
    for _, d, it in seen:
        size = board.tags[d.id][2]
        pose = estimate_pose(d, size, it)
        # the corners and a point one tag size above the tag's centre: the board is flat, so
        # only the tags' normals tell a mirrored fit from a proper one
        local = np.vstack([corner_points(size), [0.0, 0.0, size]])
        cam_pts.append(apply(pose.T_cam_tag, local))
        world_pts.append(apply(board.pose(d.id), local))
        img_pts.append(d.corners)
        obj_pts.append(board.corners(d.id))
        owner += [d.id] * 4
    cam_pts, world_pts = np.concatenate(cam_pts), np.concatenate(world_pts)
    s, R, t, reflected = _umeyama(cam_pts, world_pts)
    if reflected:
        raise CalibrationError("the board fits the camera's view only mirrored: is the board "
                               "layout entered left-right or upside down?")
    if abs(s - 1.0) > max_scale_error:
        raise CalibrationError(f"the board fits the camera's view only scaled by {s:.3f}: a "
                               f"tag size or the board's print scale is wrong")
    T0 = invert(transform(R, t))  # cam <- world, the start of the joint fit
    rvec, _ = cv2.Rodrigues(T0[:3, :3])
    obj = np.concatenate(obj_pts).reshape(-1, 1, 3)
    img = np.concatenate(img_pts).reshape(-1, 1, 2)
    ok, rvec, tvec = cv2.solvePnP(obj, img, intr.matrix, intr.distortion, rvec.copy(),
                                  T0[:3, 3].copy(), useExtrinsicGuess=True,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CalibrationError("the joint pose fit did not converge")
    Rc, _ = cv2.Rodrigues(rvec)
    T_world_cam = invert(transform(Rc, tvec.reshape(3)))
    return _checked(T_world_cam, seen, board, obj, img, owner, s, len(frames), max_rms_px,
                    max_residual_mm)


def _checked(T_world_cam, seen, board, obj, img, owner, scale, n_frames, max_rms_px,
             max_residual_mm) -> CameraCalibration:
    intr = seen[0][2]
    T = invert(T_world_cam)
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    proj, _ = cv2.projectPoints(obj, rvec, T[:3, 3], intr.matrix, intr.distortion)
    err = np.linalg.norm(proj.reshape(-1, 2) - img.reshape(-1, 2), axis=1)
    owner = np.asarray(owner)
    res_px, res_mm, mm_lists = {}, {}, {}
    for i in sorted(set(owner.tolist())):
        res_px[i] = float(np.sqrt(np.mean(err[owner == i] ** 2)))
    for _, d, it in seen:
        pose = estimate_pose(d, board.tags[d.id][2], it)
        centre = apply(T_world_cam, pose.T_cam_tag[:3, 3])
        mm_lists.setdefault(d.id, []).append(
            1000.0 * float(np.linalg.norm(centre - board.pose(d.id)[:3, 3])))
    res_mm = {i: float(np.median(v)) for i, v in mm_lists.items()}
    rms = float(np.sqrt(np.mean(err ** 2)))
    cal = CameraCalibration(T_world_cam, rms, res_px, res_mm, scale, n_frames)
    if rms > max_rms_px:
        raise CalibrationError(f"RMS reprojection error {rms:.2f} px over {max_rms_px} px "
                               f"(tags: " + ", ".join(f"{i} {v:.1f} px"
                                                      for i, v in res_px.items()) + ")")
    worst = max(res_mm, key=res_mm.get)
    if res_mm[worst] > max_residual_mm:
        raise CalibrationError(f"tag {worst} is {res_mm[worst]:.1f} mm from its place on the "
                               f"board (at most {max_residual_mm} mm): moved, or its place "
                               f"is wrong")
    return cal


# -- intrinsics -----------------------------------------------------------------------------

def intrinsics_from_chessboard(images, pattern=(9, 6), square: float = 0.025,
                               min_views: int = 5) -> tuple[Intrinsics, float]:
    """(intrinsics, RMS reprojection error px) from views of a chessboard with ``pattern``
    inner corners (columns, rows) of ``square`` m: ``cv2.calibrateCamera`` with k1, k2, p1,
    p2, k3. ``images``: RGB or gray uint8 arrays of one size; views where the board is not
    found are skipped; fewer than ``min_views`` found: `CalibrationError`."""
    cols, rows = pattern
    grid = np.zeros((cols * rows, 3), np.float32)
    grid[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * float(square)
    obj, img, size = [], [], None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    for im in images:
        gray = im if im.ndim == 2 else cv2.cvtColor(im, cv2.COLOR_RGB2GRAY)
        if size is not None and gray.shape[::-1] != size:
            raise CalibrationError(f"chessboard views differ in size: {gray.shape[::-1]} "
                                   f"and {size}")
        size = gray.shape[::-1]
        found, corners = cv2.findChessboardCorners(gray, (cols, rows))
        if not found:
            continue
        corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), crit)
        obj.append(grid)
        img.append(corners)
    if len(obj) < min_views:
        raise CalibrationError(f"the chessboard was found in {len(obj)} view(s); at least "
                               f"{min_views} are needed")
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, size, None, None)
    return Intrinsics.from_matrix(size[0], size[1], K, np.asarray(dist).reshape(-1)), float(rms)


def board_view_pose(distance: float = 1.0, elevation_deg: float = 55.0,
                    azimuth_deg: float = 0.0, centre=(0.40, 0.0, TABLE_Z)) -> np.ndarray:
    """``T_world_cam`` of a camera ``distance`` m from ``centre``, looking at it from
    ``elevation_deg`` above the table, ``azimuth_deg`` about the vertical from the front
    (+x)."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    c = np.asarray(centre, float)
    p = c + distance * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az),
                                 math.sin(el)])
    return look_at(p, c)


def synthetic_detections(board: BoardLayout, T_world_cam, intrinsics: Intrinsics,
                         noise_px: float = 0.0, rng=None) -> list[TagDetection]:
    """The detections a camera at ``T_world_cam`` would make of ``board`` (its corners
    projected, with Gaussian pixel noise): for tests and for planning a board."""
    rng = np.random.default_rng(0) if rng is None else rng
    out = []
    for i in sorted(board.tags):
        px = project(board.corners(i), T_world_cam, intrinsics)
        out.append(TagDetection(i, px + noise_px * rng.standard_normal(px.shape)))
    return out
