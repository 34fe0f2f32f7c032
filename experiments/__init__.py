"""The lab: thin callers of the console scripts (run.py, evaluate.py, ...) and, in topic
folders, the measurements behind the docs (engine parity, overheads, the Stable-Baselines3
comparison, the service benchmarks, perception). Run a topic's script as a file
(``python experiments/sb3/compare_sb3.py``) or a module (``python -m experiments.sb3.compare_sb3``)
from the repository root."""
