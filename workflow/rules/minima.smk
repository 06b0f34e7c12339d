"""Placeholder: filled in by the minima analysis."""
