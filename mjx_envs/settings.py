"""Every task's settings, as plain data, in one place (standard library only: no JAX, NumPy or
MuJoCo at import).

`TaskConfig` holds the fields every task has; `ObjectTaskConfig` adds the object's initial and
goal pose ranges (push, pickup, pot); `LiftTaskConfig` adds the training-only task-distribution
options of the lifting tasks (pickup, pot: `TRAINING_ONLY_FIELDS`, switched off for test
episodes by `TaskConfig.training_only_off`). Each task's values are declared in its module
(`mjx_envs/tasks/<task>.py`) and registered (`mjx_envs.registry`, which owns what is derived
from the tasks: the tables ``TASKS``, ``TASK_SETTINGS`` and ``OBJECTS``, `default_config`,
`task_config`, `saved_config`, `test_overrides`). Fields are declared with
`mjx_envs.schema.spec`: type, valid range and docstring, used by validation and ``--help``.
"""

from __future__ import annotations

import dataclasses

from mjx_envs.schema import (
    ConfigError,
    fields,
    finalize,
    spec,
)

PHYSICS_VERSION = 3
"""Version of the simulated physics (the MJCF scenes in assets/ and how the engines step them):
the current one, the scenes as shipped. `mjx_envs.model` keeps the history (what each version
changed, `physics_changed`) and builds the older scenes, so that a run or a policy file acts
with the physics it was trained on (its record: config.json's and the export's
``physics_version``, absent = 1; `recorded_physics_version`). See docs/MJX_VS_C.md."""


LATEST_PHYSICS_VERSION = 9
"""The newest physics version a run may ask for (``--env physics_version=N``). Versions 4 (the
finger boxes of the grasp pairs as box-shaped convex meshes: the same contact points on both
engines at any tilt; `mjx_envs.model.PHYSICS_V4`), 5 (that, and MJX's box-on-table contacts
at every penetrating corner, as in C; `mjx_envs.model.PHYSICS_V5`) and 6 (that, and the C
engine's line search to 50 iterations; `mjx_envs.model.PHYSICS_V6`) and 7 (that, and in pick up
every finger pair on the mesh copy; `mjx_envs.model.PHYSICS_V7`) and 8 (version 6, and in pick
up the finger pairs with the bar's caps on the mesh copy; `mjx_envs.model.PHYSICS_V8`) and 9
(that, and the C engine's pot handle pairs stiffer; `mjx_envs.model.PHYSICS_V9`) are opt-in
until their
MJX -> C measurement (docs/MJX_VS_C.md) makes one the default; new runs get `PHYSICS_VERSION`."""


def recorded_physics_version(recorded) -> int:
    """The physics version of a record (config.json's or a policy export's
    ``physics_version``): absent (None) means 1, the version before it was recorded."""
    return 1 if recorded is None else int(recorded)


DEFAULT_TASK = "reach"
"""the task of a command or env that names none"""

PHYSICS = ("auto", "mjx", "c")
"""physics backends: auto = MJX on an accelerator, MuJoCo's C engine on a CPU"""
ENGINES = PHYSICS[1:]
MJX_CPU_CHUNK = 32
"""episodes per batch for MJX on a CPU (`daddpg-evaluate`, and the trainer's test episodes):
its contact scenes have hung at batches of 100 and 256 and run at 64 and below (intermittently,
so no limit is proven safe; `daddpg-evaluate` backs it with a watchdog)"""


