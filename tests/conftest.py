"""Shared test setup: CPU only, persistent compilation cache, and the helpers the test modules
share (`from tests.conftest import ...`): the tiny training config `TINY` on the toy env's
episodes of `T` steps, `tree_equal`, `run_options`, and `random_batch` (an update batch of
HIDDEN-sized networks' inputs)."""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("MUJOCO_GL", "egl")   # headless rendering, as the CLIs that render set it

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from daddpg_jax.algo.config import TrainConfig  # noqa: E402

jax.config.update("jax_compilation_cache_dir",
                  os.environ.get("DADDPG_JAX_CACHE", os.path.expanduser("~/.cache/daddpg_jax_jit")))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)

T = 10
"""episode length of the toy env in the trainer tests"""

TINY = TrainConfig(hidden=(32, 32), num_envs=4, n_cycles=3, n_batches=4, batch_size=32,
                   buffer_size=20 * T * 4, n_test_episodes=16, seed=0)
"""a training config that runs an epoch on the toy env in a second (tests vary it with
TINY.replace(...))"""

LEARN = TrainConfig(hidden=(64, 64), num_envs=4, n_cycles=10, n_batches=20, batch_size=128,
                    buffer_size=200_000, n_test_episodes=100, seed=0)
"""the toy-reach learning check (one and two devices): toy_env.make(**LEARN_ENV), 6 epochs"""
LEARN_ENV = dict(episode_length=T, threshold=0.03, goal_range=0.1)

OBS, B = 25, 16
"""observation size per arm (the toy env's and reach's), rows of `random_batch`"""
HIDDEN = (16, 16)
"""hidden layers of the networks in the loss tests"""


def tree_equal(a, b) -> bool:
    """Same tree structure and leaves of equal shape and values (bit for bit)."""
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return (jax.tree.structure(a) == jax.tree.structure(b) and len(la) == len(lb)
            and all(np.array_equal(np.asarray(x), np.asarray(y))
                    for x, y in zip(la, lb, strict=True)))


def run_options(run_dir, env=None, **kw):
    """`runner.RunOptions` for `run_dir`, training on `env` (e.g. the toy env) instead of the
    task's env when given (``RunOptions.make_env``); other fields as keywords."""
    # lazy: the runner (and the env package) load only in the test modules that train
    from daddpg_jax.running.runner import RunOptions

    make_env = None if env is None else (lambda cfg, overrides: env)
    return RunOptions(str(run_dir), make_env=make_env, **kw)


def random_batch(key, n_agents, b=B):
    """A normalized update batch: o, o2 [b, 2, OBS], g [b, 2, 3], a [b, 8], r [n_agents, b]."""
    ks = jax.random.split(key, 5)
    return dict(o=jax.random.normal(ks[0], (b, 2, OBS)), o2=jax.random.normal(ks[1], (b, 2, OBS)),
                g=jax.random.normal(ks[2], (b, 2, 3)),
                a=jax.random.uniform(ks[3], (b, 8), minval=-1, maxval=1),
                r=-jax.random.bernoulli(ks[4], 0.5, (n_agents, b)).astype(jnp.float32))


def call_main(main, argv) -> int:
    """Runs a console script's ``main(argv)`` in this process (no fresh interpreter, no JAX
    import per call) and returns its exit code as a shell would see it, argparse's SystemExit
    included. Read what it printed with pytest's ``capsys``."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) or e.code is None else 1
    return 0 if code is None else code


@pytest.fixture
def arm_recorder(monkeypatch):
    """An independent recorder of every command a simulated cell receives in the test
    (tests/arm_recorder.py); a command outside the expected limits fails the test."""
    from tests.arm_recorder import ArmRecorder, install  # lazy: only the robot-side tests

    rec = ArmRecorder()
    install(monkeypatch, rec)
    yield rec
    assert not rec.violations, "commands outside the limits: " + "; ".join(rec.violations[:5])
