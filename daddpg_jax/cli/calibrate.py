r"""Frame calibration: finds each arm's base pose in the policy's world frame and writes it into
the robot limits file, with the residual of each point (daddpg_jax/deploy/calibrate.py).

Examples (daddpg-calibrate = python experiments/calibrate.py)
  daddpg-calibrate --limits cell.toml --points board.json --measured touched.json
  daddpg-calibrate --limits cell.toml --points board.json --ur-hosts 192.168.1.10,192.168.1.11
  daddpg-calibrate --limits cell.toml --points board.json --arms ur-sim \
      --sim-base-error 0.02,0,0,2,0,-0.02,0,-2

--points FILE (JSON): the known world positions of the board's points, m, per arm:
{"left": [[x, y, z], ...], "right": [[x, y, z], ...]}, at least 6 each, not on one line,
spanning at least 10 cm in two directions (8 recommended, spread over the arm's workspace).
--measured FILE: the tool centre read on each point in that arm's base frame, same layout, rows
[x, y, z] or UR poses [x, y, z, rx, ry, rz] (getActualTCPPose).
--ur-hosts LEFT,RIGHT reads them from the arms (read-only RTDE): move the gripper onto each point
(freedrive) and press Enter. --arms ur-sim rehearses it on the simulated controllers, whose
bases carry --sim-base-error (per arm dx, dy, dz in m and yaw in degrees, left then right) and
whose readings --noise-mm of Gaussian noise (RMS per point).

The fit is least squares (--model yaw: a level base, turn about z + offset; full: any
rotation); each point's residual and each base are printed. The fit is refused (nothing written)
when one point contradicts the others (it is named, never dropped), the left and right readings
are swapped, the readings fit only mirrored or scaled, the RMS or largest residual exceeds the
limits file's calibration_max_rms_mm / calibration_max_residual_mm (default 3 / 6 mm), a base
lands on the other arm's nominal base, or (unless --allow-far-base) a base lies more than
calibration_max_base_offset_m / calibration_max_base_angle_deg (default 0.05 m / 10 deg) from
its nominal pose. The limits file gets a [calibration.left] / [calibration.right] block
(replaced on each run); --print-only leaves it unchanged. Exit codes: 0 done; 2 bad arguments,
files or points, or a refused fit; 4 the arms cannot be reached.

--camera [KIND] calibrates the camera instead (sim, opencv, realsense; default the limits
file's [camera] kind, else sim): its pose in the world frame from --frames frames of the tag
board lying on the table at its known places (six 8 cm tags, ids 10-15; assets/tags/README.md),
a least-squares fit over every corner, each tag's residual printed (px and mm). Refused
(nothing written): fewer than 3 board tags seen, a fit only mirrored (the board entered
left-right) or scaled (tags printed at the wrong scale), an RMS reprojection error over 2 px,
a tag more than 15 mm from its place (named). Intrinsics: the device's (the simulated camera's
field of view, RealSense), or from --chessboard images (cv2.calibrateCamera; --pattern,
--square), then written too. --sim-camera-error rehearses it on the simulated camera mounted
at the limits' pose moved by dx,dy,dz (m),rx,ry,rz (deg). The limits file gets a [camera]
block (replaced on each run).
  daddpg-calibrate --limits cell.toml --camera realsense --frames 10
  daddpg-calibrate --limits cell.toml --camera opencv --chessboard views/*.png --square 0.025
  daddpg-calibrate --limits sim.toml --camera sim --sim-camera-error 0.03,0,0,0,2,0
"""

from __future__ import annotations

import argparse
import sys

