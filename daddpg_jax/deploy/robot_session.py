"""What ``daddpg-robot-client`` sets up around the control loop (daddpg_jax/deploy/robot.py):
its options checked, the robot's limits with the flags' tightenings, the served policy checked
against them, the perturbation, the arms' env, and one run of episodes with its summary and
exit code. NumPy only, no JAX.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import time

from daddpg_jax.deploy import server
from daddpg_jax.deploy.arms import ArmsError, ArmsUsageError, make_env
from daddpg_jax.deploy.calibrate import CalibrationError, parse_base_error
from daddpg_jax.deploy.client import read_token
from daddpg_jax.deploy.limits import LimitsError, RobotLimits
from daddpg_jax.deploy.policy import check_env, env_settings, task_settings
from daddpg_jax.deploy.robot import Pacer, run_episodes
from daddpg_jax.deploy.safety import SafetyFilter
from mjx_envs import perturb, schema, settings


class ServiceError(Exception):
    """The service cannot be used (unreachable, another task, bad settings); says why."""


def check_options(episodes: int, arms: str, fast: bool = False, perturb=(),
                  ur_hosts: str | None = None, sim_base_error: str | None = None,
                  policy_sha256: str | None = None) -> str | None:
    """One-line error text when daddpg-robot-client's options do not fit together, else
    None."""
    if episodes < 1:
        return f"--episodes must be >= 1, got {episodes}"
    if arms == "ur" and (fast or perturb):
        return "--fast and --perturb are for simulated arms only (--arms sim or ur-sim)"
    if arms != "ur" and ur_hosts:
        return "--ur-hosts needs --arms ur"
    if arms != "ur-sim" and sim_base_error:
        return "--sim-base-error needs --arms ur-sim"
    if policy_sha256 is not None and not re.fullmatch(r"[0-9a-f]{64}", policy_sha256.lower()):
        return "--policy-sha256 must be 64 hexadecimal digits (as sha256sum prints them)"
    return None


def robot_limits(path: str | None, fast: bool = False, speed_scale: float = 1.0,
                 deadline_ms: float | None = None, max_observation_age_ms: float | None = None,
                 **tighten):
    """(RobotLimits of the file at `path` (None: the built-in limits) tightened by the flags,
    SafetyLimits at `speed_scale`); `tighten`: max_speed, min_clearance, workspace_margin.
    Raises LimitsError."""
    limits = RobotLimits.load(path) if path else RobotLimits()
    deadline = None if deadline_ms is None else deadline_ms / 1e3
    age = None if max_observation_age_ms is None else max_observation_age_ms / 1e3
    limits = limits.tightened(deadline=deadline, max_observation_age=age, **tighten)
    if not fast and limits.deadline > limits.control_period:
        raise LimitsError(f"the deadline {limits.deadline * 1e3:g} ms exceeds the control period "
                          f"{limits.control_period * 1e3:g} ms; allowed only unpaced (--fast, "
                          f"simulation)")
    return limits, limits.safety_limits(speed_scale)


def served_policy(url: str, limits, task, sha256: str | None, token: str | None):
    """(service info, the task's settings (a mjx_envs.settings config), env settings with
    ``dt``) of the policy served at `url`, checked against the robot's limits; raises
    ServiceError."""
    client = server.PolicyClient(url, timeout=5.0, token=token)
    try:
        info = client.info()
    except (OSError, RuntimeError, ValueError) as e:
        raise ServiceError(f"policy service at {url} not reachable: {e}") from None
    finally:
        client.close()
    try:
        limits.check_served(info, task=task)
    except LimitsError as e:
        raise ServiceError(str(e)) from None
    if sha256 is not None and info.get("policy_sha256") != sha256:
        raise ServiceError(f"the served policy's SHA-256 {info.get('policy_sha256')!r} is not "
                           f"the pinned {sha256}")
    served = info.get("task")
    if served not in settings.TASK_SETTINGS:
        raise ServiceError(f"the service serves a policy of an unknown task {served!r}")
    # the standard task: the training-only task options (e.g. grasped starts) switched off
    env = {**(info.get("env") or {}), **settings.test_overrides(served)}
    try:
        check_env(env)
        return info, task_settings(served, env), env_settings(served, env)
    except ValueError as e:
        raise ServiceError(f"settings of the served {served!r} policy: {e}") from None


def perturbation(task: str, items: list):
    """The Perturbation of --perturb KEY=VALUE items (exact values); raises ConfigError."""
    cls = type(settings.default_config(task))
    over = schema.parse_overrides(cls, items, "--perturb")
    bad = sorted(set(over) - set(perturb.FIELDS))
    if bad:
        raise schema.ConfigError(f"--perturb: {', '.join(bad)} is not a perturbation; choose "
                                 f"from {', '.join(perturb.FIELDS)}")
    cfg = settings.task_config(task, **over, perturb_exact=True)   # validates the values
    return perturb.Perturbation.from_config(cfg)


def arms_env(kind: str, task_cfg, task: str, limits, hosts: str | None = None,
             dry_run: bool = False, base_error: str | None = None, exact: bool = True):
    """The loop's env for --arms `kind` (daddpg_jax.deploy.arms.make_env); `hosts` and
    `base_error` as the flags give them. Raises ArmsError."""
    error = None
    if base_error:
        try:
            error = parse_base_error(base_error)
        except CalibrationError as e:
            raise ArmsUsageError(str(e)) from None
    return make_env(kind, task_cfg, task, limits.control_period,
                    bases=limits.base_transforms(), hosts=hosts.split(",") if hosts else None,
                    dry_run=dry_run, base_error=error, exact=exact)


class SetupError(Exception):
    """The run cannot start; says why, with the client's exit code (2 usage, limits or service;
    4 the arms cannot be reached)."""

    def __init__(self, message: str, exit_code: int = 2):
        super().__init__(message)
        self.exit_code = exit_code


@dataclasses.dataclass
class Setup:
    """Everything a run needs besides the options: the limits (RobotLimits and the
    SafetyLimits in force), the token, the service's info, its task, the perturbation (None:
    none) and the arms' env."""
    robot_limits: RobotLimits
    safety: object
    token: str | None
    info: dict
    task: str
    perturbation: object
    env: object


