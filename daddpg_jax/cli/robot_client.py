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
import sys
import time


def _parser() -> argparse.ArgumentParser:
    from daddpg_jax.deploy.arms import ARMS_KINDS
    from daddpg_jax.deploy.robot import MAX_MISSED, MAX_OUTAGE_S

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


def _perturbation(task: str, items: list):
    """The Perturbation of --perturb KEY=VALUE items (exact values); raises ConfigError."""
    from mjx_envs import perturb, schema, settings

    cls = type(settings.default_config(task))
    over = schema.parse_overrides(cls, items, "--perturb")
    bad = sorted(set(over) - set(perturb.FIELDS))
    if bad:
        raise schema.ConfigError(f"--perturb: {', '.join(bad)} is not a perturbation; choose "
                                 f"from {', '.join(perturb.FIELDS)}")
    cfg = settings.task_config(task, **over, perturb_exact=True)   # validates the values
    return perturb.Perturbation.from_config(cfg)


class _ServiceError(Exception):
    """The service cannot be used (unreachable, another task, bad settings); says why."""


def _served(server: str, limits, task, sha256: str | None, token: str | None):
    """(service info, the task's settings (a mjx_envs.settings config), env settings with
    ``dt``) of the served policy, checked against the robot's limits; raises _ServiceError."""
    from daddpg_jax.deploy.limits import LimitsError
    from daddpg_jax.deploy.policy import check_env, env_settings, task_settings
    from daddpg_jax.deploy.server import PolicyClient
    from mjx_envs.settings import TASK_SETTINGS, test_overrides

    client = PolicyClient(server, timeout=5.0, token=token)
    try:
        info = client.info()
    except (OSError, RuntimeError, ValueError) as e:
        raise _ServiceError(f"policy service at {server} not reachable: {e}") from None
    finally:
        client.close()
    try:
        limits.check_served(info, task=task)
    except LimitsError as e:
        raise _ServiceError(str(e)) from None
    if sha256 is not None and info.get("policy_sha256") != sha256:
        raise _ServiceError(f"the served policy's SHA-256 {info.get('policy_sha256')!r} is not "
                            f"the pinned {sha256}")
    served = info.get("task")
    if served not in TASK_SETTINGS:
        raise _ServiceError(f"the service serves a policy of an unknown task {served!r}")
    # the standard task: the training-only task options (e.g. grasped starts) switched off
    env = {**(info.get("env") or {}), **test_overrides(served)}
    try:
        check_env(env)
        return info, task_settings(served, env), env_settings(served, env)
    except ValueError as e:
        raise _ServiceError(f"settings of the served {served!r} policy: {e}") from None


def _stderr_line(line: str):
    print(line, file=sys.stderr, flush=True)


def _finish(out: dict, args) -> int:
    """Print and save the summary; the exit code (3 when the run was aborted)."""
    from daddpg_jax.deploy.robot import format_summary

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


def _robot_limits(args):
    """(RobotLimits after the overrides, SafetyLimits); raises LimitsError."""
    from daddpg_jax.deploy.limits import LimitsError, RobotLimits

    limits = RobotLimits.load(args.limits) if args.limits else RobotLimits()
    deadline = None if args.deadline_ms is None else args.deadline_ms / 1e3
    age = None if args.max_observation_age_ms is None else args.max_observation_age_ms / 1e3
    limits = limits.tightened(max_speed=args.max_speed, min_clearance=args.min_clearance,
                              workspace_margin=args.workspace_margin, deadline=deadline,
                              max_observation_age=age)
    if not args.fast and limits.deadline > limits.control_period:
        raise LimitsError(f"the deadline {limits.deadline * 1e3:g} ms exceeds the control period "
                          f"{limits.control_period * 1e3:g} ms; allowed only unpaced (--fast, "
                          f"simulation)")
    return limits, limits.safety_limits(args.speed_scale)


def _check_args(args):
    """One-line error text for a bad argument, else None."""
    import re

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


