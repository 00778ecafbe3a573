"""Seed 000's printed numbers (Wang et al., Appl. Sci. 2023, 13, 5885), quoted, never computed here.

Table 3, "RMSE of different algorithms in three sea states" (the same numbers are drawn as bars in
Figs. 11-12): the RMSE of x, y, z (m) and psi (the paper prints no unit for psi; our state and every
comparison here are in rad) over the paper's 200 s catenary run, for PF, CKF, CPF and EM-MOGCPF (the paper
has no MOGCPF row). From the authors' simulation in MATLAB; how many runs it averages is not stated.
"""
from __future__ import annotations

AXES = ("x", "y", "z", "psi")
#: Table 3: sea state -> filter -> RMSE of (x, y, z, psi)
TABLE3 = {
    "0": {"PF": (1.8577, 1.2232, 3.8294, 2.5201), "CKF": (1.0618, 0.9602, 0.8827, 1.5164),
          "CPF": (0.8291, 0.7297, 0.6871, 1.5018), "EM-MOGCPF": (0.5633, 0.5290, 0.5140, 0.9196)},
    "1-2": {"PF": (0.8289, 2.6940, 6.9908, 1.6541), "CKF": (1.1010, 1.4307, 3.9050, 1.7259),
            "CPF": (0.6611, 0.8125, 1.0363, 0.8849), "EM-MOGCPF": (0.4392, 0.3738, 0.4771, 0.4083)},
    "3": {"PF": (2.1690, 7.5129, 5.9652, 8.7070), "CKF": (3.5037, 5.0190, 10.9400, 14.6010),
          "CPF": (1.2855, 1.6607, 3.3708, 6.7736), "EM-MOGCPF": (0.5956, 0.3094, 0.6318, 2.1357)},
}


def table3_rmse() -> dict[str, dict[str, dict[str, float]]]:
    """Table 3 as {sea state: {filter: {axis: RMSE}}} (a fresh copy each call)."""
    return {sea: {f: dict(zip(AXES, v)) for f, v in row.items()} for sea, row in TABLE3.items()}