def prepare(opt, report=print) -> Setup:
    """The Setup of daddpg-robot-client's parsed options `opt` (its argparse namespace), in order:
    the limits (`robot_limits`; `report(line)` gets their description), the token, the served
    policy (`served_policy`), the perturbation, the --log directory and the arms' env
    (`arms_env`). Raises SetupError."""
    try:
        limits, safety = robot_limits(
            opt.limits, fast=opt.fast, speed_scale=opt.speed_scale, deadline_ms=opt.deadline_ms,
            max_observation_age_ms=opt.max_observation_age_ms, max_speed=opt.max_speed,
            min_clearance=opt.min_clearance, workspace_margin=opt.workspace_margin)
        token = read_token(opt.token_file) if opt.token_file else None
    except ValueError as e:  # LimitsError included
        raise SetupError(str(e)) from None
    report(limits.describe(opt.speed_scale))
    sha = None if opt.policy_sha256 is None else opt.policy_sha256.lower()
    try:
        info, task_cfg, _ = served_policy(opt.server, limits, opt.task, sha, token)
        task = info["task"]
        perturbed = perturbation(task, opt.perturb) if opt.perturb else None
    except (ServiceError, schema.ConfigError) as e:
        raise SetupError(str(e)) from None
    if opt.log:
        try:
            os.makedirs(opt.log, exist_ok=True)
        except OSError as e:
            raise SetupError(f"cannot create --log directory {opt.log!r}: {e.strerror}") from None
    try:
        env = arms_env(opt.arms, task_cfg, task, limits, hosts=opt.ur_hosts, dry_run=opt.dry_run,
                       base_error=opt.sim_base_error, exact=not opt.float64)
    except ArmsError as e:  # ArmsUsageError: exit 2; the arms cannot be reached: 4
        raise SetupError(str(e), 2 if isinstance(e, ArmsUsageError) else 4) from None
    return Setup(limits, safety, token, info, task, perturbed, env)


