"""Random rotations and camera poses for the core camera tests (seeded by the caller's generator)."""

import numpy as np

from scpainter_blender.core.geometry import cameras as C


def random_rotation(rng):
    q = rng.standard_normal(4)
    return C.quaternion_to_rotation(q)


def random_w2c(rng, n=None, offset=0.0):
    shape = () if n is None else (n,)
    T = np.tile(np.eye(4), shape + (1, 1))
    R = random_rotation(rng) if n is None else np.stack([random_rotation(rng) for _ in range(n)])
    centres = rng.uniform(-50, 50, shape + (3,)) + offset
    T[..., :3, :3] = R
    T[..., :3, 3] = -np.einsum("...ij,...j->...i", R, centres)
    return T
