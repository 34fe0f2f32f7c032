"""A run of the robot client recorded for the Rerun viewer (``daddpg-robot-client --rerun
FILE.rrd``; ``rerun-sdk``, the optional extra ``[rerun]``, imported when a recording starts).

`RecordingEnv` wraps the loop's env (`daddpg_jax.deploy.arms.ArmsEnv`) and logs, on the
timelines ``step`` (control periods over the whole run) and ``episode``:

- ``world/camera``: the camera's calibrated pose and pinhole; ``world/camera/image``: its
  frame (JPEG) with the tags it detects outlined (id, axes) and the estimated targets and
  object points as crosses (`daddpg_jax.deploy.camera.tags.draw_tags`);
- ``world/goal/seen`` (what the policy is given) and ``world/goal/true`` (the drawn goal;
  simulation); ``world/object/camera`` and ``world/object/truth``: the object points from
  the camera and the simulator's (simulation);
- ``world/target``: the commanded targets; ``world/grip``: the tool centres read;
  ``world/limits/left`` / ``right``: the workspace boxes (static);
- ``safety``: a line per held or changed command (missed deadline, stale reading,
  perception hold, speed cap, box, clearance, fingers); ``timing/step_ms``,
  ``timing/rtt_ms``: per control period, from each episode's log (`episode_log`).

Without ``--rerun`` nothing here runs. Open a recording with ``rerun FILE.rrd``.
"""

from __future__ import annotations

import numpy as np

APP_ID = "daddpg-robot-client"


class RecorderError(RuntimeError):
    """Rerun is missing or the recording cannot be written (one line)."""


def _rerun():
    try:  # lazy: the optional extra [rerun]; the loop runs without it
        import rerun as rr
    except ImportError:
        raise RecorderError("--rerun needs rerun-sdk: pip install 'daddpg-jax[rerun]'") from None
    return rr


