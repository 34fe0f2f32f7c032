"""DADDPG (multi-agent DDPG + HER) for two cooperating arms, in JAX."""

from daddpg_jax.algo.config import TrainConfig, preset, replay_ratio

__all__ = ["TrainConfig", "preset", "replay_ratio"]
