"""What seed 003 reports (quoted, never computed here). The paper prints no table of errors: its
results are figures and sentences, so these are its claims, cited by figure, for the report."""

#: the paper's timing: MATLAB, dual-core 2.6 GHz, 1000 particles, 30 000 steps in 23 s (section 4.1)
PAPER_STEP_MS = 0.76
PAPER_RUN_SECONDS = 23.0

#: (case, filter) -> the paper's words, with the figure they come from
CLAIMS = {
    ("current_0.1", "sigma_1"): "max error exceeds 1000 m: the search range is too small, the truth is lost (Figs. 8-9)",
    ("current_0.1", "sigma_2"): "good tracking (Figs. 8-9)",
    ("current_0.1", "sigma_3"): "good tracking (Figs. 8-9)",
    ("current_0.1", "sigma_4"): "larger error: the correct area is not searched intensively (Figs. 8-9)",
    ("current_0.1", "sigma_5"): "larger error (Figs. 8-9)",
    ("current_0.1", "sigma_6"): "larger error (Figs. 8-9)",
    ("current_0.1", "fuzzy"): "good tracking (Figs. 8-9)",
    ("current_0.15", "sigma_2"): "max error exceeds 1000 m (Figs. 10-11)",
    ("current_0.15", "sigma_3"): "max error exceeds 1000 m (Figs. 10-11)",
    ("current_0.15", "sigma_4"): "better, but fails where the steep area's top is suddenly flat (Figs. 10-12)",
    ("current_0.15", "fuzzy"): "good tracking; error within one 500 m map cell (Figs. 10-11, abstract)",
    ("flat", "all"): "every filter is close to dead reckoning in the flat area (Fig. 15)",
}

#: the same claims in a word or two, for the figures' "the paper" row: (current, filter) -> words
VERDICTS = {
    ("current_0.1", "sigma_1"): "lost", ("current_0.1", "sigma_2"): "good", ("current_0.1", "sigma_3"): "good",
    ("current_0.1", "sigma_4"): "larger error", ("current_0.1", "sigma_5"): "larger error", ("current_0.1", "sigma_6"): "larger error",
    ("current_0.1", "fuzzy"): "good",
    ("current_0.15", "sigma_2"): "lost", ("current_0.15", "sigma_3"): "lost", ("current_0.15", "sigma_4"): "better,\nthen lost",
    ("current_0.15", "fuzzy"): "good,\n< 500 m",
}

SUMMARY = ("Fuzzy-PF keeps the position error within one 500 m map cell under both currents (abstract); "
           "fixed sigma = 2 or 3 m tracks at 0.1 m/s but loses the track (> 1000 m) at 0.15 m/s; in the flat "
           "area every filter is close to dead reckoning (Fig. 15); fuzzy gives the smallest localisation "
           "variance most of the time but not always (Fig. 14).")
