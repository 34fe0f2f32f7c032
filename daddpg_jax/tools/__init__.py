"""The GPU machine check (`gpu_check`, its stages in `gpu_check_stages`)."""
