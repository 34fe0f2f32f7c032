"""`make_camera`: the camera of a `CameraConfig` (``sim``, ``opencv``, ``realsense``); each
kind's module is imported only when it is asked for (MuJoCo for ``sim``, ``pyrealsense2`` for
``realsense``)."""

from __future__ import annotations

from daddpg_jax.deploy.camera.config import CameraConfig, CameraConfigError


def make_camera(config: CameraConfig, env=None, seed: int = 0, sensor=None):
    """The camera of ``config``: ``sim`` renders ``env`` (a `NumpyDualArmEnv`, e.g. a
    simulated cell's) with ``sensor`` (default `sim_camera.SensorModel()`) and its own random
    stream ``seed``; ``opencv`` opens ``config.device``; ``realsense`` the device of serial
    ``config.device`` ("0" or "": the first one)."""
    if config.kind == "sim":
        if env is None:
            raise CameraConfigError("the sim camera needs the simulated cell's env")
        # lazy: MuJoCo and its renderer load only for the simulated camera
        from daddpg_jax.deploy.camera.sim_camera import SensorModel, SimCamera

        return SimCamera(env, config, SensorModel() if sensor is None else sensor, seed)
    if config.kind == "opencv":
        # lazy: the camera modules load only for the kind asked for
        from daddpg_jax.deploy.camera.opencv_camera import OpenCVCamera

        return OpenCVCamera(config.device, config.intrinsics, config.width, config.height,
                            config.fovy_deg)
    # lazy: pyrealsense2 is imported by the RealSense camera itself
    from daddpg_jax.deploy.camera.realsense_camera import RealSenseCamera

    serial = "" if config.device in ("", "0") else config.device
    return RealSenseCamera(config.width, config.height, serial=serial)
