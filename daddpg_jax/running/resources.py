"""Sizes that cannot fit in memory are refused before anything is allocated.

A training state (replay buffer, networks, optimizer moments) or an evaluation batch whose
arrays alone exceed the memory of the device that holds them would fail inside XLA's allocator
(an error line, then JAX's atexit tracebacks) or push the machine into swap. Their size is
known exactly from shapes (``jax.eval_shape``), so :func:`check_fits` refuses them with one
line first. The memory available is the accelerator's ``bytes_limit`` when JAX reports one,
else the host's ``MemAvailable`` (and the cgroup's limit, if lower).
"""

from __future__ import annotations

import os

import jax
import numpy as np

from mjx_envs.schema import ConfigError


def tree_bytes(tree) -> int:
    """Total bytes of the arrays (or ``jax.ShapeDtypeStruct``s) of a pytree."""
    return int(sum(int(np.prod(x.shape)) * np.dtype(x.dtype).itemsize
                   for x in jax.tree.leaves(tree) if hasattr(x, "shape")))


def _host_available() -> int | None:
    avail = None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        with open("/sys/fs/cgroup/memory.max") as f:
            limit = f.read().strip()
        with open("/sys/fs/cgroup/memory.current") as f:
            used = int(f.read().strip())
        if limit.isdigit():
            room = int(limit) - used
            avail = room if avail is None else min(avail, room)
    except (OSError, ValueError):
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):
            return None
    return avail


def available_bytes(device=None) -> int | None:
    """Bytes the arrays of `device` (default: JAX's first device) may take: an accelerator's
    ``bytes_limit`` minus what is in use, else the host's available memory; None if unknown."""
    device = device or jax.devices()[0]
    if device.platform != "cpu":
        try:
            stats = device.memory_stats() or {}
        except Exception:  # noqa: BLE001 (backends without memory statistics)
            stats = {}
        if "bytes_limit" in stats:
            return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
    return _host_available()


def fmt_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def check_fits(what: str, nbytes: int, hint: str, available: int | None = None) -> None:
    """Raises ConfigError (one line) when `nbytes` exceed the memory available (`available`,
    default :func:`available_bytes`); `what` names the arrays, `hint` says which setting to
    lower."""
    available = available_bytes() if available is None else available
    if available is not None and nbytes > available:
        raise ConfigError(f"{what} needs {fmt_bytes(nbytes)} of memory, more than the "
                          f"{fmt_bytes(available)} available: {hint}")
