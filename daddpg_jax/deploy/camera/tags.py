"""AprilTags (family tag36h11) on the robot side (NumPy + OpenCV): what the shipped tags are,
their detection, each tag's pose by PnP (IPPE for squares) in the camera and the world frame,
and each arm's Reach target from the tags.

    detector = TagDetector()
    poses = tag_poses(frame, detector, T_world_cam)         # {id: TagPose} in the world frame
    found = targets_from_tags(poses, PER_ARM_LAYOUT)        # TagTargets: targets [2, 3], found

A tag's ``size`` is the side of its black square (8 cells of the 10 that the printed tag with
its white margin spans), in metres. The tag frame has its origin at the square's centre, x to
the right and y up as the tag is printed, and z out of the printed face (OpenCV's ArUco
convention); the corners are listed top-left, top-right, bottom-right, bottom-left.

Targets (`TargetLayout`): each arm's target is a tag's centre plus an offset in the world
frame. `PER_ARM_LAYOUT` (one tag per arm: the Reach goals of the two arms are independent,
each target 3 cm above its tag, on a stand where it is higher than the table) and
`PAPER_LAYOUT` (one tag, the two targets 10 cm above it, 15 cm to the left and to the right:
the paper gives no lateral distance; 15 cm is half the spacing of the arms' home targets).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from daddpg_jax.deploy.camera.frames import Frame, Intrinsics, apply, invert, transform

FAMILY = "tag36h11"
CELLS = 8
"""cells across the black square (1 border cell, 6 data cells, 1 border cell)"""
MARGIN_CELLS = 1
"""white cells around the black square on a printed or simulated tag"""

SHIPPED_TAGS = {
    0: (0.08, "reach, the paper's one-tag layout (targets 10 cm above, 15 cm to each side)"),
    1: (0.05, "reach, the left arm's target (3 cm above the tag)"),
    2: (0.05, "reach, the right arm's target (3 cm above the tag)"),
    10: (0.08, "calibration board"),
    11: (0.08, "calibration board"),
    12: (0.08, "calibration board"),
    13: (0.08, "calibration board"),
    14: (0.08, "calibration board"),
    15: (0.08, "calibration board"),
    20: (0.064, "the bar (push, pick up): centred on the middle's top face"),
    21: (0.04, "the pot: on the lid, in front of the knob"),
}
"""id -> (size of the black square, m; what it marks): the tags of assets/tags/"""


def dictionary():
    """OpenCV's tag36h11 dictionary."""
    return cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)


def tag_cells(tag_id: int) -> np.ndarray:
    """[8, 8] bool, True where the tag's cell is black (row 0 at the top as printed)."""
    img = cv2.aruco.generateImageMarker(dictionary(), int(tag_id), CELLS, borderBits=1)
    return np.asarray(img) < 128


def tag_image(tag_id: int, cell_px: int = 40, margin_cells: int = MARGIN_CELLS) -> np.ndarray:
    """The printable tag: uint8 gray, ``cell_px`` pixels per cell, with its white margin."""
    cells = tag_cells(tag_id)
    img = np.where(cells, 0, 255).astype(np.uint8)
    img = np.pad(img, margin_cells, constant_values=255)
    return np.kron(img, np.ones((cell_px, cell_px), np.uint8))


