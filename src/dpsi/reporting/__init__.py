"""Figures and tables of the experiments (SPEC §7)."""