class RecordingEnv:
    """The loop's env ``env``, every reset and step logged into ``path`` (.rrd); ``safety``:
    the `SafetyLimits` in force (its boxes); ``perception``: the run's
    `daddpg_jax.deploy.perception.Perception` or None (no camera: no images)."""

    def __init__(self, env, path: str, safety=None, perception=None):
        rr = self.rr = _rerun()
        self.env, self.perception = env, perception
        self.rec = rr.RecordingStream(APP_ID)
        try:
            self.rec.save(str(path))
        except Exception as e:  # noqa: BLE001 - the SDK's errors, one line
            raise RecorderError(f"--rerun {path!r}: {' '.join(str(e).split())[:200]}") from None
        self.step, self.episode, self.bases = 0, -1, {}
        self._detector = None
        if safety is not None:
            lo, hi = np.asarray(safety.workspace_low), np.asarray(safety.workspace_high)
            for i, name in enumerate(("left", "right")):
                self.rec.log(f"world/limits/{name}", rr.Boxes3D(mins=[lo[i]], sizes=[hi[i] - lo[i]],
                                                                 colors=[(255, 200, 0)]),
                             static=True)

    def __getattr__(self, name):
        return getattr(self.env, name)

    def _time(self):
        self.rec.set_time("step", sequence=self.step)
        self.rec.set_time("episode", sequence=max(self.episode, 0))

    # -- the env API ----------------------------------------------------------------------------

    def reset(self, *args, **kw):
        res = self.env.reset(*args, **kw)
        self.episode += 1
        self.bases[self.episode] = self.step
        self._time()
        rr = self.rr
        self.rec.log("world/goal/seen", rr.Points3D(res.desired_goal, colors=[(0, 160, 255)],
                                                    radii=0.01))
        if getattr(self.env, "truth", None) is not None and hasattr(self.env, "goal"):
            self.rec.log("world/goal/true", rr.Points3D(self.env.goal, colors=[(0, 200, 0)],
                                                        radii=0.006))
        self._log_state(res)
        return res

    def step_targets(self, target, ctrl):
        self.step += 1
        self._time()
        self.rec.log("world/target", self.rr.Points3D(np.asarray(target, float).reshape(2, 3),
                                                      colors=[(255, 0, 255)], radii=0.008))
        res = self.env.step_targets(target, ctrl)
        self._log_state(res)
        return res

    def close(self):
        try:
            self.env.close()
        finally:
            self.rec.flush()
            self.rec.disconnect()

    # -- what is logged -------------------------------------------------------------------------

    def _log_state(self, res) -> None:
        rr = self.rr
        self.rec.log("world/grip", rr.Points3D(np.asarray(res.observation)[:, :3],
                                               colors=[(220, 220, 220)], radii=0.01))
        fault = getattr(res, "perception_fault", None)
        if fault:
            self.rec.log("safety", rr.TextLog(f"perception hold: {fault}", level="WARN"))
        reading = getattr(getattr(self.env, "objects", None), "last", None)
        points = []
        if isinstance(reading, dict) and np.isfinite(reading.get("age", np.inf)):
            points = np.asarray(reading["object_point"], float)
            self.rec.log("world/object/camera", rr.Points3D(points, colors=[(255, 80, 0)],
                                                            radii=0.008))
        truth = getattr(self.env, "truth", None)
        if truth is not None and getattr(self.env.spec.rules, "has_object", False):
            self.rec.log("world/object/truth", rr.Points3D(truth()[1]["object_point"],
                                                           colors=[(0, 200, 0)], radii=0.005))
        self._log_image(res, points)

    def _frame(self):
        """This period's frame: the object source's, else one taken for the record (the
        simulated camera renders the present without its noise, so that recording leaves
        its random stream, and the run, as they are)."""
        p = self.perception
        if p is None or p.camera is None:
            return None
        src = getattr(p.object_source, "source", None)
        frame = getattr(src, "last_frame", None)
        if frame is not None:
            return frame
        cam = p.camera
        if hasattr(cam, "sync") and hasattr(cam, "render"):
            # lazy: the camera package, only when a run is recorded with a camera
            from daddpg_jax.deploy.camera.frames import Frame

            stamp = cam.sync()
            rgb, depth = cam.render()
            return Frame(rgb=rgb, stamp=stamp, intrinsics=cam.intrinsics, depth=depth)
        return cam.capture()

    def _log_image(self, res, object_points) -> None:
        frame = self._frame()
        if frame is None:
            return
        # lazy: OpenCV, only when a run is recorded with a camera
        from daddpg_jax.deploy.camera.tags import TagDetector

        rr, T = self.rr, self.perception.config.T_world_cam
        self._detector = self._detector or TagDetector()
        img = annotate(frame, T, [res.desired_goal, object_points], self._detector)
        it = frame.intrinsics
        self.rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        self.rec.log("world/camera", rr.Pinhole(image_from_camera=it.matrix,
                                                resolution=[it.width, it.height],
                                                camera_xyz=rr.ViewCoordinates.RDF))
        self.rec.log("world/camera/image", rr.Image(img).compress(jpeg_quality=85))

    def episode_log(self, log: dict) -> None:
        """Each control period of an episode's log (`run_episode`'s ``log``): the safety
        decisions and the times, on the ``step`` timeline."""
        rr, base = self.rr, self.bases.get(log.get("episode", self.episode), self.step)
        for k, st in enumerate(log.get("steps", ())):
            self.rec.set_time("step", sequence=base + k + 1)
            if st.get("step_ms") is not None:
                self.rec.log("timing/step_ms", rr.Scalars(float(st["step_ms"])))
            self.rec.log("timing/rtt_ms", rr.Scalars(float(st.get("rtt_ms", 0.0))))
            if st.get("missed") or st.get("reasons"):
                why = st.get("missed") or ", ".join(st["reasons"])
                level = "WARN" if st.get("stopped") else "INFO"
                self.rec.log("safety", rr.TextLog(f"{'hold' if st.get('stopped') else 'changed'}"
                                                  f": {why}", level=level))
        summary = log.get("summary") or {}
        self.rec.set_time("step", sequence=self.step)
        self.rec.log("episodes", rr.TextLog(
            f"episode {log.get('episode', 0) + 1}: "
            f"{'success' if summary.get('success') else 'failure'}, "
            f"{summary.get('stops', 0)} missed deadline(s), {summary.get('perception', 0)} "
            f"perception hold(s)"))


def annotate(frame, T_world_cam, points=(), detector=None) -> np.ndarray:
    """``frame``'s image with the tags it shows outlined (id, axes; poses at the calibrated
    ``T_world_cam``) and ``points`` (world, arrays of [.., 3]: targets, object points) as
    crosses."""
    # lazy: OpenCV, only for a recording or a picture
    from daddpg_jax.deploy.camera.tags import TagDetector, draw_tags, tag_poses

    poses = tag_poses(frame, detector or TagDetector(), T_world_cam)
    pts = [np.asarray(p, float).reshape(-1, 3) for p in points if np.size(p)]
    pts = np.concatenate(pts) if pts else np.zeros((0, 3))
    return draw_tags(frame.rgb, poses, frame.intrinsics, T_world_cam, pts)


def recorded(env, path: str | None, safety=None, perception=None):
    """``env`` wrapped in a `RecordingEnv` writing ``path``; ``env`` itself when ``path`` is
    None (nothing is recorded, nothing is imported)."""
    return env if not path else RecordingEnv(env, path, safety, perception)
