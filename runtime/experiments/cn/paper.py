"""Seed 002's printed numbers (quoted, never computed here).

Table 7: averaged position error (APE, eq. 46) in metres and time per step in seconds, from the
authors' September 2014 Lake Thai trial, filters coded in MATLAB on an Intel Pentium at 2.90 GHz
with 2 GB of memory -- a different machine, language and data set from ours.
"""
TABLE7 = {  # filter: (APE m, time per step s)
    "CKF": (152.0, 1.3644e-4),
    "MCUKF": (18.2, 1.6458e-4),
    "PF": (14.1, 2.6165e-2),
    "UPF": (15.1, 0.1725),
    "HRUPF": (12.4, 0.3398),
    "IVBCKF": (12.1, 7.9420e-4),
    "MCUPF": (8.6, 0.2156),
}
#: the paper's ranking by APE, best first (Table 7)
APE_RANKING = ("MCUPF", "IVBCKF", "HRUPF", "PF", "UPF", "MCUKF", "CKF")
