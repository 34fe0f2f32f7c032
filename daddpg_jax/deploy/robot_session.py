"""What ``daddpg-robot-client`` sets up around the control loop (daddpg_jax/deploy/robot.py):
its options checked, the robot's limits with the flags' tightenings, the served policy checked
against them, the perturbation, the arms' env, and one run of episodes with its summary and
exit code. NumPy only, no JAX.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import re
import signal
import time

from daddpg_jax.deploy import perception, server, trained_limits
from daddpg_jax.deploy.arms import ArmsError, ArmsStopped, ArmsUsageError
from daddpg_jax.deploy.arms_factory import make_env
from daddpg_jax.deploy.calibrate import CalibrationError, parse_base_error
from daddpg_jax.deploy.client import read_token
from daddpg_jax.deploy.gate import GateRefusal
from daddpg_jax.deploy.limits import LimitsError, RobotLimits
from daddpg_jax.deploy.recording import RecorderError, recorded
from daddpg_jax.deploy.robot import Pacer, run_episodes
from daddpg_jax.deploy.safety import SafetyFilter
from mjx_envs import episode_starts, perturb, registry, schema, settings
from mjx_envs import observation as obs_lib

COMPARED = ("scene", "episode_length", "timestep", "n_substeps", "max_delta", "lock_fingers",
            "locked_opening", "finger_stroke", "action_history")
"""The task settings a served policy must share with the robot's own task (the scene, its
timing, the action scale, the fingers, the observation layout); training-only, reward and
randomization settings are not compared."""
MAX_EPISODES = 1_000_000
MAX_SEED = 2**63 - 1


class ServiceError(Exception):
    """The service cannot be used (unreachable, another task, bad settings); says why."""


def check_numbers(opt) -> str | None:
    """One-line error text when a numeric option of daddpg-robot-client (its argparse
    namespace) is not finite or out of range, else None."""
    if not 1 <= opt.episodes <= MAX_EPISODES:
        return f"--episodes must be in 1..{MAX_EPISODES}, got {opt.episodes}"
    if not 0 <= opt.seed <= MAX_SEED:
        return f"--seed must be in 0..2**63-1, got {opt.seed}"
    if opt.max_missed < 0:
        return f"--max-missed must be >= 0 (0: no limit), got {opt.max_missed}"
    for flag, v in (("--max-outage-s", opt.max_outage_s), ("--speed-scale", opt.speed_scale),
                    ("--deadline-ms", opt.deadline_ms),
                    ("--max-observation-age-ms", opt.max_observation_age_ms),
                    ("--max-speed", opt.max_speed), ("--min-clearance", opt.min_clearance),
                    ("--workspace-margin", opt.workspace_margin)):
        if v is not None and not (math.isfinite(v) and v >= 0):
            return f"{flag} must be a finite number >= 0, got {v!r}"
    if opt.max_missed == 0 and opt.max_outage_s == 0:
        return ("--max-missed 0 and --max-outage-s 0 would let a dead service hold the arms "
                "forever: keep at least one limit")
    if opt.json:
        folder = os.path.dirname(os.path.abspath(opt.json))
        if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
            return f"--json {opt.json!r}: the folder {folder!r} does not exist or is not writable"
    return None


def check_options(episodes: int, arms: str, fast: bool = False, perturb=(),
                  ur_hosts: str | None = None, sim_base_error: str | None = None,
                  policy_sha256: str | None = None, starts: str | None = None) -> str | None:
    """One-line error text when daddpg-robot-client's options do not fit together, else
    None."""
    if episodes < 1:
        return f"--episodes must be >= 1, got {episodes}"
    if arms == "ur" and starts:
        return ("--starts places simulated episodes' objects: --arms sim or ur-sim only (real "
                "arms see the real scene)")
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


def robot_task(task: str, physics_version: int | None = None):
    """The robot's own settings of ``task`` (a mjx_envs.settings config): the task installed
    with this package, standard episodes (the training-only options off); its simulator (--arms
    sim, ur-sim) in physics version ``physics_version`` (None: the current one)."""
    over = dict(registry.test_overrides(task))
    if physics_version is not None:
        over["physics_version"] = int(physics_version)
    return registry.task_config(task, **over)


def check_model(info, own) -> None:
    """Refuses (ServiceError, one line) a served policy whose task settings (`COMPARED`), agent
    count or observation and action layout differ from the robot's own task ``own``."""
    env = info.get("env")
    if not isinstance(env, dict):
        raise ServiceError("GET /info holds no env settings")
    for key in COMPARED:
        mine, served = getattr(own, key), env.get(key, getattr(own, key))
        if isinstance(mine, float) and isinstance(served, (int, float)) and not isinstance(
                served, bool):
            same = abs(float(served) - mine) <= 1e-9 + 1e-6 * abs(mine)
        else:
            same = served == mine
        if not same:
            raise ServiceError(f"the served policy's {key} {served!r:.60} differs from the robot's "
                               f"own {info.get('task')!r} task ({mine!r})")
    layout = {"num_agents": 2, "num_arms": 2, "arm_action": obs_lib.ARM_ACTION_SIZE,
              "action_size": 2 * obs_lib.ARM_ACTION_SIZE, "goal_size": 3,
              "obs_size": obs_lib.obs_size(own.action_history)}
    for key, mine in layout.items():
        if info.get(key, mine) != mine:
            raise ServiceError(f"the served policy's {key} {info.get(key)!r:.60} is not the "
                               f"robot's {mine}")


