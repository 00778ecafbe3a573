"""The papers' experiments, one folder each of the same shape: paper.py (the paper's quoted numbers),
scenario.py (the simulated truth), experiment.py (Config, run_one, report, figures); reproduce.py's registry
runs them on the campaign harness (campaign.py).

* ``rov`` -- seed 000: the anchor-chain ROV on a catenary in sea states 0, 1-2, 3.
* ``cn`` -- seed 002: cooperative navigation on a simulated lake trial.
* ``tan`` -- seed 003: terrain-aided navigation with a fuzzy-sigma particle filter.
* ``remus`` -- seed 004: the REMUS 100 helix, ideal UKF vs GP-UKF (plus gp_model.py, gp_codegen.py).
"""