def corner_points(size: float) -> np.ndarray:
    """The black square's corners [4, 3] in the tag frame (TL, TR, BR, BL)."""
    h = size / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def refine_edges(gray, corners, reach: float = 2.5, step: float = 0.5) -> np.ndarray:
    """Corners [4, 2] (TL, TR, BR, BL) refined to a fraction of a pixel: along each side of
    the black square, the dark-to-light edge is found across the side (the gradient-weighted
    mean of the intensity's rise within ``reach`` px, sampled every ``step`` px), a line is
    fitted to those edge points and neighbouring lines are intersected. Corners that would
    move more than 3 px, or a side shorter than 4 px, are left as given."""
    img = gray.astype(np.float32)
    c = np.asarray(corners, float).reshape(4, 2)
    centre = c.mean(0)
    lines = []
    offs = np.arange(-reach, reach + 1e-9, step)
    for i in range(4):
        a, b = c[i], c[(i + 1) % 4]
        d = b - a
        length = float(np.linalg.norm(d))
        if length < 4:
            return c
        d /= length
        n = np.array([d[1], -d[0]])
        if n @ (0.5 * (a + b) - centre) < 0:
            n = -n
        ts = np.linspace(0.12, 0.88, max(4, int(length * 0.76)))
        base = a[None, :] + np.outer(ts * length, d)                      # [K, 2]
        pts = base[:, None, :] + offs[None, :, None] * n[None, None, :]    # [K, M, 2]
        vals = cv2.remap(img, pts[..., 0].astype(np.float32), pts[..., 1].astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        grad = np.diff(vals, axis=1)  # the rise from the dark inside to the light outside
        grad = np.clip(grad, 0, None)
        w = grad.sum(1)
        ok = w > 1e-3 * max(w.max(), 1e-9)
        mids = 0.5 * (offs[1:] + offs[:-1])
        s = (grad * mids[None, :]).sum(1) / np.maximum(w, 1e-9)
        p = base + s[:, None] * n[None, :]
        p, wk = p[ok], w[ok]
        if len(p) < 3:
            return c
        mu = (p * wk[:, None]).sum(0) / wk.sum()
        q = (p - mu) * np.sqrt(wk)[:, None]
        _, _, vt = np.linalg.svd(q, full_matrices=False)
        dirn = vt[0]
        lines.append((mu, dirn))
    out = np.empty((4, 2))
    for i in range(4):
        (p1, d1), (p2, d2) = lines[i - 1], lines[i]
        A = np.array([d1, -d2]).T
        if abs(np.linalg.det(A)) < 1e-6:
            return c
        t = np.linalg.solve(A, p2 - p1)
        out[i] = p1 + t[0] * d1
    if np.max(np.linalg.norm(out - c, axis=1)) > 3.0:
        return c
    return out


# -- detection ----------------------------------------------------------------------------------

@dataclass
class TagDetection:
    """One detected tag: its id and its corners [4, 2] in pixels (TL, TR, BR, BL)."""

    id: int
    corners: np.ndarray


class TagDetector:
    """tag36h11 detection with OpenCV's ArUco module (``backend="aruco"``) or with
    ``pupil_apriltags`` (``backend="apriltag"``, optional, imported when asked for), the
    corners then refined by `refine_edges` (``refine=True``). On noiseless and noisy renders
    of the simulated cell the refined ArUco corners were 0.1 px from the true ones (median;
    p95 0.2 px), ArUco's own sub-pixel refinement 0.24 px (p95 0.8 px)."""

    def __init__(self, backend: str = "aruco", refine: bool = True):
        if backend not in ("aruco", "apriltag"):
            raise ValueError(f"backend must be 'aruco' or 'apriltag', got {backend!r}")
        self.backend, self.refine = backend, bool(refine)
        if backend == "aruco":
            params = cv2.aruco.DetectorParameters()
            params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
            self._det = cv2.aruco.ArucoDetector(dictionary(), params)
        else:
            # lazy: an optional alternative backend (pip install pupil-apriltags)
            import pupil_apriltags

            self._det = pupil_apriltags.Detector(families=FAMILY, quad_decimate=1.0,
                                                 refine_edges=True)

    def detect(self, gray: np.ndarray) -> list[TagDetection]:
        """The tags in an 8-bit gray image, sorted by id (a repeated id: each occurrence)."""
        gray = np.ascontiguousarray(gray)
        out = []
        if self.backend == "aruco":
            corners, ids, _ = self._det.detectMarkers(gray)
            for c, i in zip(corners, [] if ids is None else ids.reshape(-1)):
                out.append(TagDetection(int(i), np.asarray(c, float).reshape(4, 2)))
        else:
            for d in self._det.detect(gray):
                # pupil_apriltags: its corner order and pixel origin (a pixel's corner, not its
                # centre) -> TL, TR, BR, BL in OpenCV's pixel coordinates
                c = np.asarray(d.corners, float).reshape(4, 2)[[1, 0, 3, 2]] - 0.5
                out.append(TagDetection(int(d.tag_id), c))
        if self.refine:
            for d in out:
                d.corners = refine_edges(gray, d.corners)
        return sorted(out, key=lambda d: d.id)


# -- pose ---------------------------------------------------------------------------------------

@dataclass
class TagPose:
    """A tag's pose: ``T_cam_tag`` (4x4, m), its RMS reprojection error (px), the ratio of
    the two IPPE solutions' errors (``ambiguity``: near 1, the tag's tilt is uncertain), its
    detected corners and, once known, ``T_world_tag``."""

    id: int
    size: float
    T_cam_tag: np.ndarray
    error_px: float
    ambiguity: float
    corners: np.ndarray
    T_world_tag: np.ndarray | None = None

    @property
    def position(self) -> np.ndarray:
        """The tag's centre in the world frame (or the camera's, before `to_world`)."""
        T = self.T_cam_tag if self.T_world_tag is None else self.T_world_tag
        return T[:3, 3].copy()

    @property
    def rotation(self) -> np.ndarray:
        T = self.T_cam_tag if self.T_world_tag is None else self.T_world_tag
        return T[:3, :3].copy()

    def to_world(self, T_world_cam) -> TagPose:
        self.T_world_tag = np.asarray(T_world_cam, float) @ self.T_cam_tag
        return self


def _rt(rvec, tvec) -> np.ndarray:
    R, _ = cv2.Rodrigues(np.asarray(rvec, float).reshape(3))
    return transform(R, np.asarray(tvec, float).reshape(3))


def estimate_pose(det: TagDetection, size: float, intrinsics: Intrinsics,
                  normal_cam=None, tie: float = 2.0) -> TagPose:
    """The pose of a detected tag of black-square side ``size`` (m) by IPPE for squares.

    IPPE gives two poses that mirror the tag's tilt; the one with the smaller reprojection
    error is taken, unless ``normal_cam`` (the expected direction of the tag's z axis in the
    camera frame, e.g. the world's up for a tag lying flat) is given and the other one's error
    is within ``tie`` times it and its z axis is closer to ``normal_cam``."""
    obj = corner_points(size)
    img = np.asarray(det.corners, float).reshape(4, 1, 2)
    n, rvecs, tvecs, errs = cv2.solvePnPGeneric(
        obj, img, intrinsics.matrix, intrinsics.distortion, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    errs = np.asarray(errs, float).reshape(-1)
    cands = [_rt(rvecs[k], tvecs[k]) for k in range(int(n))]
    order = np.argsort(errs)
    best = int(order[0])
    ambiguity = float(errs[order[1]] / max(errs[best], 1e-9)) if n > 1 else math.inf
    if normal_cam is not None and n > 1:
        other = int(order[1])
        nz = np.asarray(normal_cam, float) / np.linalg.norm(normal_cam)
        if (errs[other] <= tie * max(errs[best], 0.05)
                and cands[other][:3, 2] @ nz > cands[best][:3, 2] @ nz):
            best = other
    return TagPose(det.id, float(size), cands[best], float(errs[best]), ambiguity,
                   np.asarray(det.corners, float).reshape(4, 2))


def tag_poses(frame: Frame, detector: TagDetector, T_world_cam, sizes=None,
              detections=None, up=(0.0, 0.0, 1.0)) -> dict[int, TagPose]:
    """{id: `TagPose`} (with ``T_world_tag``) of the tags found in ``frame`` whose size is
    known (``sizes``: id -> m; default the shipped tags'); the tags are expected to face
    roughly ``up`` (world) when IPPE's two solutions are alike. A tag seen twice is left out
    (its id is ambiguous)."""
    sizes = {i: s for i, (s, _) in SHIPPED_TAGS.items()} if sizes is None else sizes
    dets = detector.detect(frame.gray) if detections is None else detections
    T_world_cam = np.asarray(T_world_cam, float)
    normal_cam = T_world_cam[:3, :3].T @ np.asarray(up, float)
    ids = [d.id for d in dets]
    out = {}
    for d in dets:
        if d.id in sizes and ids.count(d.id) == 1:
            out[d.id] = estimate_pose(d, sizes[d.id], frame.intrinsics, normal_cam).to_world(
                T_world_cam)
    return out


def project(points_world, T_world_cam, intrinsics: Intrinsics) -> np.ndarray:
    """World points [N, 3] -> pixels [N, 2] (with the lens distortion)."""
    T = invert(T_world_cam)
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    px, _ = cv2.projectPoints(np.asarray(points_world, float).reshape(-1, 1, 3), rvec,
                              T[:3, 3], intrinsics.matrix, intrinsics.distortion)
    return px.reshape(-1, 2)


# -- targets ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class TargetLayout:
    """Where each arm's target is: arm i's target = the centre of tag ``tags[i]`` +
    ``offsets[i]`` (world frame, m). The same id twice: the one-tag layout."""

    tags: tuple
    offsets: tuple

    def tag_centres(self, targets) -> dict[int, np.ndarray]:
        """The tag centres that put the targets [2, 3] where they are (the one-tag layout:
        the mean of the two)."""
        t = np.asarray(targets, float).reshape(2, 3) - np.asarray(self.offsets, float)
        out: dict[int, list] = {}
        for i, tag in enumerate(self.tags):
            out.setdefault(int(tag), []).append(t[i])
        return {k: np.mean(v, axis=0) for k, v in out.items()}


PER_ARM_LAYOUT = TargetLayout(tags=(1, 2), offsets=((0.0, 0.0, 0.03), (0.0, 0.0, 0.03)))
PAPER_LAYOUT = TargetLayout(tags=(0, 0), offsets=((0.0, 0.15, 0.10), (0.0, -0.15, 0.10)))


@dataclass
class TagTargets:
    """Each arm's target [2, 3] (world, m; NaN where its tag was not found), which were found
    [2], and the tag poses they came from."""

    targets: np.ndarray
    found: np.ndarray
    poses: dict

    @property
    def complete(self) -> bool:
        return bool(np.all(self.found))


def targets_from_tags(poses: dict, layout: TargetLayout = PER_ARM_LAYOUT) -> TagTargets:
    """Each arm's target from world-frame tag poses (`tag_poses`)."""
    targets = np.full((2, 3), np.nan)
    found = np.zeros(2, bool)
    for i, (tag, off) in enumerate(zip(layout.tags, layout.offsets)):
        if tag in poses:
            targets[i] = poses[tag].position + np.asarray(off, float)
            found[i] = True
    return TagTargets(targets, found, {k: poses[k] for k in set(layout.tags) if k in poses})


def targets_from_camera(camera, T_world_cam, layout: TargetLayout = PER_ARM_LAYOUT,
                        detector: TagDetector | None = None, frames: int = 5,
                        sizes=None) -> TagTargets:
    """The targets from ``frames`` captures of ``camera``: per arm the median over the frames
    that found its tag (the targets stand still while they are read)."""
    detector = TagDetector() if detector is None else detector
    seen: list[list] = [[], []]
    last: dict = {}
    for _ in range(max(1, int(frames))):
        got = targets_from_tags(tag_poses(camera.capture(), detector, T_world_cam, sizes),
                                layout)
        last.update(got.poses)
        for i in range(2):
            if got.found[i]:
                seen[i].append(got.targets[i])
    targets = np.full((2, 3), np.nan)
    for i in range(2):
        if seen[i]:
            targets[i] = np.median(np.asarray(seen[i]), axis=0)
    return TagTargets(targets, np.array([bool(s) for s in seen]), last)


def draw_tags(rgb: np.ndarray, poses: dict, intrinsics: Intrinsics, T_world_cam=None,
              points=None) -> np.ndarray:
    """A copy of ``rgb`` with each tag's outline, id and axes drawn, and ``points`` (world
    [N, 3]) as crosses."""
    img = np.ascontiguousarray(rgb.copy())
    for p in poses.values():
        c = np.round(p.corners).astype(np.int32)
        cv2.polylines(img, [c.reshape(-1, 1, 2)], True, (0, 255, 0), 1, cv2.LINE_AA)
        cv2.putText(img, str(p.id), tuple(int(v) for v in c[0]), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                    (255, 255, 0), 1, cv2.LINE_AA)
        rvec, _ = cv2.Rodrigues(p.T_cam_tag[:3, :3])
        cv2.drawFrameAxes(img, intrinsics.matrix, intrinsics.distortion, rvec,
                          p.T_cam_tag[:3, 3], p.size * 0.5, 1)
    if points is not None and T_world_cam is not None and len(points):
        for u, v in project(np.asarray(points, float).reshape(-1, 3), T_world_cam, intrinsics):
            if np.isfinite(u) and np.isfinite(v):
                cv2.drawMarker(img, (int(round(u)), int(round(v))), (255, 0, 255),
                               cv2.MARKER_CROSS, 10, 1)
    return img


def world_corners(T_world_tag, size: float) -> np.ndarray:
    """A tag's corners [4, 3] in the world frame."""
    return apply(T_world_tag, corner_points(size))
