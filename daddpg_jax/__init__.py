"""DADDPG (multi-agent DDPG + HER) for two cooperating arms, in JAX.

``daddpg_jax.TrainConfig``, ``preset`` and ``replay_ratio`` are the trainer's
(`daddpg_jax.algo.config`), loaded when first asked for: the robot side
(`daddpg_jax.deploy`) imports this package without loading the trainer."""

__all__ = ["TrainConfig", "preset", "replay_ratio"]


def __getattr__(name: str):
    if name in __all__:
        from daddpg_jax.algo import config  # lazy: the robot side must not load the trainer

        return getattr(config, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
