"""Synthetic hand-object scenes with exact ground truth, and perturbation models."""
