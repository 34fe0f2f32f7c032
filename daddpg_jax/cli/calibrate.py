r"""Frame calibration: finds each arm's base pose in the policy's world frame and writes it into
the robot limits file, with the residual of each point (daddpg_jax/deploy/calibrate.py).

Examples (daddpg-calibrate = python experiments/calibrate.py)
  daddpg-calibrate --limits cell.toml --points board.json --measured touched.json
  daddpg-calibrate --limits cell.toml --points board.json --ur-hosts 192.168.1.10,192.168.1.11
  daddpg-calibrate --limits cell.toml --points board.json --arms ur-sim \
      --sim-base-error 0.02,0,0,2,0,-0.02,0,-2

--points FILE (JSON): the known world positions of the board's points, m, per arm:
{"left": [[x, y, z], ...], "right": [[x, y, z], ...]}, at least 4 each (8 recommended, spread
over the arm's workspace). --measured FILE: the tool centre read on each point in that arm's
base frame, same layout, rows [x, y, z] or UR poses [x, y, z, rx, ry, rz] (getActualTCPPose).
--ur-hosts LEFT,RIGHT reads them from the arms (read-only RTDE): move the gripper onto each point
(freedrive) and press Enter. --arms ur-sim rehearses it on the simulated controllers, whose
bases carry --sim-base-error (per arm dx, dy, dz in m and yaw in degrees, left then right) and
whose readings --noise-mm of Gaussian noise (RMS per point).

The fit is least squares (--model yaw: a level base, turn about z + offset; full: any
rotation). The limits file gets a [calibration.left] / [calibration.right] block (replaced on
each run); --print-only leaves it unchanged. Exit codes: 0 done; 2 bad arguments, files or
points; 4 the arms cannot be reached.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from daddpg_jax.deploy import calibrate
from daddpg_jax.deploy.limits import ARM_KEYS, LimitsError, RobotLimits


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="daddpg-calibrate", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--limits", required=True, metavar="FILE",
                   help="the robot limits file (TOML or JSON) that receives the calibration")
    p.add_argument("--points", required=True, metavar="FILE",
                   help="known world points per arm (JSON)")
    src = p.add_mutually_exclusive_group(required=True)
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
    p.add_argument("--print-only", action="store_true", help="do not write the limits file")
    return p


def _per_arm(path: str, what: str) -> dict:
    try:
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
    except (OSError, ValueError) as e:
        raise calibrate.CalibrationError(f"cannot read {what} {path!r}: "
                                         f"{getattr(e, 'strerror', None) or e}") from None
    if not isinstance(d, dict) or set(d) != set(ARM_KEYS):
        raise calibrate.CalibrationError(f"{what} {path!r} must hold a 'left' and a 'right' "
                                         f"list of points")
    try:
        return {a: np.asarray(d[a], float) for a in ARM_KEYS}
    except (TypeError, ValueError):
        raise calibrate.CalibrationError(f"{what} {path!r}: every point must be a list of "
                                         f"numbers") from None


def sim_base_error(text: str):
    """(offset [2, 3] m, yaw [2] rad) of --sim-base-error; CalibrationError if malformed."""
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 8 or not np.all(np.isfinite(v)) or max(abs(x) for x in v) > 30:
        raise calibrate.CalibrationError("--sim-base-error must be 8 finite numbers: dx,dy,dz "
                                         "(m),yaw (deg) of the left then the right base")
    a = np.asarray(v).reshape(2, 4)
    return a[:, :3], np.radians(a[:, 3])


def _measure_sim(points: dict, args) -> dict:
    """Readings of the simulated controllers (true bases with --sim-base-error) with the tool
    centre placed exactly on each point, plus Gaussian noise of --noise-mm RMS."""
    from daddpg_jax.deploy.arms import base_transform, invert
    from daddpg_jax.deploy.robot import ARMS
    from daddpg_jax.deploy.ur3 import BASE_POS, BASE_YAW

    offset, yaw = sim_base_error(args.sim_base_error)
    if not (np.isfinite(args.noise_mm) and 0 <= args.noise_mm <= 10):
        raise calibrate.CalibrationError("--noise-mm must be in [0, 10]")
    rng = np.random.default_rng(args.seed)
    sigma = args.noise_mm * 1e-3 / np.sqrt(3.0)
    out = {}
    for i, (arm, a) in enumerate(zip(ARM_KEYS, ARMS)):
        inv = invert(base_transform(BASE_POS[a] + offset[i], BASE_YAW[a] + yaw[i]))
        w = calibrate._points("--points", points[arm])
        out[arm] = w @ inv[:3, :3].T + inv[:3, 3] + rng.normal(0.0, sigma, w.shape)
    return out


def _measure_ur(points: dict, hosts: list[str]) -> dict:
    from daddpg_jax.deploy.arms import receive_only

    receives = receive_only(hosts)
    out = {}
    try:
        for i, arm in enumerate(ARM_KEYS):
            rows = []
            for k, w in enumerate(points[arm]):
                input(f"{arm} arm: put the tool centre on point {k + 1} "
                      f"({', '.join(f'{x:.4f}' for x in w)} m) and press Enter ")
                rows.append(receives[i].getActualTCPPose())
            out[arm] = np.asarray(rows, float)
    finally:
        for r in receives:
            r.disconnect()
    return out


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    from daddpg_jax.deploy.arms import ArmsError

    try:
        RobotLimits.load(args.limits)
        points = _per_arm(args.points, "--points")
        if args.measured:
            measured = _per_arm(args.measured, "--measured")
        elif args.arms == "ur-sim":
            measured = _measure_sim(points, args)
        else:
            hosts = args.ur_hosts.split(",")
            if len(hosts) != 2 or not all(hosts):
                raise calibrate.CalibrationError("--ur-hosts must be LEFT,RIGHT")
            measured = _measure_ur(points, hosts)
        result = {}
        for arm in ARM_KEYS:
            T, res = calibrate.fit_base(points[arm], measured[arm], args.model)
            result[arm] = calibrate.entry(T, res)
    except (LimitsError, calibrate.CalibrationError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except ArmsError as e:
        print(f"error: {e}", file=sys.stderr)
        return 4
    for arm in ARM_KEYS:
        c = result[arm]
        yaw = np.degrees(np.linalg.norm(c["base_rotvec"]))
        print(f"{arm} base: position {c['base_pos']} m, rotation {yaw:.3f} deg "
              f"(rotvec {c['base_rotvec']}); residuals mm {c['residuals_mm']} "
              f"(rms {c['rms_mm']:.3f})")
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
