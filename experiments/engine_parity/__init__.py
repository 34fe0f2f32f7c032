"""Where MJX and the C engine part on grasps: the candidate-cause measurement (`parity`,
`candidates`) and the probes and hold experiments behind docs/MJX_VS_C.md."""
