"""Seed 002: cooperative navigation on a simulated lake trial (paper.py, scenario.py, experiment.py)."""
