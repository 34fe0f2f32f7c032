"""Stable-Baselines3 DDPG + HER against this trainer, side by side (docs/BENCHMARKS.md)."""
