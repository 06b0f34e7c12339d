"""Placeholder: filled in by the cost analysis."""
