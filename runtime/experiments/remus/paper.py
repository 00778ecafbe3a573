"""Seed 004's printed numbers (REMUS 100 helix, ideal UKF vs GP-UKF), quoted, never computed here.

Table 3, "Mean RMSE and standard deviation results from UKF and GP-UKF per state for 20 runs": per state,
u v w in m/s, p q r in rad/s, x y z in m, phi theta psi in rad. The velocity rows are legible; of the pose
rows the UKF means are, and the UKF's sigma of x and y ("UKF σ-UKF 2.4237 14.6908 1.2695 8.5834"); the other
pose cells are garbled in the seed text, so nothing else is quoted. That sigma of x, y exceeds sqrt(20) x the
mean, which no sample standard deviation of 20 non-negative numbers can (experiment.py prints the check):
whatever the paper's sigma is, it is not a standard deviation over the 20 runs.

Table 4, "Mean RMSE results from UKF and GP-UKF for correction and prediction": one number each; the paper
defines neither quantity (experiment.py states our readings). Prediction is read as a position RMSE (m).
"""
from __future__ import annotations

#: the number of runs Table 3 averages over
RUNS = 20
#: the regressors the paper's GPs had: 40 % of 800 s logged at 5 Hz (section 6)
REGRESSORS = 1600
#: the units of Table 3's columns
UNITS = {"u": "m/s", "v": "m/s", "w": "m/s", "p": "rad/s", "q": "rad/s", "r": "rad/s", "x": "m", "y": "m", "z": "m",
         "phi": "rad", "theta": "rad", "psi": "rad"}
#: Table 3: filter (or "sigma-<filter>", the printed sigma row) -> state -> mean RMSE over the 20 runs
TABLE3 = {
    "UKF": {"u": 0.0014, "v": 0.0015, "w": 0.0005, "p": 0.0023, "q": 0.0013, "r": 0.0031,
            "x": 2.4237, "y": 1.2695, "z": 0.0017, "phi": 0.0006, "theta": 0.0012, "psi": 0.0013},
    "sigma-UKF": {"u": 0.0003, "v": 0.0021, "w": 0.0008, "p": 0.0078, "q": 0.0035, "r": 0.0121, "x": 14.6908,
                  "y": 8.5834},
    "GP-UKF": {"u": 0.0158, "v": 0.0369, "w": 0.0154, "p": 0.0569, "q": 0.0601, "r": 0.1813},
    "sigma-GP-UKF": {"u": 0.0387, "v": 0.0069, "w": 0.0033, "p": 0.0123, "q": 0.0130, "r": 0.0347},
}
#: Table 4: (filter, "correction" | "prediction") -> mean RMSE (prediction read as m, correction unitless mix)
TABLE4 = {("UKF", "correction"): 0.0028, ("GP-UKF", "correction"): 0.086,
          ("UKF", "prediction"): 2.91, ("GP-UKF", "prediction"): 2.86}