from daddpg_jax.deploy import calibrate, perception
from daddpg_jax.deploy.arms import ArmsError
from daddpg_jax.deploy.limits import ARM_KEYS, LimitsError, RobotLimits


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="daddpg-calibrate", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--limits", required=True, metavar="FILE",
                   help="the robot limits file (TOML or JSON) that receives the calibration")
    p.add_argument("--points", metavar="FILE",
                   help="known world points per arm (JSON; not with --camera)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--camera", nargs="?", const="", metavar="KIND",
                     help="calibrate the camera (sim, opencv, realsense; default: the limits "
                          "file's [camera] kind) from the tag board on the table")
    src.add_argument("--measured", metavar="FILE",
                     help="tool centre on each point in the arm's base frame (JSON)")
    src.add_argument("--ur-hosts", metavar="LEFT,RIGHT", help="read the points from the arms")
    src.add_argument("--arms", choices=["ur-sim"], help="rehearse on the simulated controllers")
    p.add_argument("--sim-base-error", default="0,0,0,0,0,0,0,0", metavar="8 NUMBERS",
                   help="ur-sim: each base's true error dx,dy,dz (m),yaw (deg), left then right")
    p.add_argument("--noise-mm", type=float, default=0.5,
                   help="ur-sim: RMS noise of each reading, mm")
    p.add_argument("--seed", type=int, default=0, help="ur-sim: seed of the noise")
    p.add_argument("--model", choices=calibrate.MODELS, default="yaw",
                   help="yaw: level bases (default); full: any rotation")
    p.add_argument("--allow-far-base", action="store_true",
                   help="accept a base farther from its nominal pose than the limits file's "
                        "calibration_max_base_offset_m / calibration_max_base_angle_deg")
    p.add_argument("--print-only", action="store_true", help="do not write the limits file")
    cam = p.add_argument_group("--camera")
    cam.add_argument("--frames", type=int, default=5, help="frames of the board (default 5)")
    cam.add_argument("--chessboard", nargs="+", default=(), metavar="IMAGE",
                     help="views of a chessboard for the intrinsics (cv2.calibrateCamera)")
    cam.add_argument("--pattern", default="9x6", help="the chessboard's inner corners, CxR")
    cam.add_argument("--square", type=float, default=0.025, help="its square's side, m")
    cam.add_argument("--sim-camera-error", default=None, metavar="6 NUMBERS",
                     help="sim: the true mount moved by dx,dy,dz (m),rx,ry,rz (deg)")
    return p


def _camera(args) -> int:
    """daddpg-calibrate --camera: the exit code."""
    kind = args.camera or None
    try:
        if kind not in (None, *perception.CAMERAS):
            raise perception.PerceptionError(f"--camera must be one of "
                                             f"{', '.join(perception.CAMERAS)}, got {kind!r}")
        error = perception.parse_numbers(args.sim_camera_error, 6, "--sim-camera-error")
        pattern = perception.parse_numbers(args.pattern.replace("x", ","), 2, "--pattern")
        limits = RobotLimits.load(args.limits)
        table, _, lines = perception.calibrate_camera(
            limits, kind, args.frames, error, args.chessboard,
            tuple(int(v) for v in pattern), args.square)
    except (LimitsError, ValueError) as e:  # PerceptionError, the camera's refusals
        refused = "refused: " if type(e).__name__ == "CalibrationError" else ""
        print(f"error: {refused}{e}", file=sys.stderr)
        return 2
    except RuntimeError as e:  # CameraError: no device, no frame
        print(f"error: {e}", file=sys.stderr)
        return 4
    print("\n".join(lines))
    if args.print_only:
        return 0
    try:
        calibrate.write_camera(args.limits, table, lines)
    except (LimitsError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"written into {args.limits}")
    return 0


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    if args.camera is not None:
        return _camera(args)
    if not args.points:
        print("error: --points is needed (or --camera)", file=sys.stderr)
        return 2
    try:
        limits = RobotLimits.load(args.limits)
        points = calibrate.read_points(args.points, "--points")
        if args.measured:
            measured = calibrate.read_points(args.measured, "--measured")
        elif args.arms == "ur-sim":
            measured = calibrate.measure_sim(points, args.sim_base_error, args.noise_mm,
                                             args.seed)
        else:
            hosts = args.ur_hosts.split(",")
            if len(hosts) != 2 or not all(hosts):
                raise calibrate.CalibrationError("--ur-hosts must be LEFT,RIGHT")
            measured = calibrate.measure_ur(points, hosts)
        fits = calibrate.fit_arms(points, measured, args.model)
    except (LimitsError, calibrate.CalibrationError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except ArmsError as e:
        print(f"error: {e}", file=sys.stderr)
        return 4
    print("\n".join(calibrate.report_lines(points, fits)))
    try:
        calibrate.check_fits(points, measured, fits, args.model, limits, args.allow_far_base)
    except calibrate.CalibrationError as e:
        print(f"error: refused: {e}", file=sys.stderr)
        return 2
    result = {arm: calibrate.entry(*fits[arm]) for arm in ARM_KEYS}
    if args.print_only:
        return 0
    try:
        calibrate.write_calibration(args.limits, result)
    except (LimitsError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"written into {args.limits}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
