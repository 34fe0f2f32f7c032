r"""Robot client: the arms (the NumPy simulator, two UR arms, or the UR path on simulated
controllers) query the policy service every control period, through the safety layer, and the
client reports the success rate.

Examples (daddpg-robot-client = python experiments/robot_client.py)
  daddpg-serve policy.npz &
  daddpg-robot-client --limits daddpg_jax/deploy/limits/sim.toml --fast --episodes 200
  daddpg-robot-client --limits cell.toml --speed-scale 0.25 --episodes 5 --log logs/
  daddpg-robot-client --limits cell.toml --max-speed 0.1 --min-clearance 0.08 --json out.json
  daddpg-robot-client --policy-sha256 HEX --token-file token.txt --episodes 10
  daddpg-robot-client --arms ur-sim --sim-base-error 0.02,0,0,2,0,-0.02,0,-2 --episodes 20
  daddpg-robot-client --arms ur --ur-hosts 192.168.1.10,192.168.1.11 --limits cell.toml \
      --speed-scale 0.1 --episodes 1 [--dry-run]

The robot owns its limits: the workspace box per arm, the speed cap, the arm clearance, the
control period, the deadline, the finger range and the observation age come from --limits FILE
(TOML or JSON; documented field by field in daddpg_jax/deploy/limits/ur3_cell.toml), or from
conservative built-in defaults; the limits in use are printed at start (stderr). --max-speed,
--min-clearance, --workspace-margin, --deadline-ms and --max-observation-age-ms may only
tighten them; --speed-scale in (0, 1] slows the speed cap down. Nothing from the service
widens them: GET /info is checked (same control period, task and action layout, else exit 2).
The simulated world (scene, max_delta, goal region, threshold, ...) comes from the served
policy's env settings; episodes are those of the standard task (the training-only options of
mjx_envs.settings.TRAINING_ONLY_FIELDS switched off). No JAX is imported. --perturb applies the
trainer's observation and action perturbations (mjx_envs/perturb.py) at exact values to what
the policy sees and sends; the safety layer sees the true state.

The loop runs once per control period on a monotonic clock (overruns counted); --fast runs it
unpaced (sim-to-sim only; then the deadline may exceed the control period). --log DIR writes one
JSON log per episode (observations, answers, safety decisions, targets, times), which
daddpg_jax.deploy.robot.replay_episode replays in the simulator.

Outages: a control period without a usable answer in time (no answer, an error, a malformed or
late answer, or an observation older than the limit) is a missed deadline, in which both arms
hold. One line on stderr reports each outage when it starts and one when the service answers
again. After --max-missed consecutive missed deadlines or --max-outage-s seconds of outage,
whichever comes first, the client stops: the summary so far on stdout (with "aborted"), one
line on stderr, exit code 3. Episodes with a missed deadline are never counted in the results
("excluded_episodes" says how many). stdout holds the JSON summary; stderr ends with a short
human-readable one.

Arms (--arms), all behind the same arms interface: sim (default) the NumPy simulator; ur two UR
arms through ur_rtde (pip install 'daddpg-jax[ur]'; --ur-hosts LEFT,RIGHT; reach only),
streaming servoL every control period (a hold streams the held pose; servoStop on abort or
exit); ur-sim the same UR code on simulated controllers (--sim-base-error: their bases' true
error). The limits' calibration (daddpg-calibrate) converts between the world and the base
frames of ur and ur-sim (sim uses its own exact bases). --dry-run (ur,
ur-sim) connects read-only and logs what it would send (--log DIR: dry_run_commands.json).

Exit codes: 0 done; 2 bad limits or arguments, the service unreachable at start, or serving a
policy the robot refuses (control period, task, action layout, SHA-256); 3 aborted on an outage
of the service; 4 the arms cannot be reached, or an arm reports a protective or emergency
stop.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import sys

from daddpg_jax.deploy import robot_session as session
from daddpg_jax.deploy.arms import ARMS_KINDS, ArmsError, ArmsStopped, ArmsUsageError
from daddpg_jax.deploy.client import read_token
from daddpg_jax.deploy.robot import MAX_MISSED, MAX_OUTAGE_S, OutageMonitor, format_summary
from mjx_envs.schema import ConfigError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="daddpg-robot-client", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--server", default="http://127.0.0.1:8000", help="policy service URL")
    p.add_argument("--task", default=None,
                   help="task; must match the served policy (default: the served policy's)")
    p.add_argument("--episodes", type=int, default=100, help="episodes to run")
    p.add_argument("--seed", type=int, default=0, help="seed of the NumPy goal sampler")
    p.add_argument("--limits", default=None, metavar="FILE",
                   help="the robot's limits, TOML or JSON (default: conservative built-in "
                        "limits; see daddpg_jax/deploy/limits/ur3_cell.toml)")
    p.add_argument("--speed-scale", type=float, default=1.0,
                   help="scale the speed cap by this factor in (0, 1] (first runs: 0.25)")
    p.add_argument("--deadline-ms", type=float, default=None,
                   help="tighten the limits' deadline of each answer, ms")
    p.add_argument("--max-observation-age-ms", type=float, default=None,
                   help="tighten the limits' largest age of an observation when its answer "
                        "arrives, ms")
    p.add_argument("--max-missed", type=int, default=MAX_MISSED,
                   help="abort after this many consecutive missed deadlines (default "
                        f"{MAX_MISSED}; 0: no limit)")
    p.add_argument("--max-outage-s", type=float, default=MAX_OUTAGE_S,
                   help="abort when an outage of the service lasts this long, s (default "
                        f"{MAX_OUTAGE_S:g}; 0: no limit)")
    p.add_argument("--max-speed", type=float, default=None,
                   help="tighten the limits' cap of each gripper target's speed, m/s")
    p.add_argument("--min-clearance", type=float, default=None,
                   help="tighten the limits' smallest gap between the arms' link capsules, m")
    p.add_argument("--workspace-margin", type=float, default=None,
                   help="shrink the limits' workspace boxes on every side, m (>= 0)")
    p.add_argument("--policy-sha256", default=None, metavar="HEX",
                   help="refuse a service whose policy file has another SHA-256 (as sha256sum "
                        "prints it)")
    p.add_argument("--token-file", default=None, metavar="FILE",
                   help="send the shared token in this file (daddpg-serve --token-file)")
    p.add_argument("--fast", action="store_true",
                   help="run unpaced, as fast as the simulator steps (sim-to-sim only)")
    p.add_argument("--log", default=None, metavar="DIR",
                   help="write one JSON log per episode to DIR")
    p.add_argument("--float64", action="store_true",
                   help="step one float64 MjData (a plain simulator) instead of mirroring the "
                        "trainer's C-engine bookkeeping exactly")
    p.add_argument("--perturb", action="append", default=[], metavar="KEY=VALUE",
                   help="apply a perturbation at this exact value (repeatable): obs_noise (std, "
                        "m), obs_dropout (probability per step), obs_bias (m), obs_period "
                        "(steps), latency (steps); see mjx_envs/perturb.py")
    p.add_argument("--arms", choices=ARMS_KINDS, default="sim",
                   help="sim: the simulator (default); ur: two UR arms through ur_rtde "
                        "(--ur-hosts); ur-sim: the UR path on simulated controllers")
    p.add_argument("--ur-hosts", default=None, metavar="LEFT,RIGHT",
                   help="--arms ur: the two controllers' addresses")
    p.add_argument("--dry-run", action="store_true",
                   help="--arms ur/ur-sim: connect read-only, log what would be sent, move "
                        "nothing")
    p.add_argument("--sim-base-error", default=None, metavar="8 NUMBERS",
                   help="--arms ur-sim: each simulated base's true error dx,dy,dz (m),yaw "
                        "(deg), left then right (the robot side uses the limits' calibration)")
    p.add_argument("--json", default=None, help="also write the summary to this JSON file")
    return p


def _stderr_line(line: str):
    print(line, file=sys.stderr, flush=True)


def _finish(out: dict, args) -> int:
    """Print and save the summary; the exit code (3 when the run was aborted)."""
    print(json.dumps(out, indent=2), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)
    _stderr_line(format_summary(out))
    excluded = out["excluded_episodes"]
    if out["aborted"]:
        a = out["aborted"]
        _stderr_line(f"error: {a['reason']}; aborted in episode {a['episode']} of "
                     f"{args.episodes}; {excluded} episode(s) excluded, {out['episodes']} "
                     f"counted")
        return 3
    if excluded:
        _stderr_line(f"note: {excluded} of {out['episodes_run']} episodes excluded from the "
                     f"results (missed deadlines)")
    return 0


def _check_args(args):
    """One-line error text for a bad argument, else None."""
    if args.episodes < 1:
        return f"--episodes must be >= 1, got {args.episodes}"
    if args.arms == "ur" and (args.fast or args.perturb):
        return "--fast and --perturb are for simulated arms only (--arms sim or ur-sim)"
    if args.arms != "ur" and args.ur_hosts:
        return "--ur-hosts needs --arms ur"
    if args.arms != "ur-sim" and args.sim_base_error:
        return "--sim-base-error needs --arms ur-sim"
    if args.policy_sha256 is not None and not re.fullmatch(r"[0-9a-f]{64}",
                                                           args.policy_sha256.lower()):
        return "--policy-sha256 must be 64 hexadecimal digits (as sha256sum prints them)"
    return None


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    bad = _check_args(args)
    if bad:
        print(f"error: {bad}", file=sys.stderr)
        return 2
    try:
        robot_limits, limits = session.robot_limits(
            args.limits, fast=args.fast, speed_scale=args.speed_scale,
            deadline_ms=args.deadline_ms, max_observation_age_ms=args.max_observation_age_ms,
            max_speed=args.max_speed, min_clearance=args.min_clearance,
            workspace_margin=args.workspace_margin)
        token = read_token(args.token_file) if args.token_file else None
    except ValueError as e:  # LimitsError included
        print(f"error: {e}", file=sys.stderr)
        return 2
    _stderr_line(robot_limits.describe(args.speed_scale))
    sha = None if args.policy_sha256 is None else args.policy_sha256.lower()
    try:
        info, task_cfg, _ = session.served_policy(args.server, robot_limits, args.task, sha,
                                                  token)
        task = info["task"]
        perturbation = session.perturbation(task, args.perturb) if args.perturb else None
    except (session.ServiceError, ConfigError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.log:
        try:
            os.makedirs(args.log, exist_ok=True)
        except OSError as e:
            print(f"error: cannot create --log directory {args.log!r}: {e.strerror}",
                  file=sys.stderr)
            return 2
    try:
        env = session.arms_env(args.arms, task_cfg, task, robot_limits, hosts=args.ur_hosts,
                               dry_run=args.dry_run, base_error=args.sim_base_error,
                               exact=not args.float64)
    except ArmsError as e:  # ArmsUsageError: exit 2; the arms cannot be reached: 4
        print(f"error: {e}", file=sys.stderr)
        return 2 if isinstance(e, ArmsUsageError) else 4
    monitor = OutageMonitor(args.max_missed, args.max_outage_s, report=_stderr_line)
    try:
        out = session.run(env, args.server, token, robot_limits, limits, args.episodes, monitor,
                          seed=args.seed, fast=args.fast, perturbation=perturbation,
                          log_dir=args.log, dry_run=args.dry_run, report=_stderr_line)
    except (ArmsStopped, ArmsError) as e:
        print(f"error: {e}; the run is stopped", file=sys.stderr)
        return 4
    out.update(server=args.server, task=task, arms=args.arms, dry_run=args.dry_run,
               algo=info.get("algo"), policy_sha256=info.get("policy_sha256"), seed=args.seed,
               limits=robot_limits.source, speed_scale=args.speed_scale,
               deadline_ms=limits.deadline_s * 1e3, max_step_m=limits.max_step,
               min_clearance_m=limits.min_clearance,
               max_observation_age_ms=robot_limits.max_observation_age * 1e3,
               max_missed=monitor.max_missed, max_outage_s=monitor.max_outage_s,
               perturbation=(dataclasses.asdict(perturbation)
                             if perturbation is not None else None))
    return _finish(out, args)


if __name__ == "__main__":
    sys.exit(main())
