"""Verification cases with analytic answers: error against run time (softsim verify)."""
