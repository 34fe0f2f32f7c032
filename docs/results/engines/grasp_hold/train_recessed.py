"""daddpg-train with the recessed dense pads of recessed.py (probe; the scenes are not changed).
OUT_M=0.001 HOLD_HI=0.024 python train_recessed.py --task pickup ..."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import recessed  # noqa: E402

recessed.patch()
from daddpg_jax.cli.train import main  # noqa: E402

sys.exit(main(sys.argv[1:]))
