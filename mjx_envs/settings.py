"""Every task's settings, as plain data, in one place (standard library only: no JAX, NumPy or
MuJoCo at import).

`TaskConfig` holds the fields every task has; `ObjectTaskConfig` adds the object's initial and
goal pose ranges (push, pickup, pot); `LiftTaskConfig` adds the training-only task-distribution
options of the lifting tasks (pickup, pot: `TRAINING_ONLY_FIELDS`, switched off for test
episodes by `test_overrides`). Each task's values are declared in its module
(`mjx_envs/tasks/<task>.py`) and registered (`mjx_envs.registry`); `TASKS`, `TASK_SETTINGS`
and `OBJECTS` here are derived from the registry. The JAX env (`mjx_envs.make`), the NumPy
simulator (`mjx_envs.numpy_env`), the Gymnasium adapter (`mjx_envs.gym_env`) and the robot
client all read them from here. Fields are declared with
`mjx_envs.schema.spec`: type, valid range and docstring, used by validation and ``--help``.
"""

from __future__ import annotations

import dataclasses

from mjx_envs import registry
from mjx_envs.schema import ConfigError, fields, finalize, from_dict, spec

PHYSICS_VERSION = 3
"""Version of the simulated physics (the MJCF scenes in assets/ and how the engines step them).
1: up to 2026-12-04 (5 mm margin on every finger pair, thin finger boxes, finger-pot body and
finger-bar middle/cap friction 0.5 / 1.5). 2: finger boxes 5 mm larger on every side with margin
0 (MJX's box-box collision ignores contact margins), friction 0.05 on the finger pairs that
only block (pot body; bar middle and caps). 3: MJX returns each box-box contact point once, as
the C engine does (the scenes' numeric `MJX_UNIQUE_CONTACTS`, which the C engine ignores), and
pot's finger-handle contacts are softer (solimp 0.9 0.95); on the C engine, push and pick up act
in versions 2 and 3 alike. See docs/TASKS.md, "MJX vs C".
The scenes in assets/ are the current version; `mjx_envs.model.load_model` builds the older
ones from them (version 2: `PHYSICS_V2`; version 1: that and `PHYSICS_V1`), so that a run or a
policy file acts with the physics it was trained on (its record: config.json's and the export's
``physics_version``, absent = 1)."""


def physics_changed(version: int, task: str, engine: str | None = None) -> bool:
    """Whether physics `version` changed how `task` acts on `engine` ("c", "mjx"; None: either):
    versions 2 and 3 changed the finger contacts, so every task with an object (reach and unknown
    tasks: no); on the C engine version 3 changed only the scenes `PHYSICS_V2` names."""
    if version == 3 and engine == "c":
        return (registry.is_task(task) and registry.get(task).config.scene
                in PHYSICS_V2["pair_solimp"])
    return (version in (2, 3) and registry.is_task(task)
            and registry.get(task).object is not None)

MJX_UNIQUE_CONTACTS = "mjx_unique_contact_points"
"""Name of a scene's custom numeric: 1 = MJX returns each contact point of a box-box or
convex-convex pair once, as the C engine does (`mjx_envs.physics.mjx_contacts`)."""

PHYSICS_V2 = dict(
    pair_solimp={
        "scene_pot.xml": {"pot_handle_l": (0.95, 0.99, 0.001, 0.5, 2.0),
                          "pot_handle_r": (0.95, 0.99, 0.001, 0.5, 2.0)},
    },
)
"""Physics version 2, as differences from the shipped scenes besides the numeric
`MJX_UNIQUE_CONTACTS` (which it lacks): per scene the solimp of the finger pairs with the named
object geoms."""

PHYSICS_V1 = dict(
    finger_size=(0.012, 0.006, 0.035),
    finger_pair_margin=0.005,
    pair_friction={
        "scene_pickup.xml": {"bar_mid": (1.5, 1.5, 0.01, 0.0001, 0.0001),
                             "bar_cap_l": (1.5, 1.5, 0.01, 0.0001, 0.0001),
                             "bar_cap_r": (1.5, 1.5, 0.01, 0.0001, 0.0001)},
        "scene_pot.xml": {"pot_body": (0.5, 0.5, 0.005, 0.0001, 0.0001)},
    },
)
"""Physics version 1, as differences from the shipped scenes: the half-sizes of every finger
box (geoms ``<arm>_finger1/2``), the margin of every contact pair with a finger, and per scene
the friction of the finger pairs with the named object geoms."""


def recorded_physics_version(recorded) -> int:
    """The physics version of a record (config.json's or a policy export's
    ``physics_version``): absent (None) means 1, the version before it was recorded."""
    return 1 if recorded is None else int(recorded)


