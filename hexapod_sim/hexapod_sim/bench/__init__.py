"""Benchmarks of the sim and of bag replay (they print figures)."""
