"""Perception: from a photo to the optimizer's inputs (pluggable backends per role)."""
