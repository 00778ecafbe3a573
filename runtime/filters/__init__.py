"""State estimators on generated C: kalman/ (one engine, thin families), particle/ (SIR), mixture/ (Gaussian sums)."""
