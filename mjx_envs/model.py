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


def load_model(scene: str, timestep: float | None = None,
               cone: str | None = None) -> mujoco.MjModel:
    """The scene's model with the task's ``timestep`` and friction ``cone`` (when given)."""
    if cone is not None and cone not in CONES:
        raise ValueError(f"cone must be one of {sorted(CONES)}, got {cone!r}")
    with scene_path(scene) as path:
        m = mujoco.MjModel.from_xml_path(str(path))
    if timestep is not None:
        m.opt.timestep = float(timestep)
    if cone is not None:
        m.opt.cone = CONES[cone]
    return m


def home_state(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """(qpos [nq], gripper targets [2, 3]) of the scene's ``home`` keyframe, float32."""
    key = model.key("home")
    qpos = np.asarray(key.qpos, np.float32)
    mocap = np.asarray(key.mpos, np.float32).reshape(-1, 3)[:NUM_ARMS]
    return qpos, mocap