def _arms_env(args, task_cfg, task: str, robot_limits):
    """The loop's env for --arms (daddpg_jax.deploy.arms.make_env); raises ArmsError."""
    from daddpg_jax.deploy.arms import ArmsUsageError, make_env

    base_error = None
    if args.sim_base_error:
        from daddpg_jax.cli.calibrate import sim_base_error
        from daddpg_jax.deploy.calibrate import CalibrationError

        try:
            base_error = sim_base_error(args.sim_base_error)
        except CalibrationError as e:
            raise ArmsUsageError(str(e)) from None
    hosts = args.ur_hosts.split(",") if args.ur_hosts else None
    return make_env(args.arms, task_cfg, task, robot_limits.control_period,
                    bases=robot_limits.base_transforms(), hosts=hosts, dry_run=args.dry_run,
                    base_error=base_error, exact=not args.float64)


def main(argv=None) -> int:
    args = _parser().parse_args(argv)

    from daddpg_jax.deploy.arms import ArmsError, ArmsStopped, ArmsUsageError
    from daddpg_jax.deploy.client import read_token
    from daddpg_jax.deploy.robot import OutageMonitor, Pacer, run_episodes
    from daddpg_jax.deploy.safety import SafetyFilter
    from daddpg_jax.deploy.server import PolicyClient
    from mjx_envs.schema import ConfigError

    bad = _check_args(args)
    if bad:
        print(f"error: {bad}", file=sys.stderr)
        return 2
    try:
        robot_limits, limits = _robot_limits(args)
        token = read_token(args.token_file) if args.token_file else None
    except ValueError as e:  # LimitsError included
        print(f"error: {e}", file=sys.stderr)
        return 2
    _stderr_line(robot_limits.describe(args.speed_scale))
    sha = None if args.policy_sha256 is None else args.policy_sha256.lower()
    try:
        info, task_cfg, _ = _served(args.server, robot_limits, args.task, sha, token)
    except _ServiceError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    task = info["task"]
    try:
        perturbation = _perturbation(task, args.perturb) if args.perturb else None
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    on_log = None
    if args.log:
        try:
            os.makedirs(args.log, exist_ok=True)
        except OSError as e:
            print(f"error: cannot create --log directory {args.log!r}: {e.strerror}",
                  file=sys.stderr)
            return 2

        def on_log(log):
            path = os.path.join(args.log, f"episode_{log['episode'] + 1:05d}.json")
            with open(path, "w") as f:
                json.dump(log, f)

    try:
        env = _arms_env(args, task_cfg, task, robot_limits)
    except ArmsError as e:  # ArmsUsageError: exit 2; the arms cannot be reached: 4
        print(f"error: {e}", file=sys.stderr)
        return 2 if isinstance(e, ArmsUsageError) else 4
    client = PolicyClient(args.server, timeout=limits.deadline_s, token=token)
    monitor = OutageMonitor(args.max_missed, args.max_outage_s, report=_stderr_line)
    pacer = None if args.fast else Pacer(robot_limits.control_period, clock=monitor.clock)
    t0 = time.perf_counter()
    try:
        out = run_episodes(env, client, SafetyFilter(limits), args.episodes, seed=args.seed,
                           monitor=monitor, perturbation=perturbation, pacer=pacer,
                           max_observation_age=robot_limits.max_observation_age, on_log=on_log)
    except (ArmsStopped, ArmsError) as e:
        print(f"error: {e}; the run is stopped", file=sys.stderr)
        return 4
    finally:
        client.close()
        if hasattr(env, "close"):
            env.close()  # servoStop, then the connections
    if hasattr(env, "refused"):
        out["joint_refusals"] = env.refused
        if env.refused:
            _stderr_line(f"joint limits: {env.refused} arm target(s) without a joint solution "
                         f"within the limits were refused (the arm kept its target)")
    if args.dry_run:
        out["dry_run_commands"] = len(env.arms.sent)
        if args.log:
            with open(os.path.join(args.log, "dry_run_commands.json"), "w") as f:
                json.dump(env.arms.sent, f)
    out.update(wall_s=round(time.perf_counter() - t0, 2), server=args.server, task=task,
               arms=args.arms, dry_run=args.dry_run,
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
