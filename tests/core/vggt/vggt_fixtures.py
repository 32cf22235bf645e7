"""Predictions files written as raw ``np.savez`` archives (any keys, any layout), for the core.vggt.predictions* tests."""

import numpy as np


def save(tmp_path, arrays, name="predictions.npz", **extra):
    """``arrays`` (and ``extra`` keys) saved as ``tmp_path/name`` exactly as given; returns the path."""
    p = tmp_path / name
    np.savez(p, **arrays, **extra)
    return str(p)
