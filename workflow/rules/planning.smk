"""Placeholder: filled in by the planning analysis."""
