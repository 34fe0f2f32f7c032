"""An Intel RealSense (``kind = "realsense"``) through ``pyrealsense2`` (the optional extra
``[realsense]``, imported when the camera is opened): RGB and depth, the depth aligned to the
colour image (``rs.align``), in metres (the device's depth scale), the colour stream's
intrinsics and distortion from the device.

Not run on real hardware here: tests/test_camera.py runs it against a fake module with the
same API (the calls below are all it uses). The capture time: the frame's timestamp when the
device reports it on the system clock (``global_time`` / ``system_time`` domains), mapped onto
the monotonic clock, else the monotonic clock when the frame arrived.
"""

from __future__ import annotations

import time

import numpy as np

from daddpg_jax.deploy.camera.frames import CameraError, Frame, Intrinsics


def _module():
    try:
        # lazy: pyrealsense2 is an optional extra (pip install -e ".[realsense]")
        import pyrealsense2 as rs
    except ImportError:
        raise CameraError("the realsense camera needs pyrealsense2 "
                          "(pip install -e \".[realsense]\")") from None
    return rs


class RealSenseCamera:
    """``serial``: the device's serial number ("" = the first one); ``rs``: the
    ``pyrealsense2`` module (for tests; default imported); ``timeout_ms``: the longest wait
    for a frame."""

    def __init__(self, width: int = 640, height: int = 480, fps: int = 30, serial: str = "",
                 rs=None, timeout_ms: int = 1000, clock=time.monotonic, wall=time.time):
        self.rs = _module() if rs is None else rs
        self.clock, self.wall, self.timeout_ms = clock, wall, int(timeout_ms)
        rs = self.rs
        self.pipeline = rs.pipeline()
        cfg = rs.config()
        if serial:
            cfg.enable_device(str(serial))
        cfg.enable_stream(rs.stream.color, int(width), int(height), rs.format.rgb8, int(fps))
        cfg.enable_stream(rs.stream.depth, int(width), int(height), rs.format.z16, int(fps))
        try:
            profile = self.pipeline.start(cfg)
        except RuntimeError as e:
            raise CameraError(f"cannot start the RealSense camera: {e}") from None
        self.depth_scale = float(profile.get_device().first_depth_sensor().get_depth_scale())
        colour = profile.get_stream(rs.stream.color).as_video_stream_profile()
        i = colour.get_intrinsics()
        self.intrinsics = Intrinsics(int(i.width), int(i.height), float(i.fx), float(i.fy),
                                     float(i.ppx), float(i.ppy),
                                     tuple(float(c) for c in i.coeffs))
        self.align = rs.align(rs.stream.color)
        self.index = 0

    def _stamp(self, frame) -> float:
        now = self.clock()
        rs = self.rs
        domain = frame.get_frame_timestamp_domain()
        if domain in (rs.timestamp_domain.global_time, rs.timestamp_domain.system_time):
            age = self.wall() - float(frame.get_timestamp()) / 1000.0
            if 0.0 <= age < 1.0:
                return now - age
        return now

    def capture(self) -> Frame:
        try:
            frames = self.pipeline.wait_for_frames(self.timeout_ms)
        except RuntimeError as e:
            raise CameraError(f"no frame from the RealSense camera: {e}") from None
        aligned = self.align.process(frames)
        colour, depth = aligned.get_color_frame(), aligned.get_depth_frame()
        if not colour or not depth:
            raise CameraError("the RealSense camera delivered a frame without colour or depth")
        rgb = np.asanyarray(colour.get_data()).copy()
        z = np.asanyarray(depth.get_data()).astype(np.float32) * self.depth_scale
        frame = Frame(rgb=rgb, stamp=self._stamp(colour), intrinsics=self.intrinsics, depth=z,
                      index=self.index)
        self.index += 1
        return frame

    def close(self) -> None:
        self.pipeline.stop()