def served_policy(url: str, limits, task, sha256: str | None, token: str | None):
    """(service info, the robot's own task settings (a mjx_envs.settings config)) of the
    policy served at `url`, checked against the robot's limits and its own task (the served
    settings are only compared, never used); raises ServiceError."""
    try:
        client = server.PolicyClient(url, timeout=5.0, token=token)
    except ValueError as e:
        raise ServiceError(str(e)) from None
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
    if not isinstance(served, str) or served not in registry.TASK_SETTINGS:
        raise ServiceError(f"the service serves a policy of a task {str(served)[:40]!r} this "
                           f"robot does not have")
    # a simulated robot acts with the physics the policy was trained with (the service reports
    # it; a service that does not: the current version); the physics versions differ in
    # collision geometry only, not in kinematics
    version = info.get("physics_version")
    if not isinstance(version, int) or isinstance(version, bool):
        version = settings.PHYSICS_VERSION
    if not 1 <= version <= settings.LATEST_PHYSICS_VERSION:
        raise ServiceError(f"the served policy's physics version {version} is not one this "
                           f"package simulates (1 to {settings.LATEST_PHYSICS_VERSION})")
    own = robot_task(served, version)
    check_model(info, own)
    return info, own


def perturbation(task: str, items: list):
    """The Perturbation of --perturb KEY=VALUE items (exact values); raises ConfigError."""
    cls = type(registry.default_config(task))
    over = schema.parse_overrides(cls, items, "--perturb")
    bad = sorted(set(over) - set(perturb.FIELDS))
    if bad:
        raise schema.ConfigError(f"--perturb: {', '.join(bad)} is not a perturbation; choose "
                                 f"from {', '.join(perturb.FIELDS)}")
    cfg = registry.task_config(task, **over, perturb_exact=True)   # validates the values
    return perturb.Perturbation.from_config(cfg)


