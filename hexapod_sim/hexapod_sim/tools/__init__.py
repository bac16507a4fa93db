"""Offline tools around the simulated robot: bag replay, pictures and videos, the TF figure."""