@dataclasses.dataclass(frozen=True)
class TaskConfig:
    """Settings of a task (reach uses exactly these; object tasks add `ObjectTaskConfig`'s)."""

    scene: str = spec("scene_reach.xml", "MJCF scene file in assets/", nonempty=True)
    episode_length: int = spec(50, "control steps per episode (fixed; no early termination)",
                               low=2)
    n_substeps: int = spec(4, "physics steps per control step", low=1)
    timestep: float = spec(0.01, "physics timestep, seconds (overrides the MJCF option)",
                           low=0.0, low_open=True)
    cone: str = spec("elliptic", "friction cone: 'elliptic' holds grasps better; 'pyramidal' "
                     "where a scene has no contacts (MJX 3.17's elliptic solver fails on a "
                     "model without contacts)", choices=("elliptic", "pyramidal"))
    physics_version: int = spec(PHYSICS_VERSION, "physics version of the simulated scene "
                                "(mjx_envs.settings.PHYSICS_VERSION: the current one; 1: the "
                                "contacts before the engines were made to agree; 2: before MJX "
                                "returned each box-box contact point once; kept so that older "
                                "runs and policy files act with the physics they were trained "
                                "on; 4-9: opt-in, up to "
                                "mjx_envs.settings.LATEST_PHYSICS_VERSION; see "
                                "mjx_envs.model)", low=1,
                                high=LATEST_PHYSICS_VERSION)
    max_delta: float = spec(0.05, "largest move of a gripper target per control step along "
                            "each axis, metres", low=0.0, low_open=True)
    lock_fingers: bool = spec(True, "ignore the finger command and hold the fingers at "
                              "locked_opening")
    locked_opening: float = spec(0.0, "finger opening while locked, metres", low=0.0)
    finger_stroke: float = spec(0.04, "opening of one finger at command +1, metres", low=0.0)
    distance_threshold: float = spec(0.02, "success radius of each arm's achieved goal, "
                                     "metres", low=0.0, low_open=True)
    goal_scale: float = spec(1.0, "scale of the per-arm goal term -(d_i >= threshold)",
                             low=0.0)
    team_scale: float = spec(0.0, "scale of the team term: -team_scale for both arms unless "
                             "every arm succeeds", low=0.0)
    obs_noise: float = spec(0.0, "observation perturbation (mjx_envs/perturb.py): std, m, of "
                            "Gaussian noise on each arm's object point and gripper position, "
                            "every step; 0 = off", low=0.0)
    obs_dropout: float = spec(0.0, "observation perturbation: probability per step that the "
                              "object observation stays at its last value (occlusion); 0 = "
                              "off", low=0.0, high=1.0)
    obs_bias: float = spec(0.0, "observation perturbation: length, m, of one offset of the "
                           "object positions per episode in a random direction; 0 = off",
                           low=0.0)
    obs_period: int = spec(0, "observation perturbation: a new observation every k control "
                           "steps, the last one held in between; 0 or 1 = every step", low=0)
    latency: int = spec(0, "action perturbation: actions applied k control steps late (no "
                        "motion before the first arrives); 0 = off", low=0)
    action_history: int = spec(0, "observation: each arm's own last k actions (newest first, "
                                "zeros before the first step) appended to its observation, "
                                "25 + 4 k values per arm (mjx_envs/observation.py); lets a "
                                "policy see the actions that latency still holds back; kept in "
                                "test episodes and exports (the policy's input); 0 = off",
                                low=0, high=8)
    perturb_exact: bool = spec(False, "false: the perturbation and randomization fields "
                               "(obs_*, latency and those of RANDOMIZATION_FIELDS) are bounds, "
                               "each episode draws its values up to them (training "
                               "randomization); true: every episode uses them exactly "
                               "(evaluation under a perturbation)")
    base_offset: float = spec(0.0, "physics randomization (mjx_envs/randomize.py): length, m, "
                              "of each arm's base offset in a random direction (calibration "
                              "error; the policy's targets and gripper readings stay in the "
                              "nominal frame); 0 = off", low=0.0, high=0.05)
    base_yaw: float = spec(0.0, "physics randomization: each arm's base turned about the "
                           "vertical, degrees (bound: uniform in [-|v|, |v|]); 0 = off",
                           low=-10.0, high=10.0)
    finger_force: float = spec(0.0, "physics randomization: finger servo stiffness and force "
                               "limit x (1 + v) (bound: v uniform in [-|v|, |v|]); 0 = off",
                               low=-0.9, high=0.9)
    action_scale: float = spec(0.0, "physics randomization: the gripper's Cartesian step per "
                               "action x (1 + v) (bound: v uniform in [-|v|, |v|]); 0 = off",
                               low=-0.9, high=0.9)
    arm_contact_penalty: float = spec(0.0, "per-arm penalty when the arms come closer than "
                                      "arm_clearance (goal-independent)", low=0.0)
    arm_clearance: float = spec(0.01, "surface gap between the arms' link capsules under which "
                                "arm_contact is set, metres", low=0.0)
    workspace_low: tuple = spec(((0.12, -0.14, 0.41), (0.12, -0.36, 0.41)),
                                "lower corner of each arm's target box (left, right), world "
                                "metres", length=(2, 3))
    workspace_high: tuple = spec(((0.40, 0.36, 0.65), (0.40, 0.14, 0.65)),
                                 "upper corner of each arm's target box (left, right), world "
                                 "metres", length=(2, 3))
    goal_low: tuple = spec(((0.18, -0.08, 0.43), (0.18, -0.30, 0.43)),
                           "lower corner of each arm's goal region (reach)", length=(2, 3))
    goal_high: tuple = spec(((0.34, 0.30, 0.60), (0.34, 0.08, 0.60)),
                            "upper corner of each arm's goal region (reach)", length=(2, 3))
    robot_limits: tuple = spec((), "the robot's limits applied to every target as the robot "
                               "client's safety layer applies them (mjx_envs/limit_rules.py; "
                               "set by daddpg-train --limits FILE): box low [2 x 3], box high "
                               "[2 x 3], max_step m, min_clearance m, finger_low m, "
                               "finger_high m (16 numbers); () = off")
    intervention_penalty: float = spec(0.0, "with robot_limits: per-arm penalty for each control "
                                       "step in which the robot's rules change a target "
                                       "(workspace clamp, speed cap or arm clearance, either "
                                       "arm, as the robot client counts interventions; the "
                                       "finger range is not charged; goal-independent; "
                                       "daddpg-train --intervention-penalty C); 0 = off",
                                       low=0.0)

    def __post_init__(self):
        finalize(self)
        for lo, hi in (("workspace_low", "workspace_high"), ("goal_low", "goal_high")):
            _check_ordered(self, lo, hi)
        if self.intervention_penalty > 0 and not self.robot_limits:
            raise ConfigError("intervention_penalty needs robot_limits (daddpg-train --limits "
                              "FILE --intervention-penalty C)")

    def training_only_off(self) -> dict:
        """The overrides that give the standard task (test episodes): every field of
        `TRAINING_ONLY_FIELDS` this config has, set to 0 (off)."""
        names = fields(self)
        return {name: type(getattr(self, name))(0) for name in TRAINING_ONLY_FIELDS
                if name in names}


