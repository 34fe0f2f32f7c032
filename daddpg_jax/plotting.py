"""Learning-curve plots (PNG) from metrics rows (dicts as read from metrics.csv)."""

from __future__ import annotations

import os
from typing import Iterable, Sequence

import numpy as np


def _mpl():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_learning_curve(rows: Sequence[dict], out: str, title: str = "") -> str:
    """Test success (and arm-contact rate) vs env steps for one run."""
    plt = _mpl()
    x = np.array([float(r["env_steps"]) for r in rows])
    s = np.array([float(r["test_success_rate"]) for r in rows])
    c = np.array([float(r["test_arm_contact_rate"]) for r in rows])
    fig, ax = plt.subplots(figsize=(6, 4), dpi=110)
    ax.plot(x, s, "o-", label="test success rate", color="tab:blue")
    ax.plot(x, c, "s--", label="arm-contact rate (test)", color="tab:red", alpha=0.7)
    ax.set_xlabel("env steps")
    ax.set_ylabel("rate")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    if title:
        ax.set_title(title)
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out
