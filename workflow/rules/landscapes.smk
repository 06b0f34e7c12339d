"""Placeholder: filled in by the landscapes analysis."""
