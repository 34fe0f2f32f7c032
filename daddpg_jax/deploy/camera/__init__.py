"""The robot side's camera path (NumPy + OpenCV; MuJoCo only in `sim_camera`; no JAX).

- `frames`: `Frame` (RGB, optional depth in metres, the capture time on a monotonic clock,
  the intrinsics and distortion), `Intrinsics`, the `Camera` protocol, pose helpers.
- `config`: `CameraConfig` and `camera_from_limits` (the limits file's ``[camera]`` table);
  `factory.make_camera` (``sim``, ``opencv``, ``realsense``).
- `sim_camera`: `SimCamera`, the simulated cell rendered from a camera pose, with sensor
  noise, blur, exposure, lighting and latency from its own random stream.
- `opencv_camera`: `OpenCVCamera` (``cv2.VideoCapture``: a UVC camera or a video file).
- `realsense_camera`: `RealSenseCamera` (``pyrealsense2``, depth aligned to colour).
- `tags`: tag36h11 detection, each tag's pose by IPPE, Reach targets (`targets_from_tags`,
  `targets_from_camera`; `PER_ARM_LAYOUT`, `PAPER_LAYOUT`).
- `objects`: the bar and the pot from a tag or from colour and depth, the tracking filter
  (hold or predict while hidden, the sighting's age), `CameraObjectSource`.
- `calibration`: the camera's pose from a board of tags (`calibrate_camera_pose`), the
  intrinsics from a chessboard (`intrinsics_from_chessboard`).

See docs/PERCEPTION.md.
"""
