"""Latency and flood benchmarks of the policy service on loopback (docs/RELIABILITY.md)."""
