"""Placeholder: filled in by the heightmap_losses analysis."""
