"""A UVC camera or a video file through ``cv2.VideoCapture`` (``kind = "opencv"``): RGB only,
no depth (the tag paths work with it; the colour path needs depth).

Intrinsics: given (a chessboard calibration,
`daddpg_jax.deploy.camera.calibration.intrinsics_from_chessboard`, or the limits file's
``fx``... keys), else a nominal pinhole of ``fovy_deg`` on the delivered image size (good
enough to detect, not to measure: calibrate a real camera). The stamp of a frame is the
monotonic clock when ``read`` returned (a UVC driver's own timestamps are not portable).
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from daddpg_jax.deploy.camera.frames import CameraError, Frame, Intrinsics


class OpenCVCamera:
    """``source``: a device index (int or a string of digits) or a video file's path;
    ``width``/``height``: the size asked of a device (a file keeps its own); ``loop``: a file
    starts again at its end instead of raising `CameraError`."""

    def __init__(self, source=0, intrinsics: Intrinsics | None = None, width: int | None = None,
                 height: int | None = None, fovy_deg: float = 45.0, loop: bool = False,
                 clock=time.monotonic):
        src = int(source) if isinstance(source, str) and source.isdigit() else source
        self.source, self.loop, self.clock = src, bool(loop), clock
        self.cap = cv2.VideoCapture(src)
        if not self.cap.isOpened():
            raise CameraError(f"cannot open camera or video {source!r}")
        if isinstance(src, int):
            if width:
                self.cap.set(cv2.CAP_PROP_FRAME_WIDTH, int(width))
            if height:
                self.cap.set(cv2.CAP_PROP_FRAME_HEIGHT, int(height))
        w = int(self.cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        h = int(self.cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        self.intrinsics = intrinsics if intrinsics is not None else \
            Intrinsics.from_fovy(w, h, fovy_deg)
        self.index = 0

    def capture(self) -> Frame:
        ok, bgr = self.cap.read()
        if not ok and self.loop and not isinstance(self.source, int):
            self.cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, bgr = self.cap.read()
        if not ok or bgr is None:
            raise CameraError(f"no frame from {self.source!r} (end of the file, or the device "
                              f"stopped)")
        stamp = self.clock()
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB) if bgr.ndim == 3 else \
            cv2.cvtColor(bgr, cv2.COLOR_GRAY2RGB)
        it = self.intrinsics
        if rgb.shape[:2] != (it.height, it.width):
            raise CameraError(f"frame of {rgb.shape[1]}x{rgb.shape[0]} from {self.source!r}, "
                              f"intrinsics for {it.width}x{it.height}")
        frame = Frame(rgb=np.ascontiguousarray(rgb), stamp=stamp, intrinsics=it, depth=None,
                      index=self.index)
        self.index += 1
        return frame

    def close(self) -> None:
        self.cap.release()
