"""The loop's env for each ``--arms`` kind (NumPy only at import; MuJoCo and ``ur_rtde`` are
imported when a kind needs them): ``sim`` (`daddpg_jax.deploy.ursim.SimArms`), ``ur``
(`daddpg_jax.deploy.arms.URArms` on two controllers) and ``ur-sim`` (the same `URArms` on
`daddpg_jax.deploy.ursim`'s simulated controllers). Every kind is an
`daddpg_jax.deploy.arms.ArmsEnv`, so every command passes the gate
(`daddpg_jax.deploy.gate.GatedArms`)."""

from __future__ import annotations

from daddpg_jax.deploy.arms import ArmsEnv, ArmsError, ArmsUsageError, connect_ur
from daddpg_jax.deploy.ursim import sim_env, sim_ur_env

ARMS_KINDS = ("sim", "ur", "ur-sim")


def make_env(kind: str, task_cfg, task: str, period: float, bases=None, hosts=None,
             dry_run: bool = False, base_error=None, exact: bool = True, safety=None,
             connect_timeout: float | None = None, call_timeout: float | None = None,
             watchdog: float | None = None, sources=None) -> ArmsEnv:
    """The loop's `ArmsEnv` for ``--arms kind``: ``sim`` `daddpg_jax.deploy.ursim.SimArms` on
    the simulator (whose bases are exactly the nominal ones: ``bases`` is not used);
    ``ur`` `URArms` on the controllers at ``hosts`` (left, right; reach only unless
    ``sources`` gives an object source); ``ur-sim`` `URArms` on simulated controllers whose bases
    carry ``base_error`` ((offset [2, 3] m, yaw [2] rad)). ``bases``: the robot side's world <-
    base transforms of ``ur`` and ``ur-sim`` (`RobotLimits.base_transforms`). ``safety``: the
    `SafetyLimits` the gate enforces (None: the simulator's own); connect_timeout,
    call_timeout, watchdog: seconds (`daddpg_jax.deploy.arms.connect_ur`). ``sources``: called
    with the simulated cell (None for ``ur``), (object source, goal source), either None for
    the cell's own (`daddpg_jax.deploy.perception.Perception`: a camera); with an object
    source ``ur`` runs every task. ArmsError (one line) when it cannot be made."""
    from mjx_envs.numpy_env import NumpyDualArmEnv  # lazy: MuJoCo; NumPy only at import

    if kind not in ARMS_KINDS:
        raise ArmsUsageError(f"--arms must be one of {', '.join(ARMS_KINDS)}, got {kind!r}")
    if kind == "sim" and dry_run:
        raise ArmsUsageError("--dry-run needs --arms ur or ur-sim (the simulator moves nothing)")
    spec = NumpyDualArmEnv(task_cfg, task=task, exact=exact)
    if kind == "sim":
        return sim_env(spec, NumpyDualArmEnv(task_cfg, task=task, exact=exact), safety=safety,
                       sources=sources)
    if kind == "ur-sim":
        offset, yaw = (None, None) if base_error is None else base_error
        return sim_ur_env(spec, NumpyDualArmEnv(task_cfg, task=task, exact=exact), period,
                          bases=bases, offset=offset, yaw=yaw, dry_run=dry_run, safety=safety,
                          call_timeout=call_timeout, watchdog=watchdog, sources=sources)
    if hosts is None or len(hosts) != 2 or not all(hosts):
        raise ArmsUsageError("--arms ur needs --ur-hosts LEFT,RIGHT")
    objects, goals = (None, None) if sources is None else sources(None)
    if spec.rules.has_object and objects is None:
        raise ArmsUsageError(f"--arms ur runs reach only: the {task!r} task needs an object "
                             f"source (--objects camera-tag or camera-color; docs/PERCEPTION.md)")
    kw = {k: v for k, v in dict(connect_timeout=connect_timeout, call_timeout=call_timeout,
                                watchdog=watchdog).items() if v is not None}
    try:
        arms = connect_ur(hosts, period, dry_run=dry_run, **kw)
    except ArmsError:
        for source in (objects, goals):  # the camera is released
            if hasattr(source, "close"):
                source.close()
        raise
    return ArmsEnv(spec, arms, bases=bases, safety=safety, objects=objects, goals=goals)
