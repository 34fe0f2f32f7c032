"""Stand-alone tools beside the trainer: the Stable-Baselines3 comparison (`sb3_compare`) and the
GPU machine check (`gpu_check`)."""
