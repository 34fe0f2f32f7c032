"""The package's Python sources, for the code-hygiene tests (test_function_length,
test_imports): one walk over daddpg_jax/ and mjx_envs/."""

import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGES = ("daddpg_jax", "mjx_envs")


def sources(package: str):
    """(path, path relative to the repository, text) of every .py file under `package`, in a
    fixed order."""
    for dirpath, dirnames, filenames in os.walk(os.path.join(ROOT, package)):
        dirnames[:] = sorted(d for d in dirnames if d != "__pycache__")
        for name in sorted(f for f in filenames if f.endswith(".py")):
            path = os.path.join(dirpath, name)
            with open(path, encoding="utf-8") as f:
                yield path, os.path.relpath(path, ROOT), f.read()
