"""One LiDAR sweep's returns, the objects' point counts, and nuScenes' ``.pcd.bin`` file (docs/design.md §10a).

``Sweep``: the returns in the sensor frame (``core.lidar_model``: x right, y forward, z up, metres), in ray order
(column by column, azimuth from +y clockwise; within a column top beam first), with the sensor's pose.

``.pcd.bin`` (nuScenes ``LidarPointCloud.from_file``): no header, rows of 5 little-endian float32
(x, y, z, intensity, ring) in the sensor frame; intensity 0..255, ring 0 = the lowest beam.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from scpainter_blender.core import errors, outputs

#: Values per row of a ``.pcd.bin``: x, y, z, intensity, ring.
PCD_COLUMNS = 5
#: The largest sweep ``read_pcd_bin`` reads: 256 MiB, 13 M returns (a velodyne-64 sweep holds 136 k at most).
MAX_PCD_BYTES = 1 << 28


@dataclass(eq=False)
class Sweep:
    """R returns: ``points`` (R, 3) float32 sensor frame, metres; ``range_m`` (R,) float32 (= |points| up to the
    float32 rounding); ``intensity`` (R,) float32 0..255; ``ring`` (R,) int32 (0 = lowest beam); ``column`` (R,)
    int32 azimuth column; ``source`` (R,) int32: 0 the reconstruction's points, k the k-th set of Gaussians (an
    inserted car, 1-based); ``lidar_to_world`` (4, 4) float64 rigid, the sensor frame to the world; ``model`` the
    ``core.lidar_model`` key."""
    points: np.ndarray
    range_m: np.ndarray
    intensity: np.ndarray
    ring: np.ndarray
    column: np.ndarray
    source: np.ndarray
    lidar_to_world: np.ndarray
    model: str

    def __len__(self) -> int:
        return len(self.points)

    def world_points(self) -> np.ndarray:
        """(R, 3) float64: the returns in the world."""
        T = np.asarray(self.lidar_to_world, np.float64)
        return self.points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]

    def counts(self, boxes: Sequence[tuple]) -> np.ndarray:
        """``counts(self, boxes)``."""
        return counts(self, boxes)


def counts(sweep: Sweep, boxes: Sequence[tuple]) -> np.ndarray:
    """(K,) int64: per box the returns strictly inside it (nuScenes' ``num_lidar_pts``: the sweep's points in the
    box). ``boxes``: K pairs (box_to_world (4, 4) rigid, size (w, l, h) metres), the job's box frame (centre at the
    origin, ``core.geometry.boxes``); the test is in float64, in each box's frame."""
    out = np.zeros(len(boxes), np.int64)
    if not len(sweep) or not len(boxes):
        return out
    world = sweep.world_points()
    for k, (T, size) in enumerate(boxes):
        T = np.asarray(T, np.float64)
        local = (world - T[:3, 3]) @ T[:3, :3]
        out[k] = int(np.count_nonzero(np.all(np.abs(local) < np.asarray(size, np.float64) / 2, axis=1)))
    return out


def pcd_rows(sweep: Sweep) -> np.ndarray:
    """(R, 5) float32: the ``.pcd.bin`` rows (x, y, z, intensity, ring)."""
    return np.column_stack([sweep.points.astype(np.float32), sweep.intensity.astype(np.float32),
                            sweep.ring.astype(np.float32)]).astype("<f4")


def write_pcd_bin(path: str | os.PathLike, sweep: Sweep) -> None:
    """The sweep as nuScenes' ``.pcd.bin`` at ``path``, atomically (``outputs.atomic_write``)."""
    data = pcd_rows(sweep).tobytes()
    with outputs.atomic_write(path, "wb") as f:
        f.write(data)


def read_pcd_bin(path: str | os.PathLike) -> np.ndarray:
    """(R, 5) float32 rows of a ``.pcd.bin`` (x, y, z, intensity, ring; sensor frame), the one reader of the files
    ``write_pcd_bin`` writes (render's surround pictures, the nuScenes and KITTI exports). Opened as a regular file
    only (a FIFO, device or folder there is an ``InputError``, never a hang) and bounded (``MAX_PCD_BYTES``); a size
    that is not a whole number of rows is an ``InputError`` naming the file."""
    from scpainter_blender.core import files

    path = os.fspath(path)
    with files.open_regular(path) as f:
        data = f.read(MAX_PCD_BYTES + 1)
    if len(data) > MAX_PCD_BYTES:
        raise errors.InputError(path, "(file)", f"is over {MAX_PCD_BYTES} bytes: not a LiDAR sweep",
                                hint="render again: python -m backend render JOB")
    if len(data) % (4 * PCD_COLUMNS):
        raise errors.InputError(path, "(file)", f"{len(data)} bytes: not rows of {PCD_COLUMNS} float32 "
                                "(x, y, z, intensity, ring)", hint="render again: python -m backend render JOB")
    return np.frombuffer(data, "<f4").reshape(-1, PCD_COLUMNS).astype(np.float32)
