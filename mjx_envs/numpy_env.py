"""Plain-MuJoCo, NumPy-only stand-in for the real dual-arm robot (no JAX).

The robot client (``experiments/robot_client.py``) drives this env the way it would drive the
real robot: read sensors, build observations with ``mjx_envs.observation`` (``xp = numpy``),
ask the policy service for an action, move the Cartesian targets. The step mirrors
``mjx_envs.core.DualArmEnv.step`` on the C engine:

- the same MJCF scene from ``assets/`` with the task's timestep and friction cone;
- target = previous target + ``max_delta * clip(a[:3], -1, 1)``, clipped to the arm's
  workspace box; finger servo targets from ``a[3]`` (or held at ``locked_opening``);
- ``mujoco.mj_step`` ``n_substeps`` times holding ctrl and mocap; sensors are read right after
  the last substep (MuJoCo evaluates them before that substep's final integration, as in the
  trainer's engines);
- goals sampled uniformly (NumPy) from the same per-arm goal region as the task.

``exact=True`` (default) also repeats the C backend's bookkeeping: state kept in float32
between control steps, and every control step starts from ``mj_resetData`` + that state (so the
solver warmstart is zero, as ``mujoco.rollout`` does). Then the trajectory equals the trainer's
C-engine env to float32 rounding. ``exact=False`` keeps one float64 ``MjData`` running, like a
real simulator would.

Only the reach task is supported (object tasks need their object placement and goal sampling
ported; see docs/DEPLOYMENT.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional

import mujoco
import numpy as np

from mjx_envs import observation as obs_lib

ASSETS = Path(__file__).resolve().parent.parent / "assets"
NUM_ARMS = 2
SUPPORTED_TASKS = ("reach",)

# settings of the reach task's default_config() (mjx_envs/tasks/reach.py + core.TaskConfig); the
# policy export carries the values a run actually used, which take precedence
REACH_SETTINGS: dict[str, Any] = dict(
    scene="scene_reach.xml", episode_length=50, n_substeps=4, timestep=0.01, cone="pyramidal",
    max_delta=0.05, lock_fingers=True, locked_opening=0.0, finger_stroke=0.04,
    distance_threshold=0.02, arm_clearance=0.01,
    workspace_low=[[0.12, -0.14, 0.41], [0.12, -0.36, 0.41]],
    workspace_high=[[0.40, 0.36, 0.65], [0.40, 0.14, 0.65]],
    goal_low=[[0.18, -0.08, 0.43], [0.18, -0.30, 0.43]],
    goal_high=[[0.34, 0.30, 0.60], [0.34, 0.08, 0.60]],
)


def load_model(scene: str, timestep: float, cone: str) -> mujoco.MjModel:
    """The scene with the task's timestep and cone (same overrides as ``core.load_model``)."""
    path = ASSETS / scene
    if not path.exists():
        raise FileNotFoundError(f"scene {path} not found")
    m = mujoco.MjModel.from_xml_path(str(path))
    m.opt.timestep = float(timestep)
    cones = {"elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC, "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL}
    if cone not in cones:
        raise ValueError(f"cone must be one of {sorted(cones)}, got {cone!r}")
    m.opt.cone = cones[cone]
    return m


@dataclass
class StepResult:
    """What the robot knows after a control step (all NumPy, float32)."""

    observation: np.ndarray  # [2, 25]
    achieved_goal: np.ndarray  # [2, 3]
    desired_goal: np.ndarray  # [2, 3]
    link_points: np.ndarray  # [2, 5, 3] shoulder, elbow, wrist 1, flange, tool centre
    target: np.ndarray  # [2, 3] current Cartesian targets (mocap)
    success: bool
    goal_distance: np.ndarray  # [2]
    arm_clearance: float
    step: int


