"""daddpg-train with sphere finger pads on the grasp pairs (probe; the scenes are not changed)."""
import sys
import spheres
spheres.patch(r=0.006, xs=(-0.01, 0.01), zs=(0.005, 0.025, 0.045, 0.065))
from daddpg_jax.cli.train import main
sys.exit(main(sys.argv[1:]))
