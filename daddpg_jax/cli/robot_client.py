r"""Sim-to-sim robot client: a plain-MuJoCo NumPy stand-in for the robot queries the policy
service every control period, through the safety layer, and reports the success rate.

Examples (daddpg-robot-client = python experiments/robot_client.py)
  daddpg-serve policy.npz &
  daddpg-robot-client --server http://127.0.0.1:8000 --episodes 200
  daddpg-robot-client --server http://127.0.0.1:8000 --episodes 50 \
      --max-speed 0.5 --min-clearance 0.03 --json client.json
  daddpg-robot-client --episodes 100 --perturb obs_noise=0.01 --perturb latency=1

The task and its env settings (scene, dt, max_delta, workspace, goal region, threshold, ...)
come from the service's GET /info, i.e. from the exported run; settings an older export lacks
are the task's defaults from mjx_envs.settings. Episodes are those of the standard task: the
training-only task options (mjx_envs.settings.TRAINING_ONLY_FIELDS, e.g. goals at rest height
or grasped starts) are switched off. No JAX is imported. --perturb applies the trainer's
observation and action perturbations (mjx_envs/perturb.py, the same code) at exact values to
what the policy sees and sends; the safety layer sees the true state.

Outages: a control period without a usable answer in time (no answer, an error, a malformed or
late answer) is a missed deadline, in which both arms hold. One line on stderr reports each
outage when it starts and one when the service answers again. After --max-missed consecutive
missed deadlines or --max-outage-s seconds of outage, whichever comes first, the client stops:
the summary so far on stdout (with "aborted"), one line on stderr, exit code 3. Episodes with
a missed deadline are never counted in the results ("excluded_episodes" says how many).

Exit codes: 0 done; 2 the service unreachable at start or serving another task; 3 aborted on an
outage of the service.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time


def _parser() -> argparse.ArgumentParser:
    from daddpg_jax.deploy.robot import MAX_MISSED, MAX_OUTAGE_S

    p = argparse.ArgumentParser(prog="daddpg-robot-client", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--server", default="http://127.0.0.1:8000", help="policy service URL")
    p.add_argument("--task", default=None,
                   help="task; must match the served policy (default: the served policy's)")
    p.add_argument("--episodes", type=int, default=100, help="episodes to run")
    p.add_argument("--seed", type=int, default=0, help="seed of the NumPy goal sampler")
    p.add_argument("--deadline-ms", type=float, default=None,
                   help="hold both arms when the answer takes longer (default: one control period)")
    p.add_argument("--max-missed", type=int, default=MAX_MISSED,
                   help="abort after this many consecutive missed deadlines (default "
                        f"{MAX_MISSED}; 0: no limit)")
    p.add_argument("--max-outage-s", type=float, default=MAX_OUTAGE_S,
                   help="abort when an outage of the service lasts this long, s (default "
                        f"{MAX_OUTAGE_S:g}; 0: no limit)")
    p.add_argument("--max-speed", type=float, default=None,
                   help="cap of each gripper target's speed, m/s (default: what the policy can "
                        "command, sqrt(3)*max_delta/dt)")
    p.add_argument("--min-clearance", type=float, default=None,
                   help="refuse moves that bring the arms' link capsules closer, m (default: the "
                        "env's arm_clearance)")
    p.add_argument("--workspace-margin", type=float, default=0.0,
                   help="shrink the workspace boxes on every side, m")
    p.add_argument("--float64", action="store_true",
                   help="step one float64 MjData (a plain simulator) instead of mirroring the "
                        "trainer's C-engine bookkeeping exactly")
    p.add_argument("--perturb", action="append", default=[], metavar="KEY=VALUE",
                   help="apply a perturbation at this exact value (repeatable): obs_noise (std, "
                        "m), obs_dropout (probability per step), obs_bias (m), obs_period "
                        "(steps), latency (steps); see mjx_envs/perturb.py")
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


def _served(server: str, task):
    """(service info, the task's settings (a mjx_envs.settings config), env settings with
    ``dt``) of the served policy; raises _ServiceError."""
    from http.client import HTTPException

    from daddpg_jax.deploy.policy import env_settings, task_settings
    from daddpg_jax.deploy.server import PolicyClient
    from mjx_envs.settings import test_overrides

    try:
        info = PolicyClient(server, timeout=5.0).info()
    except (OSError, RuntimeError, ValueError, HTTPException) as e:
        raise _ServiceError(f"policy service at {server} not reachable: {e}") from None
    served = info.get("task")
    if task is not None and served != task:
        raise _ServiceError(f"the service serves a {served!r} policy, not {task!r}")
    # the standard task: the training-only task options (e.g. grasped starts) switched off
    env = {**(info.get("env") or {}), **test_overrides(served)}
    try:
        return info, task_settings(served, env), env_settings(served, env)
    except ValueError as e:
        raise _ServiceError(f"settings of the served {served!r} policy: {e}") from None


def _stderr_line(line: str):
    print(line, file=sys.stderr, flush=True)


def _finish(out: dict, args) -> int:
    """Print and save the summary; the exit code (3 when the run was aborted)."""
    print(json.dumps(out, indent=2), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)
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


def main(argv=None) -> int:
    args = _parser().parse_args(argv)

    from daddpg_jax.deploy.robot import OutageMonitor, run_episodes
    from daddpg_jax.deploy.safety import SafetyFilter, SafetyLimits
    from daddpg_jax.deploy.server import PolicyClient
    from mjx_envs.numpy_env import NumpyDualArmEnv

    try:
        info, task_cfg, settings = _served(args.server, args.task)
    except _ServiceError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    deadline = None if args.deadline_ms is None else args.deadline_ms / 1e3
    limits = SafetyLimits.from_env(settings, max_speed=args.max_speed,
                                   min_clearance=args.min_clearance, deadline_s=deadline,
                                   margin=args.workspace_margin)
    client = PolicyClient(args.server, timeout=max(limits.deadline_s, 0.001))
    task = info["task"]
    from mjx_envs.schema import ConfigError

    try:
        perturbation = _perturbation(task, args.perturb) if args.perturb else None
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    env = NumpyDualArmEnv(task_cfg, task=task, exact=not args.float64)
    monitor = OutageMonitor(args.max_missed, args.max_outage_s, report=_stderr_line)
    t0 = time.perf_counter()
    try:
        out = run_episodes(env, client, SafetyFilter(limits), args.episodes, seed=args.seed,
                           monitor=monitor, perturbation=perturbation)
    finally:
        client.close()
    out.update(wall_s=round(time.perf_counter() - t0, 2), server=args.server, task=task,
               algo=info.get("algo"), seed=args.seed, deadline_ms=limits.deadline_s * 1e3,
               max_step_m=limits.max_step, min_clearance_m=limits.min_clearance,
               max_missed=monitor.max_missed, max_outage_s=monitor.max_outage_s,
               perturbation=(dataclasses.asdict(perturbation)
                             if perturbation is not None else None))
    return _finish(out, args)


if __name__ == "__main__":
    sys.exit(main())
