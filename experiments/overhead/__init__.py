"""What TensorBoard logging and physics randomization cost in env steps/s."""
