"""An asset's *data frame* and its default size: how a Gaussian file is stood in the world, by the Blender import
(scene/gaussians.py) and by headless variations (core/variation) alike.

Data frame: Z up, origin at the bottom centre of the valid means' bounds, after undoing TRELLIS/Amodal3R's axes
(``core.splats.trellis``). ``file_to_data`` (4, 4) maps the file's coordinates into it. The *length* is the longer
horizontal extent. A TRELLIS/Amodal3R file, or a mesh conversion inside their unit cube, is scaled to
``TRELLIS_DEFAULT_LENGTH`` (their objects have no units); anything else keeps its file units.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass

import numpy as np

from . import trellis
from .gaussians import GaussianPly

#: metres: a unit-cube asset is scaled to a mid-size car until the artist fits it
TRELLIS_DEFAULT_LENGTH = 4.5
#: (min, max) metres a car asset's length may have: outside, its file is most likely in other units (millimetres,
#: centimetres); the import says so, a variation library refuses it.
CAR_LENGTH_M = (0.5, 30.0)


def data_frame(xyz_file: np.ndarray, axes: str) -> tuple:
    """(file_to_data (4, 4), F (3, 3) the axis change, data-frame bounds lo (3,), hi (3,)) for file means (N, 3),
    N ≥ 1, read with ``axes`` ("TRELLIS" or "NONE")."""
    F = trellis.ZUP_TO_TRELLIS_FILE.T if axes == "TRELLIS" else np.eye(3)
    xyz = np.asarray(xyz_file, np.float64) @ F.T
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    bottom = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    D = np.eye(4)
    D[:3, :3], D[:3, 3] = F, -bottom
    return D, F, lo - bottom, hi - bottom


def default_length(ply: GaussianPly, keep: np.ndarray, axes: str, is_mesh: bool, extent: float) -> float:
    """The length (file units or metres) an asset gets when none is asked for: ``TRELLIS_DEFAULT_LENGTH`` for a
    TRELLIS/Amodal3R file or a mesh conversion inside their unit cube (their GLBs are), else ``extent`` (its
    longer horizontal extent in file units: kept)."""
    in_cube = float(np.abs(ply.xyz[keep]).max()) <= trellis.TRELLIS_MEAN_BOUND
    return TRELLIS_DEFAULT_LENGTH if axes == "TRELLIS" or (is_mesh and in_cube) else float(extent)


@dataclass
class AssetFrame:
    """How a file stands in the world: ``axes`` ("TRELLIS" / "NONE") and ``reason``, ``file_to_data`` (4, 4),
    data-frame bounds ``lo``, ``hi`` (3,) in file units, and ``scale`` (file units → metres, uniform) that gives
    the default length."""
    axes: str
    reason: str
    file_to_data: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    scale: float


def asset_frame(ply: GaussianPly, keep: np.ndarray, is_mesh: bool = False) -> AssetFrame:
    """The data frame and default scale of ``ply``'s rows ``keep`` (at least one), its axes detected as the import
    detects them (a mesh conversion is already Z up)."""
    if is_mesh:
        axes, reason = "NONE", "a mesh turned Z up by its conversion"
    else:
        axes, reason = trellis.detect_axes(ply, keep)
    file_to_data, _, lo, hi = data_frame(ply.xyz[keep], axes)
    extent = float(max(hi[0] - lo[0], hi[1] - lo[1]))
    length = default_length(ply, keep, axes, is_mesh, extent)
    return AssetFrame(axes, reason, file_to_data, lo, hi, length / extent if extent > 0 else 1.0)


def file_key(path: str | os.PathLike) -> str:
    """10 hex digits naming a file's identity and version: its absolute path, size and modification time. Files
    derived from it (a mesh's Gaussians, a recoloured copy) carry it, so ``car.stl`` and ``car.ply``, or a file
    edited since, never share one."""
    st = os.stat(path)
    return hashlib.sha256(f"{os.path.abspath(path)}|{st.st_size}|{st.st_mtime_ns}".encode()).hexdigest()[:10]


def mesh_gaussians_name(mesh_path: str | os.PathLike, count: int) -> str:
    """The file name of a mesh's surface Gaussians (``mesh-asset``'s output, cached): ``car.stl.200000.<key>
    .gaussians.ply`` (``file_key``)."""
    return f"{os.path.basename(mesh_path)}.{int(count)}.{file_key(mesh_path)}.gaussians.ply"