@dataclasses.dataclass(frozen=True)
class ObjectTaskConfig(TaskConfig):
    """`TaskConfig` plus the ranges of the object's initial and goal poses."""

    init_low: tuple = spec((0.245, -0.005, -0.10), "lower bound of the object's initial pose "
                           "on the table: (x, y, yaw) in m, m, rad", length=3)
    init_high: tuple = spec((0.255, 0.005, 0.10), "upper bound of the object's initial pose "
                            "on the table", length=3)
    target_low: tuple = spec((0.25, 0.0, 0.0, -0.15), "lower bound of the object's goal pose: "
                             "(x, y, height above its resting height, yaw)", length=4)
    target_high: tuple = spec((0.25, 0.0, 0.0, 0.15), "upper bound of the object's goal pose",
                              length=4)
    target_radius: tuple = spec((0.0, 0.0), "(min, max) length of an extra horizontal offset "
                                "of the goal pose in a uniformly random direction: keeps goals "
                                "on the table away from the initial pose (push)", length=2,
                                low=0.0)

    object_mass: float = spec(0.0, "physics randomization: the object's mass and inertia x "
                              "(1 + v) (bound: v uniform in [-|v|, |v|]); 0 = off", low=-0.9,
                              high=0.9)
    object_size: float = spec(0.0, "physics randomization: every object geom's half-sizes + v, "
                              "m (bound: uniform in [-|v|, |v|]); the resting height and the "
                              "goals move by v; 0 = off", low=-0.01, high=0.01)
    object_friction: float = spec(0.0, "physics randomization: tangential friction of every "
                                  "contact pair with the object x (1 + v) (bound: v uniform in "
                                  "[-|v|, |v|]); 0 = off", low=-0.9, high=0.9)
    table_height: float = spec(0.0, "physics randomization: the table top's height + v, m "
                               "(bound: uniform in [-|v|, |v|]); the resting height and the "
                               "goals move by v (the grippers' workspace does not: within "
                               "1 cm they still reach the object); 0 = off", low=-0.01,
                               high=0.01)
    grasp_timeconst: float = spec(0.0, "physics randomization: the contact time constant "
                                  "(solref[0]) of every finger-object contact pair x (1 + v), "
                                  "so the grip's contact stiffness (~1/timeconst^2) x 0.59 to "
                                  "2.04 at v = 0.3 (bound: v uniform in [-|v|, |v|]); 0 = off",
                                  low=-0.5, high=0.5)

    def __post_init__(self):
        super().__post_init__()
        for lo, hi in (("init_low", "init_high"), ("target_low", "target_high")):
            _check_ordered(self, lo, hi)
        if self.target_radius[0] > self.target_radius[1]:
            raise ConfigError(f"target_radius must be (min, max), got {self.target_radius!r}")


