"""Geometry toolkit: rotations, signed distances, ray casting, ICP, watertight repair."""
