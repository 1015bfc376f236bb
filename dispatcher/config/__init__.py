"""Scenario, fleet and farm files as the dispatcher reads them, and the errors that name the
file and key at fault. Loads without the solver (no numba)."""