@dataclasses.dataclass(frozen=True)
class LiftTaskConfig(ObjectTaskConfig):
    """`ObjectTaskConfig` plus two options of the training task distribution (pickup, pot),
    both off by default; test episodes use the standard task
    (`mjx_envs.registry.test_overrides`)."""

    goal_rest_fraction: float = spec(0.0, "training only: the fraction of episodes whose goal "
                                     "lies at the object's resting height on the table (goal "
                                     "height term 0) instead of lifted; 0 = off", low=0.0,
                                     high=1.0)
    grasp_start_fraction: float = spec(0.0, "training only: the fraction of episodes that "
                                       "start from a grasped state (both grippers closed on "
                                       "the object, recorded with the scripted controller when "
                                       "the env is built) instead of the standard initial "
                                       "state; 0 = off", low=0.0, high=1.0)
    n_grasp_states: int = spec(64, "grasped states recorded for grasp_start_fraction (each "
                               "from a different seed; used only when grasp_start_fraction > "
                               "0)", low=1)


RANDOMIZATION_FIELDS = ("object_mass", "object_size", "object_friction", "table_height",
                        "grasp_timeconst", "base_offset", "base_yaw", "finger_force",
                        "action_scale")
"""Physics randomization fields (mjx_envs/randomize.py); the first five exist in object tasks
only."""

TRAINING_ONLY_FIELDS = ("goal_rest_fraction", "grasp_start_fraction", "obs_noise",
                        "obs_dropout", "obs_bias", "obs_period", "latency",
                        *RANDOMIZATION_FIELDS)
"""Task fields that change only the training task distribution (and the observations and
actions of training episodes); test episodes turn them off (`TaskConfig.training_only_off`,
`mjx_envs.registry.test_overrides`)."""


def _flat(v):
    return [y for x in v for y in (_flat(x) if isinstance(x, tuple) else [x])]


def _check_ordered(cfg, lo: str, hi: str) -> None:
    if any(a > b for a, b in zip(_flat(getattr(cfg, lo)), _flat(getattr(cfg, hi)), strict=False)):
        raise ConfigError(f"{lo} must not exceed {hi} ({getattr(cfg, lo)!r} > "
                          f"{getattr(cfg, hi)!r})")


# Contact tasks: a 0.005 s timestep (contacts at 0.01 s tunnel and eject the bar at 1.25 m/s
# pushes) with 8 substeps keeps the control period at 0.04 s; success radius 0.05 m (paper 4.1).
CONTACT_DEFAULTS = dict(cone="elliptic", timestep=0.005, n_substeps=8, distance_threshold=0.05)
"""Settings shared by the contact tasks (push, pickup, pot; ``TaskConfig(**CONTACT_DEFAULTS,
...)`` in a task's module)."""
