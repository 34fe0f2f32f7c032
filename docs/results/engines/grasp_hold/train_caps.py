"""daddpg-train with capsule finger pads on the grasp pairs (probe)."""
import sys
sys.path.insert(0, __import__("os").path.dirname(__import__("os").path.abspath(__file__)))
import caps
caps.patch(**caps.DEFAULT)
from daddpg_jax.cli.train import main
sys.exit(main(sys.argv[1:]))
