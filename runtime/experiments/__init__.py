"""The papers' experiments: one folder each (scenario, the paper's quoted numbers, figures).

* ``rov`` -- seed 000: the anchor-chain ROV on a catenary in sea states 0, 1-2, 3.
"""