def physics_version_note(recorded, task: str, simulated: int | None = None,
                         engine: str | None = None) -> str | None:
    """None when a run or a policy file of `task`, trained with physics version `recorded`, is
    simulated (version `simulated`, default `PHYSICS_VERSION`) with physics that act alike on
    `engine` (None: on either engine); else one line saying which version it was trained with and
    which one simulates it."""
    version = recorded_physics_version(recorded)
    now = PHYSICS_VERSION if simulated is None else int(simulated)
    lo, hi = sorted((version, now))
    if not any(physics_changed(v, task, engine) for v in range(lo + 1, hi + 1)):
        return None
    return (f"trained with physics version {version}, simulated here with version {now} "
            f"(docs/TASKS.md, 'MJX vs C'): its success can differ from the figures logged in "
            f"training")


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
                                "on)", low=1, high=PHYSICS_VERSION)
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

    def __post_init__(self):
        finalize(self)
        for lo, hi in (("workspace_low", "workspace_high"), ("goal_low", "goal_high")):
            _check_ordered(self, lo, hi)


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

    def __post_init__(self):
        super().__post_init__()
        for lo, hi in (("init_low", "init_high"), ("target_low", "target_high")):
            _check_ordered(self, lo, hi)
        if self.target_radius[0] > self.target_radius[1]:
            raise ConfigError(f"target_radius must be (min, max), got {self.target_radius!r}")


@dataclasses.dataclass(frozen=True)
class LiftTaskConfig(ObjectTaskConfig):
    """`ObjectTaskConfig` plus two options of the training task distribution (pickup, pot),
    both off by default; test episodes use the standard task (`test_overrides`)."""

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
                        "base_offset", "base_yaw", "finger_force", "action_scale")
"""Physics randomization fields (mjx_envs/randomize.py); the first four exist in object tasks
only."""

TRAINING_ONLY_FIELDS = ("goal_rest_fraction", "grasp_start_fraction", "obs_noise",
                        "obs_dropout", "obs_bias", "obs_period", "latency",
                        *RANDOMIZATION_FIELDS)
"""Task fields that change only the training task distribution (and the observations and
actions of training episodes); `test_overrides` turns them off for test episodes."""


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


def __getattr__(name: str):
    """The tables derived from the task registry (`mjx_envs.registry`; read when asked for, so
    a task registered later is in them): ``TASKS`` (names), ``TASK_SETTINGS`` (name -> settings
    defaults) and ``OBJECTS`` (name -> (free joint, body, point sites), object tasks only)."""
    if name == "TASKS":
        return registry.task_names()
    if name == "TASK_SETTINGS":
        return {t.name: t.config for t in registry.tasks()}
    if name == "OBJECTS":
        return {t.name: t.object for t in registry.tasks() if t.object is not None}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def check_task(task: str) -> None:
    registry.get(task)


def default_config(task: str) -> TaskConfig:
    """The task's settings (a frozen dataclass)."""
    return registry.get(task).config


def test_overrides(task: str) -> dict:
    """The env overrides that give the standard task for test episodes: every field of
    `TRAINING_ONLY_FIELDS` that the task has, set to 0 (off); {} for tasks this module does
    not know."""
    if not registry.is_task(task):
        return {}
    cfg = registry.get(task).config
    names = fields(cfg)
    return {name: type(getattr(cfg, name))(0) for name in TRAINING_ONLY_FIELDS if name in names}



def replace_config(cfg: TaskConfig, **overrides) -> TaskConfig:
    """``dataclasses.replace`` with a clear error for unknown fields; values are validated."""
    names = fields(cfg)
    unknown = sorted(set(overrides) - set(names))
    if unknown:
        raise ConfigError(f"unknown config field(s) {unknown} for {type(cfg).__name__}; "
                          f"valid: {sorted(names)}")
    return dataclasses.replace(cfg, **overrides)


def task_config(task: str, **overrides) -> TaskConfig:
    """The task's settings with `overrides` applied (lists from JSON become tuples)."""
    return replace_config(default_config(task), **overrides)


def saved_config(task: str, saved=None) -> TaskConfig:
    """The task's settings holding the values in `saved`: a dict (e.g. a policy export's env
    settings; keys that are not fields, such as ``dt``, are ignored; fields it lacks keep the
    task's values) or a whole config of the task's class (returned as is)."""
    base = default_config(task)
    if saved is None:
        return base
    if isinstance(saved, TaskConfig):
        if not isinstance(saved, type(base)):
            raise TypeError(f"task {task!r} needs a {type(base).__name__}, got "
                            f"{type(saved).__name__}")
        return saved
    names = fields(base)
    return replace_config(base, **{k: v for k, v in dict(saved).items() if k in names})


def config_from_dict(task: str, d: dict) -> TaskConfig:
    """The task's config class filled from a JSON dict (e.g. a policy export's settings)."""
    return from_dict(type(default_config(task)), d)