def arms_env(kind: str, task_cfg, task: str, limits, hosts: str | None = None,
             dry_run: bool = False, base_error: str | None = None, exact: bool = True,
             safety=None, sources=None):
    """The loop's env for --arms `kind` (daddpg_jax.deploy.arms_factory.make_env) behind the
    gate with `safety` (the SafetyLimits in force); `hosts` and `base_error` as the flags give
    them; the connect and call timeouts and the watchdog from `limits`; `sources`: the camera's
    (`daddpg_jax.deploy.perception.Perception`) or None. Raises ArmsError."""
    error = None
    if base_error:
        try:
            error = parse_base_error(base_error)
        except CalibrationError as e:
            raise ArmsUsageError(str(e)) from None
    watchdog = max(limits.watchdog, limits.deadline + limits.control_period)
    return make_env(kind, task_cfg, task, limits.control_period,
                    bases=limits.base_transforms(), hosts=hosts.split(",") if hosts else None,
                    dry_run=dry_run, base_error=error, exact=exact, safety=safety,
                    connect_timeout=limits.connect_timeout, call_timeout=limits.call_timeout,
                    watchdog=watchdog, sources=sources)


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
    none), the arms' env and the episodes' starts (--starts; None: drawn from --seed)."""
    robot_limits: RobotLimits
    safety: object
    token: str | None
    info: dict
    task: str
    perturbation: object
    env: object
    starts: episode_starts.EpisodeStarts | None = None


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
        limits.check_calibration()
        token = read_token(opt.token_file) if opt.token_file else None
    except ValueError as e:  # LimitsError included
        raise SetupError(str(e)) from None
    report(limits.describe(opt.speed_scale))
    sha = None if opt.policy_sha256 is None else opt.policy_sha256.lower()
    try:
        info, task_cfg = served_policy(opt.server, limits, opt.task, sha, token)
        task = info["task"]
        mismatch = trained_limits.check(info, safety, getattr(opt, "require_trained_limits",
                                                              False))
        if mismatch:
            report(mismatch)
        perturbed = perturbation(task, opt.perturb) if opt.perturb else None
    except (ServiceError, ValueError) as e:  # ConfigError, --require-trained-limits
        raise SetupError(str(e)) from None
    if opt.log:
        try:
            os.makedirs(opt.log, exist_ok=True)
        except OSError as e:
            raise SetupError(f"cannot create --log directory {opt.log!r}: {e.strerror}") from None
    try:
        sight = perception.from_options(opt, limits, task)
        env = arms_env(opt.arms, task_cfg, task, limits, hosts=opt.ur_hosts, dry_run=opt.dry_run,
                       base_error=opt.sim_base_error, exact=not opt.float64, safety=safety,
                       sources=sight)
    except ArmsError as e:  # ArmsUsageError: exit 2; the arms cannot be reached: 4
        raise SetupError(str(e), 2 if isinstance(e, ArmsUsageError) else 4) from None
    except perception.PerceptionError as e:
        raise SetupError(str(e)) from None
    try:
        starts = _starts(opt, task, env)
        env = recorded(env, getattr(opt, "rerun", None), safety, sight)
    except (RecorderError, episode_starts.StartsError) as e:
        env.close()
        raise SetupError(str(e)) from None
    return Setup(limits, safety, token, info, task, perturbed, env, starts)


def _starts(opt, task: str, env) -> episode_starts.EpisodeStarts | None:
    """The episodes' starts of --starts (None without it), checked against the task, its
    model's state size and --episodes. Raises StartsError."""
    path = getattr(opt, "starts", None)
    if not path:
        return None
    starts = episode_starts.load(path, task=task, nq=env.spec.model.nq)
    if opt.episodes > len(starts):
        raise episode_starts.StartsError(f"--starts {path}: {len(starts)} episodes, --episodes "
                                         f"asks {opt.episodes}")
    return starts


def episode_logger(log_dir: str):
    """on_log for run_episodes: one JSON file per episode in the directory log_dir."""
    def on_log(log):
        path = os.path.join(log_dir, f"episode_{log['episode'] + 1:05d}.json")
        with open(path, "w") as f:
            json.dump(log, f)

    return on_log


ENDS_RUN = (ArmsError, ArmsStopped, GateRefusal)
"""The arms' errors that end a run (in the summary's ``aborted``; exit 4, a gate refusal 2)."""


class Signals:
    """SIGINT and SIGTERM ask the run to stop at the next control period (the arms hold, the
    summary and logs are written; exit 130 / 143); a second signal of the same kind stops at
    once. Use as a context manager; ``requested()`` is ``run_episodes``' ``interrupted``."""

    NAMES = {signal.SIGINT: "SIGINT", signal.SIGTERM: "SIGTERM"}

    def __init__(self):
        self.signum: int | None = None
        self._old: dict = {}

    def _handle(self, signum, frame):
        if self.signum == signum:
            raise KeyboardInterrupt
        self.signum = signum

    def requested(self):
        if self.signum is None:
            return None
        return self.signum, f"interrupted by {self.NAMES.get(self.signum, self.signum)}"

    def __enter__(self):
        with contextlib.suppress(ValueError):  # not the main thread: signals stay as they are
            for sig in self.NAMES:
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)
        return False


