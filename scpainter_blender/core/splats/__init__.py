"""Gaussian splat files and values: INRIA PLY, SuperSplat compressed PLY, .splat, TRELLIS, SH."""
