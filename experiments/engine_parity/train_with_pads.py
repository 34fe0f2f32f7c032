"""daddpg-train with finger pads of KIND on the grasp pairs (pads.py; this process only, the
scenes are not changed):

    python experiments/engine_parity/train_with_pads.py KIND --task pickup ...

e.g. ``OUT_M=0.001 HOLD_HI=0.024 ... train_with_pads.py recessed --task pickup``. Runs:
docs/results/engines/finger_pads/*_pads, grasp_hold/pickup_caps_train, pickup_recessed_train.
"""

from __future__ import annotations

import os
import sys

if __package__ in (None, ""):  # run as a file: the repository root holds `experiments`
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))

from experiments.engine_parity import pads  # noqa: E402


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in pads.PADS:
        print(__doc__ + "\nKIND: " + ", ".join(pads.PADS))
        return 2
    pads.patch(argv[0])
    from daddpg_jax.cli.train import main as train

    return train(argv[1:])


if __name__ == "__main__":
    sys.exit(main())