def run(env, url: str, token: str | None, limits, safety, episodes: int, monitor,
        seed: int = 0, fast: bool = False, perturbation=None, log_dir: str | None = None,
        dry_run: bool = False, report=print, interrupted=None, starts=None) -> dict:
    """Runs `episodes` episodes of `env` against the service at `url` through the safety
    filter (robot.run_episodes, outages watched by `monitor`; paced at the control period
    unless `fast`; one JSON log per episode in `log_dir`) and closes the client and the env.
    Returns robot.run_episodes' summary with joint_refusals (arms with joint limits),
    dry_run_commands (`dry_run`; written to log_dir/dry_run_commands.json) and wall_s;
    `report(line)` gets the refusal line and the gate's. The arms' errors (`ENDS_RUN`), lost
    readings and `interrupted` (`Signals.requested`) end the run with ``aborted`` set; the
    arms are stopped (servoStop) and released in every case. `starts`: the episodes' goals
    and initial states (`mjx_envs.episode_starts.EpisodeStarts`; None: drawn from `seed`)."""
    client = server.PolicyClient(url, timeout=safety.deadline_s, token=token)
    pacer = None if fast else Pacer(limits.control_period, clock=monitor.clock)
    on_log = episode_logger(log_dir) if log_dir else None
    record = getattr(env, "episode_log", None)  # a recorded run (--rerun)
    if record is not None:
        on_log = record if on_log is None else (lambda log, f=on_log: (f(log), record(log)))
    t0 = time.perf_counter()
    try:
        out = run_episodes(env, client, SafetyFilter(safety), episodes, seed=seed,
                           monitor=monitor, perturbation=perturbation, pacer=pacer,
                           max_observation_age=limits.max_observation_age, on_log=on_log,
                           max_reading_gap=limits.max_reading_gap, interrupted=interrupted,
                           ends_run=ENDS_RUN, starts=starts)
    finally:
        client.close()
        if hasattr(env, "close"):
            env.close()  # servoStop, then the connections
    gate = getattr(env, "arms", None)
    refusals = dict(getattr(gate, "refusals", {}) or {})
    out["gate_refusals"] = refusals
    if refusals:
        report(f"gate: {sum(refusals.values())} command(s) refused and held "
               f"({', '.join(f'{k} {v}' for k, v in sorted(refusals.items()))}); first: "
               f"{gate.refused[0]}")
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


EXIT_CODES = {"outage": 3, "GateRefusal": 2, "signal": None}
"""Exit code of an aborted run by its kind (``signal``: 128 + the signal's number); 4 else."""


def outcome(out: dict, episodes: int) -> tuple[int, str | None]:
    """(exit code, closing stderr line or None) of a run's summary: when it was aborted, 3 (an
    outage of the service), 4 (the arms: a driver error, a stop, lost readings), 2 (the gate
    refused the start) or 130 / 143 (SIGINT / SIGTERM) with an error line; else 0 with a note
    when episodes were excluded."""
    excluded = out["excluded_episodes"]
    if out["aborted"]:
        aborted = out["aborted"]
        kind = aborted.get("kind", "outage")
        code = EXIT_CODES.get(kind, 4)
        if kind == "signal":
            code = 128 + int(aborted["signal"])
        what = "the run is stopped" if kind not in ("outage", "signal") else "aborted"
        return code, (f"error: {aborted['reason']}; {what} in episode {aborted['episode']} of "
                      f"{episodes}; {excluded} episode(s) excluded, {out['episodes']} counted")
    if excluded:
        return 0, (f"note: {excluded} of {out['episodes_run']} episodes excluded from the "
                   f"results (missed deadlines)")
    return 0, None
