r"""Robot client: the arms (the NumPy simulator, two UR arms, or the UR path on simulated
controllers) query the policy service every control period, through the safety layer, and the
client reports the success rate. No JAX is imported. Details: docs/DEPLOYMENT.md, "Robot
client, sim-to-sim" and "Arms"; outages: docs/RELIABILITY.md, "Robot client".

Examples (daddpg-robot-client = python experiments/robot_client.py)
  daddpg-serve policy.npz &
  daddpg-robot-client --limits daddpg_jax/deploy/limits/sim.toml --fast --episodes 200
  daddpg-robot-client --limits cell.toml --speed-scale 0.25 --episodes 5 --log logs/
  daddpg-robot-client --limits cell.toml --max-speed 0.1 --min-clearance 0.08 --json out.json
  daddpg-robot-client --policy-sha256 HEX --token-file token.txt --episodes 10
  daddpg-robot-client --arms ur-sim --sim-base-error 0.02,0,0,2,0,-0.02,0,-2 --episodes 20
  daddpg-robot-client --arms ur --ur-hosts 192.168.1.10,192.168.1.11 --limits cell.toml \
      --speed-scale 0.1 --episodes 1 [--dry-run]
  daddpg-robot-client --arms ur-sim --goals tags --objects camera-tag --rerun run.rrd
  daddpg-robot-client --arms ur --ur-hosts L,R --objects camera-tag --camera realsense

The robot owns its limits (--limits, printed on stderr at start); the flags may only tighten
them, and nothing from the service widens them (GET /info is checked: the same control period,
task and action layout, else exit 2). A control period without a usable answer in time is a
missed deadline in which both arms hold; episodes with one are excluded from the results.
stdout holds the JSON summary; stderr ends with a short human-readable one.

Every command to an arm passes one gate last (daddpg_jax/deploy/gate.py): inside the box, within
the speed cap of the last command, the clearance rule, the finger range; a command that fails is
held. The task's model (scene, timing, episode length, layout) is the robot's own: the service
is only checked against it.

Exit codes: 0 done; 2 bad limits or arguments, the service unreachable at start, serving a
policy the robot refuses (control period, task, task settings, layout, SHA-256), or a start
pose or measured pose outside the box (nothing moved); 3 aborted on an outage of the service
(--max-missed, --max-outage-s); 4 the arms cannot be reached, a driver call failed, returned
False or overran, the readings froze, or an arm reports a protective or emergency stop;
130 / 143 interrupted by SIGINT / SIGTERM (the arms hold, the summary is written).
"""

from __future__ import annotations

import argparse
import json
import sys