class NumpyDualArmEnv:
    """One env, stepped with MuJoCo's C engine from NumPy; see the module docstring."""

    def __init__(self, settings: Optional[Mapping[str, Any]] = None, task: str = "reach",
                 exact: bool = True):
        if task not in SUPPORTED_TASKS:
            raise NotImplementedError(f"the NumPy env supports {SUPPORTED_TASKS}, not {task!r}")
        s = dict(REACH_SETTINGS)
        s.update(settings or {})
        self.settings = s
        self.task = task
        self.exact = bool(exact)
        self.model = load_model(s["scene"], s["timestep"], s["cone"])
        self.data = mujoco.MjData(self.model)
        self.n_substeps = int(s["n_substeps"])
        self.dt = float(s["timestep"]) * self.n_substeps
        self.episode_length = int(s["episode_length"])
        self.max_delta = np.float32(s["max_delta"])
        self.ws_low = np.asarray(s["workspace_low"], np.float32)
        self.ws_high = np.asarray(s["workspace_high"], np.float32)
        self.goal_low = np.asarray(s["goal_low"], np.float32)
        self.goal_high = np.asarray(s["goal_high"], np.float32)
        self.threshold = float(s["distance_threshold"])
        self.sensors = obs_lib.SensorLayout.from_model(self.model)
        key = self.model.key("home")
        self.home_qpos = np.asarray(key.qpos, np.float32)
        self.home_mocap = np.asarray(key.mpos, np.float32).reshape(-1, 3)[:NUM_ARMS]
        self._goal = np.zeros((NUM_ARMS, 3), np.float32)
        self._target = self.home_mocap.copy()
        self._t = 0
        # float32 mirror of the C backend's state
        self._time = np.float32(0.0)
        self._qpos = self.home_qpos.copy()
        self._qvel = np.zeros(self.model.nv, np.float32)
        self._act = np.zeros(self.model.na, np.float32)
        self._sens = np.zeros(self.model.nsensordata, np.float32)

    # -- helpers --------------------------------------------------------------------------------

    def sample_goal(self, rng: np.random.Generator) -> np.ndarray:
        return rng.uniform(self.goal_low, self.goal_high).astype(np.float32)

    def finger_ctrl(self, finger_cmd) -> np.ndarray:
        s = self.settings
        if s["lock_fingers"]:
            opening = np.full((NUM_ARMS,), s["locked_opening"], np.float32)
        else:
            opening = ((np.asarray(finger_cmd, np.float32) + np.float32(1.0)) * np.float32(0.5)
                       * np.float32(s["finger_stroke"]))
        return np.repeat(opening, 2)  # [l1, l2, r1, r2]

    def _result(self) -> StepResult:
        sens = self._sens
        obs, arm, _obj = obs_lib.observe(np, self.sensors, sens, self.dt)
        ag = np.asarray(arm["grip_pos"], np.float32)  # reach: the tool centre points
        dist = np.linalg.norm(ag - self._goal, axis=-1)
        clearance = float(obs_lib.arm_clearance(np, arm["link_points"]))
        return StepResult(observation=obs, achieved_goal=ag, desired_goal=self._goal.copy(),
                          link_points=np.asarray(arm["link_points"], np.float32),
                          target=self._target.copy(), success=bool(np.all(dist < self.threshold)),
                          goal_distance=dist.astype(np.float32), arm_clearance=clearance,
                          step=self._t)

    # -- API ------------------------------------------------------------------------------------

    def reset(self, rng: Optional[np.random.Generator] = None, goal=None) -> StepResult:
        """Home pose, targets at the home mocap, a new goal (from ``rng`` or given)."""
        if goal is None:
            rng = rng if rng is not None else np.random.default_rng()
            goal = self.sample_goal(rng)
        self._goal = np.asarray(goal, np.float32).reshape(NUM_ARMS, 3)
        self._t = 0
        self._target = self.home_mocap.copy()
        self._time = np.float32(0.0)
        self._qpos = self.home_qpos.copy()
        self._qvel = np.zeros(self.model.nv, np.float32)
        self._act = np.zeros(self.model.na, np.float32)
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[:] = self._qpos
        d.qvel[:] = self._qvel
        d.mocap_pos[:NUM_ARMS] = self._target
        mujoco.mj_forward(m, d)
        self._sens = np.asarray(d.sensordata, np.float32).copy()
        return self._result()

    def command_targets(self, action) -> tuple[np.ndarray, np.ndarray]:
        """(new targets [2, 3], finger ctrl [4]) that ``action`` [8] would command."""
        a = np.clip(np.asarray(action, np.float32).reshape(NUM_ARMS, 4), -1.0, 1.0)
        target = np.clip(self._target + self.max_delta * a[:, :3], self.ws_low, self.ws_high)
        return target.astype(np.float32), self.finger_ctrl(a[:, 3])

    def step(self, action) -> StepResult:
        """One control step from a policy action [8] in [-1, 1] (clipped), as the trainer's env."""
        target, ctrl = self.command_targets(action)
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
