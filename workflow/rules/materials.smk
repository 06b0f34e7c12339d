"""Placeholder: filled in by the materials analysis."""
