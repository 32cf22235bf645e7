"""Procedural shapes as numpy arrays: boxes, cylinders, a car; and a mesh turned into surface Gaussians.

Frame: Z up, metres. The car stands on z = 0, centred on x = y = 0, its length along +Y (front towards +Y).
Faces are polygons (vertex index lists, outward normals, counter-clockwise seen from outside); material keys are
whatever the caller passes (Blender materials for the street, RGB names for the Gaussian car).

No bpy, no torch: numpy only.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .geometry import cameras
from .splats import gaussians as splats, inria as splats_inria, trellis
from .splats.sh import SH_C0
from .geometry.similarity import decompose_similarity  # a bare name: transform_gaussians has a parameter "similarity"

if TYPE_CHECKING:
    from collections.abc import Sequence

_BOX_SIGNS = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
                       [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], float)
_BOX_FACES = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (2, 3, 7, 6), (3, 0, 4, 7), (1, 2, 6, 5)]


class MeshBuilder:
    """Collects boxes and cylinders with per-face material keys."""

    def __init__(self) -> None:
        self.verts, self.faces, self.mats = [], [], []
        self.materials = []
        self.n = 0

    def _slot(self, mat):
        if mat not in self.materials:
            self.materials.append(mat)
        return self.materials.index(mat)

    def box(self, center: Sequence[float], size: Sequence[float], mat: object) -> None:
        self.verts.append(np.asarray(center, float) + _BOX_SIGNS * np.asarray(size, float) / 2)
        slot = self._slot(mat)
        for f in _BOX_FACES:
            self.faces.append([self.n + i for i in f])
            self.mats.append(slot)
        self.n += 8

    def cylinder(self, center: Sequence[float], radius: float, length: float, axis: int, mat: object,
                 segments: int = 16) -> None:
        """Axis-aligned closed cylinder; ``axis`` 0, 1 or 2."""
        a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
        ring = np.zeros((segments, 3))
        u, v = [i for i in range(3) if i != axis]
        if axis == 1:  # keep the ring counter-clockwise about +axis so the side faces point outwards
            u, v = v, u
        ring[:, u], ring[:, v] = radius * np.cos(a), radius * np.sin(a)
        lo, hi = ring.copy(), ring.copy()
        lo[:, axis], hi[:, axis] = -length / 2, length / 2
        self.verts.append(np.asarray(center, float) + np.concatenate([lo, hi]))
        slot = self._slot(mat)
        b = self.n
        for i in range(segments):
            j = (i + 1) % segments
            self.faces.append([b + i, b + j, b + segments + j, b + segments + i])
            self.mats.append(slot)
        self.faces.append([b + i for i in reversed(range(segments))])
        self.faces.append([b + segments + i for i in range(segments)])
        self.mats += [slot, slot]
        self.n += 2 * segments

    def arrays(self) -> tuple[np.ndarray, list, np.ndarray]:
        """(vertices (V, 3) float64, faces (list of index lists), material slot per face (F,) int32)."""
        verts = np.concatenate(self.verts) if self.verts else np.zeros((0, 3))
        return verts, self.faces, np.asarray(self.mats, np.int32)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        verts = self.arrays()[0]
        return verts.min(axis=0), verts.max(axis=0)

    def triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """Fan-triangulated faces: (T, 3, 3) corner positions and (T,) material slots."""
        verts, faces, mats = self.arrays()
        tri, slot = [], []
        for f, m in zip(faces, mats):
            for k in range(1, len(f) - 1):
                tri.append((f[0], f[k], f[k + 1]))
                slot.append(m)
        return verts[np.asarray(tri)], np.asarray(slot, np.int32)


def add_car(builder: MeshBuilder, rng: np.random.Generator, paint: object, glass: object, tyre: object,
            length: float = 4.4, width: float = 1.8) -> None:
    """A car-shaped body: chassis, glass cabin with a roof, four wheels; on z = 0, length along Y."""
    body_z0, body_h = 0.28, 0.72
    builder.box((0, 0, body_z0 + body_h / 2), (width, length, body_h), paint)
    cabin_len = length * rng.uniform(0.48, 0.56)
    builder.box((0, -0.15 * length / 4.4, body_z0 + body_h + 0.27), (width * 0.88, cabin_len, 0.54), glass)
    builder.box((0, -0.15 * length / 4.4, body_z0 + body_h + 0.56), (width * 0.86, cabin_len * 0.9, 0.04), paint)
    for sx in (-1, 1):
        for sy in (-1, 1):
            builder.cylinder((sx * (width / 2 - 0.1), sy * (length / 2 - 0.8), 0.32), 0.32, 0.24, 0, tyre)


def face_frames(tri: np.ndarray) -> np.ndarray:
    """Rotations (F, 3, 3) whose columns are a flat Gaussian's local x, y, z on triangles ``tri`` (F, 3, 3):
    z = n = normalise((v1 - v0) x (v2 - v0)) (the winding's normal), x = t1 = v1 - v0 made orthogonal to n and
    normalised, y = n x t1. Degenerate or non-finite triangles give NaN rows (the caller drops them)."""
    tri = np.asarray(tri, np.float64)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.cross(e1, e2)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        t1 = e1 - np.sum(e1 * n, axis=1, keepdims=True) * n
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return np.stack([t1, np.cross(n, t1), n], axis=2)


def surface_gaussians(builder: MeshBuilder, colors: dict, count: int, seed: int = 0, flatness: float = 0.1,
                      opacity: float = 0.95) -> splats.Gaussians:
    """Flat Gaussians spread over a mesh's surface, area-weighted, coloured by material.

    Each Gaussian lies on a triangle (uniform barycentric sample), its local z along the face normal; its in-plane
    standard deviation is about the mean spacing of the samples, the normal one ``flatness`` times that. ``colors``
    maps material keys to sRGB-encoded RGB in [0, 1], stored as the SH DC term (degree 0).
    """
    rng = np.random.default_rng(seed)
    tri, slot = builder.triangles()
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    pick = rng.choice(len(tri), size=count, p=area / area.sum())
    r1, r2 = rng.random(count), rng.random(count)
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    means = tri[pick, 0] + r1[:, None] * e1[pick] + r2[:, None] * e2[pick]
    R = face_frames(tri[pick])
    sigma = np.sqrt(area.sum() / count)
    scales = np.tile([sigma, sigma, flatness * sigma], (count, 1))
    rgb = np.array([colors[m] for m in builder.materials], float)[slot[pick]]
    sh = ((rgb - 0.5) / SH_C0)[:, None, :]
    return splats.Gaussians(means=means.astype(np.float32), scales=scales.astype(np.float32),
                            quats=cameras.rotation_to_quaternion(R).astype(np.float32),
                            opacities=np.full(count, opacity, np.float32), sh=sh.astype(np.float32))


def procedural_car_gaussians(count: int = 20000, seed: int = 0,
                             paint: Sequence[float] | None = None) -> splats.Gaussians:
    """The test/demo car as Gaussians, metric (4.4 x 1.8 m), on z = 0, front towards +Y."""
    rng = np.random.default_rng(seed)
    paint = tuple(rng.uniform(0.1, 0.8, 3)) if paint is None else tuple(paint)
    b = MeshBuilder()
    add_car(b, rng, "paint", "glass", "tyre")
    return surface_gaussians(b, {"paint": paint, "glass": (0.05, 0.06, 0.08), "tyre": (0.03, 0.03, 0.03)},
                             count, seed)


def transform_gaussians(g: splats.Gaussians, similarity: np.ndarray) -> splats.Gaussians:
    """Apply x -> s R x + t: means move, scales grow by s, orientations turn by R (DC/SH colours unchanged).

    Higher SH degrees would need rotating too; this keeps them as they are, so use it for degree 0 or identity R.
    """
    s, R, t = decompose_similarity(similarity)
    q = cameras.rotation_to_quaternion(R @ cameras.quaternion_to_rotation(g.quats.astype(np.float64)))
    return splats.Gaussians(means=(s * g.means.astype(np.float64) @ R.T + t).astype(np.float32),
                            scales=(s * g.scales).astype(np.float32), quats=q.astype(np.float32),
                            opacities=g.opacities, sh=g.sh, dropped=dict(g.dropped))


def save_as_amodal3r(path: str | os.PathLike, g: splats.Gaussians) -> np.ndarray:
    """Write Gaussians (Z-up, any size) as TRELLIS/Amodal3R do: centred in the unit cube, their file axes, SH 0.

    Returns the 4x4 similarity that took the input to the file's coordinates (so a test knows the truth).
    """
    lo, hi = g.means.min(axis=0).astype(np.float64), g.means.max(axis=0).astype(np.float64)
    s = 0.98 / float(np.max(hi - lo))
    A = np.eye(4)
    A[:3, :3] = s * trellis.ZUP_TO_TRELLIS_FILE
    A[:3, 3] = -s * trellis.ZUP_TO_TRELLIS_FILE @ ((lo + hi) / 2)
    out = transform_gaussians(splats.Gaussians(g.means, g.scales, g.quats, g.opacities, g.sh[:, :1]), A)
    zeros = np.zeros(len(out), np.float32)
    splats_inria.write_ply(path, splats.encode(out, extra={"nx": zeros, "ny": zeros, "nz": zeros}))
    return A
