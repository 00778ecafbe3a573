"""Cooperative navigation (seed 002) on a simulated lake trial: scenario, filters, Table 7, figures."""
