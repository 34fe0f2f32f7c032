"""The MJCF scenes as MuJoCo models (MuJoCo and NumPy only: no JAX).

The scenes ship inside the package: ``mjx_envs/assets`` (in a source tree a link to the
top-level ``assets/``) is read through ``importlib.resources``, so an installed wheel finds them
too. Both the JAX env (`mjx_envs.core`) and the NumPy simulator (`mjx_envs.numpy_env`) load
their model here.
"""

from __future__ import annotations

import contextlib
import importlib.resources
from collections.abc import Iterator
from pathlib import Path

import mujoco
import numpy as np

from mjx_envs import settings

NUM_ARMS = 2
CONES = {"elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC,
         "pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL}


def _assets():
    return importlib.resources.files("mjx_envs") / "assets"


def scenes() -> list[str]:
    """Names of the MJCF files shipped in ``mjx_envs/assets``."""
    assets = _assets()
    if not assets.is_dir():
        return []
    return sorted(p.name for p in assets.iterdir() if p.name.endswith(".xml"))


@contextlib.contextmanager
def scene_path(scene: str) -> Iterator[Path]:
    """A real file path of ``scene`` for the duration of the ``with`` block.

    Scenes include other files of the folder, so the whole assets folder is made available
    (``importlib.resources.as_file``; a plain installed package or source tree is used in place).
    Raises FileNotFoundError naming the available scenes when ``scene`` is not shipped.
    """
    assets = _assets()
    if not (assets / scene).is_file():
        raise FileNotFoundError(f"scene {scene!r} not found in the package's assets "
                                f"(mjx_envs/assets); available: {scenes()}")
    with importlib.resources.as_file(assets) as folder:
        yield Path(folder) / scene


def load_model(scene: str, timestep: float | None = None, cone: str | None = None,
               physics_version: int | None = None) -> mujoco.MjModel:
    """The scene's model with the task's ``timestep`` and friction ``cone`` (when given), in
    physics version ``physics_version`` (default: the current one, the scene as shipped; older
    ones apply `mjx_envs.settings`'s record of what they had instead, e.g. `PHYSICS_V1`)."""
    if cone is not None and cone not in CONES:
        raise ValueError(f"cone must be one of {sorted(CONES)}, got {cone!r}")
    version = settings.PHYSICS_VERSION if physics_version is None else int(physics_version)
    if not 1 <= version <= settings.PHYSICS_VERSION:
        raise ValueError(f"physics_version must be in [1, {settings.PHYSICS_VERSION}], got "
                         f"{physics_version!r}")
    with scene_path(scene) as path:
        if version == settings.PHYSICS_VERSION:
            m = mujoco.MjModel.from_xml_path(str(path))
        else:
            spec = mujoco.MjSpec.from_file(str(path))
            _physics_v2(spec, scene)
            if version == 1:
                _physics_v1(spec, scene)
            m = spec.compile()
    if timestep is not None:
        m.opt.timestep = float(timestep)
    if cone is not None:
        m.opt.cone = CONES[cone]
    return m


def _is_finger(name: str) -> bool:
    return name.endswith(("_finger1", "_finger2"))


def _physics_v2(spec: mujoco.MjSpec, scene: str) -> None:
    """Turns a shipped scene's spec (physics version 3) into version 2 (`PHYSICS_V2`): without
    the numeric that makes MJX return each box-box contact point once
    (`settings.MJX_UNIQUE_CONTACTS`), with version 2's finger-pair solimp."""
    for numeric in list(spec.numerics):
        if numeric.name == settings.MJX_UNIQUE_CONTACTS:
            spec.delete(numeric)
    _finger_pairs(spec, "solimp", settings.PHYSICS_V2["pair_solimp"].get(scene, {}))


def _finger_pairs(spec: mujoco.MjSpec, field: str, values: dict) -> None:
    """Sets ``field`` (e.g. "friction") of every finger pair with an object geom named in
    ``values`` to that geom's value."""
    for pair in spec.pairs:
        names = (pair.geomname1, pair.geomname2)
        if any(_is_finger(n) for n in names):
            for n in names:
                if n in values:
                    setattr(pair, field, values[n])


def _physics_v1(spec: mujoco.MjSpec, scene: str) -> None:
    """Turns a version-2 spec (`_physics_v2`) into version 1 (`PHYSICS_V1`)."""
    v1 = settings.PHYSICS_V1
    for geom in spec.geoms:
        if _is_finger(geom.name):
            geom.size = v1["finger_size"]
    for pair in spec.pairs:
        if any(_is_finger(n) for n in (pair.geomname1, pair.geomname2)):
            pair.margin = v1["finger_pair_margin"]
    _finger_pairs(spec, "friction", v1["pair_friction"].get(scene, {}))


def home_state(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """(qpos [nq], gripper targets [2, 3]) of the scene's ``home`` keyframe, float32."""
    key = model.key("home")
    qpos = np.asarray(key.qpos, np.float32)
    mocap = np.asarray(key.mpos, np.float32).reshape(-1, 3)[:NUM_ARMS]
    return qpos, mocap
