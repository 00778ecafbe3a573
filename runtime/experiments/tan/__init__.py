"""Seed 003: terrain-aided navigation with a fuzzy-sigma particle filter (paper.py, scenario.py, experiment.py)."""
