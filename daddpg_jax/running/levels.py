"""When a learning curve reaches a test-success level (pure Python, no JAX import)."""

from __future__ import annotations

import math
from collections.abc import Sequence

# Success rates are k/n episode fractions logged in float32 (0.9 is stored as 0.89999998):
# a rate counts as reaching a level within this tolerance.
REACH_TOL = 1e-6


def reaches(success: float, level: float) -> bool:
    """True when ``success`` is at or above ``level`` (within float32 rounding)."""
    return float(success) >= level - REACH_TOL


def first_reaching(rows: Sequence[dict], level: float, key: str):
    """``row[key]`` of the first row whose ``test_success_rate`` reaches ``level``; NaN if none."""
    for r in rows:
        if reaches(r["test_success_rate"], level):
            return float(r[key])
    return math.nan
