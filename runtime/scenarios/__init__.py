"""Simulated experiments of the seed papers: truth from the compiled models, noise models as data.

* ``rov_sea_state`` -- seed 000: the anchor-chain ROV on a catenary in sea states 0, 1-2, 3.
"""