from daddpg_jax.deploy import perception
from daddpg_jax.deploy import robot_session as session
from daddpg_jax.deploy.arms import ArmsError, ArmsStopped
from daddpg_jax.deploy.arms_factory import ARMS_KINDS
from daddpg_jax.deploy.robot import MAX_MISSED, MAX_OUTAGE_S, OutageMonitor, format_summary


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="daddpg-robot-client", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add = p.add_argument
    add("--server", default="http://127.0.0.1:8000", help="policy service URL")
    add("--task", default=None,
        help="task; must match the served policy (default: the served policy's); episodes are "
             "those of the standard task (mjx_envs.settings.TRAINING_ONLY_FIELDS off)")
    add("--episodes", type=int, default=100, help="episodes to run")
    add("--seed", type=int, default=0, help="seed of the NumPy goal sampler")
    add("--starts", default=None, metavar="FILE.npz",
        help="--arms sim/ur-sim: play the episodes of this file (goals and initial states, "
             "from daddpg-evaluate --save-starts) in order, paired with that evaluation")
    add("--limits", default=None, metavar="FILE",
        help="the robot's limits, TOML or JSON: workspace box per arm, speed cap, arm "
             "clearance, control period, deadline, finger range, observation age, calibration "
             "(default: conservative built-in limits; documented field by field in "
             "daddpg_jax/deploy/limits/ur3_cell.toml)")
    add("--speed-scale", type=float, default=1.0,
        help="scale the speed cap by this factor in (0, 1] (first runs: 0.25)")
    add("--require-trained-limits", action="store_true",
        help="refuse the run (exit 2) unless the policy was trained under limits no looser "
             "than the robot's (daddpg-train --limits)")
    add("--deadline-ms", type=float, default=None,
        help="tighten the limits' deadline of each answer, ms")
    add("--max-observation-age-ms", type=float, default=None,
        help="tighten the limits' largest age of an observation when its answer arrives, ms")
    add("--max-missed", type=int, default=MAX_MISSED,
        help=f"abort after this many consecutive missed deadlines (default {MAX_MISSED}; 0: no "
             "limit)")
    add("--max-outage-s", type=float, default=MAX_OUTAGE_S,
        help=f"abort when an outage of the service lasts this long, s (default "
             f"{MAX_OUTAGE_S:g}; 0: no limit)")
    add("--max-speed", type=float, default=None,
        help="tighten the limits' cap of each gripper target's speed, m/s")
    add("--min-clearance", type=float, default=None,
        help="tighten the limits' smallest gap between the arms' link capsules, m")
    add("--workspace-margin", type=float, default=None,
        help="shrink the limits' workspace boxes on every side, m (>= 0)")
    add("--policy-sha256", default=None, metavar="HEX",
        help="refuse a service whose policy file has another SHA-256 (as sha256sum prints it)")
    add("--token-file", default=None, metavar="FILE",
        help="send the shared token in this file (daddpg-serve --token-file)")
    add("--fast", action="store_true",
        help="run unpaced, as fast as the simulator steps (sim-to-sim only; the deadline may "
             "then exceed the control period); else the loop runs once per control period on "
             "a monotonic clock (overruns counted)")
    add("--log", default=None, metavar="DIR",
        help="write one JSON log per episode to DIR (observations, answers, safety decisions, "
             "targets, times; daddpg_jax.deploy.robot.replay_episode replays one)")
    add("--float64", action="store_true",
        help="step one float64 MjData (a plain simulator) instead of mirroring the trainer's "
             "C-engine bookkeeping exactly")
    add("--perturb", action="append", default=[], metavar="KEY=VALUE",
        help="apply a perturbation at this exact value (repeatable): obs_noise (std, m), "
             "obs_dropout (probability per step), obs_bias (m), obs_period (steps), latency "
             "(steps); see mjx_envs/perturb.py; the safety layer sees the true state")
    add("--arms", choices=ARMS_KINDS, default="sim",
        help="sim: the simulator (default); ur: two UR arms through ur_rtde (pip install "
             "'daddpg-jax[ur]'; --ur-hosts; reach, or any task with a camera's --objects; "
             "servoL every control period, servoStop "
             "on abort or exit); ur-sim: the UR path on simulated controllers; ur and ur-sim "
             "convert frames with the limits' calibration (daddpg-calibrate)")
    add("--ur-hosts", default=None, metavar="LEFT,RIGHT",
        help="--arms ur: the two controllers' addresses")
    add("--dry-run", action="store_true",
        help="--arms ur/ur-sim: connect read-only, log what would be sent (with --log DIR: "
             "dry_run_commands.json), move nothing")
    add("--sim-base-error", default=None, metavar="8 NUMBERS",
        help="--arms ur-sim: each simulated base's true error dx,dy,dz (m),yaw (deg), left then "
             "right (the robot side uses the limits' calibration)")
    add("--json", default=None, help="also write the summary to this JSON file")
    perception.add_arguments(p)  # --goals, --objects, --camera, --rerun
    return p


def _stderr_line(line: str):
    print(line, file=sys.stderr, flush=True)


def _finish(out: dict, args) -> int:
    """Print and save the summary; the exit code (3 when the run was aborted)."""
    print(json.dumps(out, indent=2), flush=True)
    if args.json:
        try:
            with open(args.json, "w") as f:
                json.dump(out, f, indent=2)
        except OSError as e:
            _stderr_line(f"error: cannot write --json {args.json!r}: {e.strerror or e}")
    _stderr_line(format_summary(out))
    code, line = session.outcome(out, args.episodes)
    if line:
        _stderr_line(line)
    return code


def _fail(message: str, code: int = 2) -> int:
    print(f"error: {message}", file=sys.stderr)
    return code


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    bad = session.check_options(args.episodes, args.arms, fast=args.fast, perturb=args.perturb,
                                ur_hosts=args.ur_hosts, sim_base_error=args.sim_base_error,
                                policy_sha256=args.policy_sha256, starts=args.starts)
    bad = bad or session.check_numbers(args) or perception.check_options(
        args.goals, args.objects, args.camera, args.arms, track=args.track)
    if bad:
        return _fail(bad)
    with session.Signals() as signals:
        try:
            setup = session.prepare(args, report=_stderr_line)
        except session.SetupError as e:
            return _fail(str(e), e.exit_code)
        monitor = OutageMonitor(args.max_missed, args.max_outage_s, report=_stderr_line)
        try:
            out = session.run(setup.env, args.server, setup.token, setup.robot_limits,
                              setup.safety, args.episodes, monitor, seed=args.seed,
                              fast=args.fast, perturbation=setup.perturbation, log_dir=args.log,
                              dry_run=args.dry_run, report=_stderr_line,
                              interrupted=signals.requested, starts=setup.starts)
        except (ArmsStopped, ArmsError) as e:
            return _fail(f"{e}; the run is stopped", 4)
    out.update(server=args.server, task=setup.task, arms=args.arms, dry_run=args.dry_run,
               algo=setup.info.get("algo"), policy_sha256=setup.info.get("policy_sha256"),
               seed=args.seed, starts=args.starts, goals=args.goals, objects=args.objects,
               camera=args.camera, **session.limits_fields(setup.robot_limits, setup.safety,
                                                       args.speed_scale, monitor,
                                                       setup.perturbation))
    return _finish(out, args)


if __name__ == "__main__":
    sys.exit(main())
