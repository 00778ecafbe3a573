"""Seed 000: the anchor-chain cleaning ROV in sea states 0, 1-2 and 3 (paper.py, scenario.py, experiment.py)."""
