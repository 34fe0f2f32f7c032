"""Plain-MuJoCo, NumPy-only simulator of every task (no JAX): the stand-in for the real dual-arm
robot and the engine of the Gymnasium adapter (`mjx_envs.gym_env`).

The robot client (``daddpg_jax/cli/robot_client.py``) drives this env the way it would drive the
real robot: read sensors, build observations with `mjx_envs.observation` (``xp = numpy``), ask
the policy service for an action, move the Cartesian targets. The step mirrors
``mjx_envs.core.DualArmEnv.step`` on the C engine:

- the same MJCF scene (`mjx_envs.model.load_model`) with the task's timestep and friction cone;
- target = previous target + ``max_delta * clip(a[:3], -1, 1)``, clipped to the arm's
  workspace box; finger servo targets from ``a[3]`` (or held at ``locked_opening``);
- ``mujoco.mj_step`` ``n_substeps`` times holding ctrl and mocap; sensors are read right after
  the last substep (MuJoCo evaluates them before that substep's final integration, as in the
  trainer's engines);
- goals, the object's initial placement, achieved goals, success and rewards from the same
  rules as the JAX env (`mjx_envs.rules`, ``xp = numpy``), drawn from a NumPy ``Generator``.

Settings: the task's defaults; ``settings`` (a dict, e.g. a policy export's ``env`` settings,
or a `TaskConfig`) overrides them (`mjx_envs.registry.saved_config`). Dict keys that are not
config fields (such as the export's derived ``dt``) are ignored.

Training-only options of pickup and pot (`mjx_envs.settings.TRAINING_ONLY_FIELDS`):
``goal_rest_fraction`` is supported (goals come from the shared rules, with the same draws as
the JAX env); ``grasp_start_fraction`` is not: it is set to 0 in ``config`` with a warning, and
every episode starts from the standard initial state (the grasped states are recorded by the
JAX env). The robot client evaluates the standard task (`mjx_envs.registry.test_overrides`).
The observation and action perturbations (`mjx_envs.perturb`) are not simulated here either
(set to 0 with a warning): the robot client applies them to what it reads and sends.

``exact=True`` (default) also repeats the C backend's bookkeeping: state kept in float32
between control steps, and every control step starts from ``mj_resetData`` + that state (so the
solver warmstart is zero, as ``mujoco.rollout`` does). Then the trajectory equals the trainer's
C-engine env to float32 rounding. ``exact=False`` keeps one float64 ``MjData`` running, like a
real simulator would.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from mjx_envs import limit_rules, perturb, registry, rules
from mjx_envs import observation as obs_lib
from mjx_envs import settings as settings_lib
from mjx_envs.model import home_state, load_model
from mjx_envs.schema import replace_config

NUM_ARMS = 2
SUPPORTED_TASKS = registry.TASKS
SAMPLER = rules.NumpySampler()


@dataclass
class StepResult:
    """What the robot knows after a control step (all NumPy, float32)."""

    observation: np.ndarray  # [2, 25] (the sensor observation; no action history)
    achieved_goal: np.ndarray  # [2, 3]
    desired_goal: np.ndarray  # [2, 3]
    link_points: np.ndarray  # [2, 5, 3] shoulder, elbow, wrist 1, flange, tool centre
    target: np.ndarray  # [2, 3] current Cartesian targets (mocap)
    success: bool
    goal_distance: np.ndarray  # [2]
    arm_clearance: float
    step: int


class NumpyDualArmEnv:
    """One env of any task, stepped with MuJoCo's C engine from NumPy; see the module doc."""

    def __init__(self, settings: Mapping[str, Any] | settings_lib.TaskConfig | None = None,
                 task: str = settings_lib.DEFAULT_TASK, exact: bool = True):
        cfg = registry.saved_config(task, settings)
        if getattr(cfg, "grasp_start_fraction", 0.0) > 0:
            warnings.warn(f"NumpyDualArmEnv does not start episodes from grasped states: "
                          f"grasp_start_fraction={cfg.grasp_start_fraction} is set to 0",
                          stacklevel=2)
            cfg = replace_config(cfg, grasp_start_fraction=0.0)
        on = {k: getattr(cfg, k) for k in perturb.FIELDS if getattr(cfg, k)}
        if on:
            warnings.warn(f"NumpyDualArmEnv simulates true observations and actions: {on} "
                          "set to 0 (the robot client applies perturbations: "
                          "daddpg-robot-client --perturb)", stacklevel=2)
            cfg = replace_config(cfg, **{k: type(v)(0) for k, v in on.items()})
        on = {k: getattr(cfg, k) for k in settings_lib.RANDOMIZATION_FIELDS
              if getattr(cfg, k, 0.0)}
        if on:
            warnings.warn(f"NumpyDualArmEnv simulates the nominal physics: {on} set to 0 "
                          "(physics randomization is in the JAX env, mjx_envs/randomize.py)",
                          stacklevel=2)
            cfg = replace_config(cfg, **{k: 0.0 for k in on})
        self.config = cfg
        self.settings = dataclasses.asdict(cfg)
        self.task = task
        self.exact = bool(exact)
        self.model = load_model(cfg.scene, cfg.timestep, cfg.cone, cfg.physics_version)
        self.data = mujoco.MjData(self.model)
        self.rules = registry.make_rules(task, cfg, self.model)
        self.n_substeps = int(cfg.n_substeps)
        self.dt = float(cfg.timestep) * self.n_substeps
        self.episode_length = int(cfg.episode_length)
        self.max_delta = np.float32(cfg.max_delta)
        self.ws_low = np.asarray(cfg.workspace_low, np.float32)
        self.ws_high = np.asarray(cfg.workspace_high, np.float32)
        self.goal_low = np.asarray(cfg.goal_low, np.float32)
        self.goal_high = np.asarray(cfg.goal_high, np.float32)
        self.threshold = float(cfg.distance_threshold)
        self.sensors = obs_lib.SensorLayout.from_model(self.model)
        self.limits = limit_rules.from_config(np, cfg)  # the robot's rules in `step` (None: off)
        self.home_qpos, self.home_mocap = home_state(self.model)
        self._goal = np.zeros((NUM_ARMS, 3), np.float32)
        self._set_state(self.home_qpos)

    # -- rules (`mjx_envs.rules` with xp = numpy) -----------------------------------------------

    def sample_goal(self, rng: np.random.Generator) -> np.ndarray:
        """A desired goal [2, 3] drawn from ``rng``."""
        return self.rules.goal(np, SAMPLER, rng).astype(np.float32)

    def sample_qpos(self, rng: np.random.Generator) -> np.ndarray:
        """An initial qpos [nq]: the home keyframe, the object placed from ``rng``."""
        return np.array(self.rules.init_qpos(np, SAMPLER, rng), np.float32)

    def compute_reward(self, achieved_goal, desired_goal, info=None) -> np.ndarray:
        """Per-arm reward [..., 2] for goals [..., 2, 3], as the JAX env's ``compute_reward``
        (``info``: a dict of goal-independent terms [..., 2]; missing terms count as 0)."""
        ag = np.asarray(achieved_goal, np.float32)
        dg = np.asarray(desired_goal, np.float32)
        return np.asarray(self.rules.reward(np, ag, dg, info), np.float32)

    def info_terms(self, arm_clearance) -> tuple[float, dict[str, np.ndarray]]:
        """(arm_contact 0/1, goal-independent reward terms) for an arm clearance, metres."""
        contact, info = self.rules.contact_terms(np, np.float32(arm_clearance))
        if self.config.intervention_penalty > 0:  # as `DualArmEnv.charge`, after `step`
            info["intervention_penalty"] = np.full(
                (NUM_ARMS,), -self.config.intervention_penalty * self.intervened, np.float32)
        return float(contact), {k: np.asarray(v, np.float32) for k, v in info.items()}

    def finger_ctrl(self, finger_cmd) -> np.ndarray:
        cfg = self.config
        if cfg.lock_fingers:
            opening = np.full((NUM_ARMS,), cfg.locked_opening, np.float32)
        else:
            opening = ((np.asarray(finger_cmd, np.float32) + np.float32(1.0)) * np.float32(0.5)
                       * np.float32(cfg.finger_stroke))
        return np.repeat(opening, 2)  # [l1, l2, r1, r2]

    # -- state ------------------------------------------------------------------------------------

    def _set_state(self, qpos) -> None:
        """Home targets, ``qpos`` at rest, sensors from ``mj_forward`` (as the C backend's init)."""
        m, d = self.model, self.data
        self._t = 0
        self.intervened = False
        self._target = self.home_mocap.copy()
        self._time = np.float32(0.0)
        self._qpos = np.array(qpos, np.float32).reshape(m.nq)
        self._qvel = np.zeros(m.nv, np.float32)
        self._act = np.zeros(m.na, np.float32)
        mujoco.mj_resetData(m, d)
        d.qpos[:] = self._qpos
        d.qvel[:] = self._qvel
        d.mocap_pos[:NUM_ARMS] = self._target
        mujoco.mj_forward(m, d)
        self._sens = np.asarray(d.sensordata, np.float32).copy()

    def _result(self) -> StepResult:
        obs, arm, obj = obs_lib.observe(np, self.sensors, self._sens, self.dt)
        ag = np.asarray(self.rules.achieved_goal(arm, obj), np.float32)
        dist = self.rules.goal_distance(np, ag, self._goal)
        clearance = float(obs_lib.arm_clearance(np, arm["link_points"]))
        return StepResult(observation=np.asarray(obs, np.float32), achieved_goal=ag,
                          desired_goal=self._goal.copy(),
                          link_points=np.asarray(arm["link_points"], np.float32),
                          target=self._target.copy(),
                          success=bool(self.rules.success(np, ag, self._goal)),
                          goal_distance=dist.astype(np.float32), arm_clearance=clearance,
                          step=self._t)

    # -- API ------------------------------------------------------------------------------------

    def reset(self, rng: np.random.Generator | None = None, goal=None, qpos=None) -> StepResult:
        """Targets at the home mocap, a new goal and initial state: drawn from ``rng`` (goal
        first, then the object's placement) unless given (``goal`` [2, 3], ``qpos`` [nq])."""
        if goal is None or qpos is None:
            rng = rng if rng is not None else np.random.default_rng()
            goal = self.sample_goal(rng) if goal is None else goal
            qpos = self.sample_qpos(rng) if qpos is None else qpos
        self._goal = np.asarray(goal, np.float32).reshape(NUM_ARMS, 3).copy()
        self._set_state(qpos)
        return self._result()

    def command_targets(self, action) -> tuple[np.ndarray, np.ndarray]:
        """(new targets [2, 3], finger ctrl [4]) that ``action`` [8] would command."""
        a = np.clip(np.asarray(action, np.float32).reshape(NUM_ARMS, 4), -1.0, 1.0)
        target = np.clip(self._target + self.max_delta * a[:, :3], self.ws_low, self.ws_high)
        return target.astype(np.float32), self.finger_ctrl(a[:, 3])

    def step(self, action) -> StepResult:
        """One control step from a policy action [8] in [-1, 1] (clipped), as the trainer's env
        (under the config's ``robot_limits`` too; the robot client applies its own instead:
        `command_targets`, its safety layer, `step_targets`)."""
        target, ctrl = self.command_targets(action)
        self.intervened = False  # whether the rules changed a target (`info_terms`)
        if self.limits is not None:  # as the trainer's env under robot_limits
            links, tool = limit_rules.measured(np, self.sensors, self._sens, self.dt)
            target, _, flags = limit_rules.apply(np, self.limits, self._target, target, links,
                                                 tool, np.zeros((NUM_ARMS,), np.float32))
            self.intervened = bool(flags["workspace"] or flags["speed"] or flags["clearance"])
            ctrl = limit_rules.finger_opening(np, self.limits, ctrl)
        return self.step_targets(target, ctrl)

    def step_targets(self, target, ctrl) -> StepResult:
        """One control step towards Cartesian targets [2, 3] with finger ctrl [4]: what the
        safety layer sends (it may have changed the policy's targets)."""
        m, d = self.model, self.data
        self._target = np.asarray(target, np.float32).reshape(NUM_ARMS, 3)
        ctrl = np.asarray(ctrl, np.float32).reshape(m.nu)
        if self.exact:
            mujoco.mj_resetData(m, d)
            d.time = float(self._time)
            d.qpos[:] = self._qpos
            d.qvel[:] = self._qvel
            if m.na:
                d.act[:] = self._act
        for _ in range(self.n_substeps):
            d.ctrl[:] = ctrl
            d.mocap_pos[:NUM_ARMS] = self._target
            mujoco.mj_step(m, d)
        self._time = np.float32(d.time)
        self._qpos = np.asarray(d.qpos, np.float32).copy()
        self._qvel = np.asarray(d.qvel, np.float32).copy()
        self._act = np.asarray(d.act, np.float32).copy()
        self._sens = np.asarray(d.sensordata, np.float32).copy()
        self._t += 1
        return self._result()

    @property
    def target(self) -> np.ndarray:
        return self._target.copy()

    @property
    def goal(self) -> np.ndarray:
        return self._goal.copy()

