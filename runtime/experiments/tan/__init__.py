"""Seed 003: terrain-aided navigation with a fuzzy-sigma particle filter (scenario, paper numbers, figures)."""
