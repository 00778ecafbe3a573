"""Seed 004: the REMUS 100 helix, ideal UKF vs GP-UKF (paper.py, scenario.py, experiment.py; the GPs in gp_model.py
and their generated C in gp_codegen.py)."""
