"""Test helpers for the mesh-asset tests (tests/backend/test_mesh_*.py): small meshes made here (an asymmetric
car-like object, a cell texture), the glTF axes, and the colour and normal of Gaussians as the sampler makes them."""

import os

import numpy as np
import trimesh
from PIL import Image

from backend.mesh import load as mesh_load
from scpainter_blender.core.geometry import cameras
from scpainter_blender.core.splats.sh import SH_C0

R_GLTF = mesh_load.Y_UP_TO_Z_UP            # p_zup = R_GLTF @ p_gltf
TRELLIS_GLB = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # to_glb: vertices @ TRELLIS_GLB


def rgb_of(g):
    """sRGB colours (N, 3) of degree-0 Gaussians: 0.5 + C0 f_dc."""
    return SH_C0 * g.sh[:, 0].astype(np.float64) + 0.5


def normals_of(g):
    """Unit normals (N, 3) of flat Gaussians: the local z axis of their rotations."""
    return cameras.quaternion_to_rotation(g.quats.astype(np.float64))[:, :, 2]


def split_triangles(vertices, faces):
    """Every triangle with its own three vertices (so per-triangle UVs and colours are free)."""
    tri = np.asarray(vertices, float)[np.asarray(faces)]
    return tri.reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3)


def car_like_zup():
    """An asymmetric test object, Z up: a 4 x 2 x 1 body on z = 0 and a mast at its (+x, +y) corner."""
    body = trimesh.creation.box((4.0, 2.0, 1.0), trimesh.transformations.translation_matrix((0, 0, 0.5)))
    mast = trimesh.creation.box((0.4, 0.4, 1.0), trimesh.transformations.translation_matrix((1.6, 0.7, 1.5)))
    return trimesh.util.concatenate([body, mast])


def cell_texture(colours, cell=16):
    """A 3 x 2 grid of uniform cells (uint8 RGB colours (6, 3)), and a function giving UVs inside cell k."""
    img = np.zeros((2 * cell, 3 * cell, 3), np.uint8)
    for k, c in enumerate(colours):
        i, j = k % 3, k // 3
        img[j * cell:(j + 1) * cell, i * cell:(i + 1) * cell] = c

    def uv_in_cell(k, n):  # n points well inside cell k (trimesh's V: v = 1 is the image's top row)
        i, j = k % 3, k // 3
        centre = np.array([(i + 0.5) / 3, 1 - (j + 0.5) / 2])
        ring = np.array([[-0.3, -0.3], [0.3, -0.3], [0.0, 0.3]])[:n]
        return centre + ring * np.array([1 / 3, 1 / 2])

    return Image.fromarray(img), uv_in_cell


def export(mesh, path):
    """``mesh`` exported by trimesh to ``path`` (format by extension); returns the path as a string."""
    mesh.export(os.fspath(path))
    return os.fspath(path)
