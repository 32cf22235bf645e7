"""Geometry in numpy: cameras, similarities, trajectories, fits, metric scale, unprojection."""