def episode_logger(log_dir: str):
    """on_log for run_episodes: one JSON file per episode in the directory log_dir."""
    def on_log(log):
        path = os.path.join(log_dir, f"episode_{log['episode'] + 1:05d}.json")
        with open(path, "w") as f:
            json.dump(log, f)

    return on_log


def run(env, url: str, token: str | None, limits, safety, episodes: int, monitor,
        seed: int = 0, fast: bool = False, perturbation=None, log_dir: str | None = None,
        dry_run: bool = False, report=print) -> dict:
    """Runs `episodes` episodes of `env` against the service at `url` through the safety
    filter (robot.run_episodes, outages watched by `monitor`; paced at the control period
    unless `fast`; one JSON log per episode in `log_dir`) and closes the client and the env.
    Returns robot.run_episodes' summary with joint_refusals (arms with joint limits),
    dry_run_commands (`dry_run`; written to log_dir/dry_run_commands.json) and wall_s;
    `report(line)` gets the refusal line. Raises ArmsStopped / ArmsError."""
    client = server.PolicyClient(url, timeout=safety.deadline_s, token=token)
    pacer = None if fast else Pacer(limits.control_period, clock=monitor.clock)
    on_log = episode_logger(log_dir) if log_dir else None
    t0 = time.perf_counter()
    try:
        out = run_episodes(env, client, SafetyFilter(safety), episodes, seed=seed,
                           monitor=monitor, perturbation=perturbation, pacer=pacer,
                           max_observation_age=limits.max_observation_age, on_log=on_log)
    finally:
        client.close()
        if hasattr(env, "close"):
            env.close()  # servoStop, then the connections
    if hasattr(env, "refused"):
        out["joint_refusals"] = env.refused
        if env.refused:
            report(f"joint limits: {env.refused} arm target(s) without a joint solution "
                   f"within the limits were refused (the arm kept its target)")
    if dry_run:
        out["dry_run_commands"] = len(env.arms.sent)
        if log_dir:
            with open(os.path.join(log_dir, "dry_run_commands.json"), "w") as f:
                json.dump(env.arms.sent, f)
    out["wall_s"] = round(time.perf_counter() - t0, 2)
    return out


def limits_fields(robot_limits, safety, speed_scale: float, monitor, perturbation) -> dict:
    """The summary's record of the limits a run kept: their source, the speed scale, the
    deadline, step cap, clearance and observation age in force, the outage limits and the
    perturbation (None: none)."""
    return dict(limits=robot_limits.source, speed_scale=speed_scale,
                deadline_ms=safety.deadline_s * 1e3, max_step_m=safety.max_step,
                min_clearance_m=safety.min_clearance,
                max_observation_age_ms=robot_limits.max_observation_age * 1e3,
                max_missed=monitor.max_missed, max_outage_s=monitor.max_outage_s,
                perturbation=(dataclasses.asdict(perturbation)
                              if perturbation is not None else None))


def outcome(out: dict, episodes: int) -> tuple[int, str | None]:
    """(exit code, closing stderr line or None) of a run's summary: 3 with an error line when
    it was aborted, else 0 with a note when episodes were excluded."""
    excluded = out["excluded_episodes"]
    if out["aborted"]:
        aborted = out["aborted"]
        return 3, (f"error: {aborted['reason']}; aborted in episode {aborted['episode']} of "
                   f"{episodes}; {excluded} episode(s) excluded, {out['episodes']} counted")
    if excluded:
        return 0, (f"note: {excluded} of {out['episodes_run']} episodes excluded from the "
                   f"results (missed deadlines)")
    return 0, None
