"""The simulated robot: MuJoCo model and terrain, the AX-12A firmware, the plant that steps them, its truth log."""
