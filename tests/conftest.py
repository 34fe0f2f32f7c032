"""Shared test setup: CPU only, persistent compilation cache, session-scoped envs."""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_compilation_cache_dir",
                  os.environ.get("DADDPG_JAX_CACHE", os.path.expanduser("~/.cache/daddpg_jax_jit")))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
