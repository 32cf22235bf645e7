"""A LiDAR sweep of the scene the cameras see: the reconstruction's points and the inserted cars' Gaussians
(docs/design.md §10a). The rule is ``cast``'s; the work is ``cast_cpu``'s numba kernels.

Frames: the world is Z up, metres; ``lidar_to_world`` (4, 4) rigid maps the sensor frame (``core.lidar_model``:
x right, y forward, z up) into it. Everything is moved next to the sensor in float64 before it is rounded to float32,
so a world whose coordinates are 1e5 m loses nothing (``simulate``); the renderer's scene is stored relative to its
origin in float32 already, and the sensor is put relative to that origin in float64 (``sweep_for_frame``).

A car's Gaussians enter as their means (surface samples, like the points) where the opacity reaches
``LidarSettings.opacity_min``, coloured by their DC colour.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from scpainter_blender.core.geometry import fits
from scpainter_blender.core.lidar_model import LidarModel
from scpainter_blender.core.splats.sh import SH_C0

from . import cast_cpu
from .cast import LidarSettings, ray_bases
from .sweep import Sweep

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from backend.render.frames import Scene


def _rigid(lidar_to_world) -> np.ndarray:
    T = np.asarray(lidar_to_world, np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise ValueError(f"lidar_to_world must be a finite (4, 4) matrix, got {T.shape}")
    return T


def gaussian_samples(means: np.ndarray, opacities: np.ndarray | None, colours: np.ndarray | None,
                     object_to_world: np.ndarray, origin: np.ndarray, opacity_min: float) -> tuple:
    """(xyz (M', 3) float32 relative to ``origin``, colours (M', 3) float32 0..1): the means (M, 3) of one car's
    Gaussians (its file coordinates) placed by ``object_to_world`` (4, 4), those whose opacity (M,) is below
    ``opacity_min`` left out (None: all kept); ``colours`` (M, 3) 0..1 or None (grey)."""
    means = np.asarray(means, np.float64)
    keep = np.ones(len(means), bool) if opacities is None else np.asarray(opacities) >= opacity_min
    A = np.asarray(object_to_world, np.float64)
    xyz = means[keep] @ A[:3, :3].T + (A[:3, 3] - np.asarray(origin, np.float64))
    rgb = np.full((len(xyz), 3), 0.5) if colours is None else np.asarray(colours)[keep]
    return xyz.astype(np.float32), np.clip(rgb, 0.0, 1.0).astype(np.float32)


def sweep_from_rays(model: LidarModel, lidar_to_world: np.ndarray, rng: np.ndarray, inten: np.ndarray,
                    src: np.ndarray, set_starts: Sequence[int]) -> Sweep:
    """The ``Sweep`` of a cast's per-ray (range, intensity, source) (A, B) [column, row]; ``set_starts``: the index
    in ``source`` where each point set begins (the reconstruction's first), for ``Sweep.source``."""
    hit = np.isfinite(rng)
    d0, _, _ = ray_bases(model)
    col, row = np.nonzero(hit)  # C order: column by column, top beam first, the rays' order
    r = rng[col, row]
    which = np.searchsorted(np.asarray(set_starts, np.int64), src[col, row], side="right") - 1
    return Sweep(points=(d0[col, row] * r[:, None]).astype(np.float32), range_m=r.astype(np.float32),
                 intensity=inten[col, row].astype(np.float32), ring=model.ring(row).astype(np.int32),
                 column=col.astype(np.int32), source=which.astype(np.int32),
                 lidar_to_world=np.array(lidar_to_world, np.float64), model=model.name)


def simulate(model: LidarModel, lidar_to_world: np.ndarray, points: np.ndarray, colours: np.ndarray | None = None,
             gaussians: Iterable[tuple] = (), removal_boxes: Iterable[tuple] = (),
             settings: LidarSettings | None = None) -> Sweep:
    """One sweep of a sensor at ``lidar_to_world`` (4, 4) float64 rigid over the world points ``points`` (N, 3)
    float64 metres (NaN/inf rows never return) with ``colours`` (N, 3) 0..1 (None: intensity 0) and the cars
    ``gaussians``: (means (M, 3) world metres, opacities (M,) or None, colours (M, 3) 0..1 or None) each.
    ``removal_boxes``: (box_to_world (4, 4), size (w, l, h)) pairs whose points are left out (the loader's rule,
    ``fits.points_in_box``). Worked relative to the sensor in float64, then float32."""
    settings = settings or LidarSettings()
    T = _rigid(lidar_to_world)
    o = T[:3, 3].copy()
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    rgb = np.zeros((len(pts), 3), np.float32) if colours is None else np.asarray(colours, np.float32)
    keep = np.ones(len(pts), bool)
    for box_to_world, size in removal_boxes:
        keep &= ~fits.points_in_box(pts, box_to_world, size)
    if not keep.all():
        pts, rgb = pts[keep], rgb[keep]
    sets = [gaussian_samples(m, op, col, np.eye(4), o, settings.opacity_min) for m, op, col in gaussians]
    return _cast(model, T, (pts - o).astype(np.float32), rgb, sets, np.zeros(3), settings)


def _cast(model, T, xyz, rgb, sets, t, settings) -> Sweep:
    xyz_b = np.concatenate([s[0] for s in sets]) if sets else np.zeros((0, 3), np.float32)
    rgb_b = np.concatenate([s[1] for s in sets]) if sets else np.zeros((0, 3), np.float32)
    starts = np.cumsum([0, len(xyz)] + [len(s[0]) for s in sets])[:-1]
    rng, inten, src = cast_cpu.cast(model, xyz, rgb, xyz_b, rgb_b, T[:3, :3].T, t, settings)
    return sweep_from_rays(model, T, rng, inten, src, starts)


def sweep_for_frame(scene: Scene, frame: int, lidar_to_world: np.ndarray, model: LidarModel,
                    settings: LidarSettings | None = None, source_frames: Sequence[int] | None = None) -> Sweep:
    """The sweep at output frame ``frame`` of the renderer's loaded scene (``backend.render.frames.Scene``: points
    float32 relative to ``scene.origin``, removal boxes already applied; each asset placed by its
    ``object_to_world[frame]``, an asset without that frame left out), the sensor at ``lidar_to_world`` (4, 4)
    world, float64. ``source_frames``: the source frames whose points it sees (None: every point; a LiDAR sees all
    around, not a camera's few frames)."""
    settings = settings or LidarSettings()
    T = _rigid(lidar_to_world)
    origin = np.asarray(scene.origin, np.float64)
    if scene.xyz is None:
        xyz, rgb = np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)
    else:
        if source_frames is None:
            x, c = scene.xyz, scene.rgb
        else:
            from backend.render.frames import select_points

            x, c = select_points(scene, sorted(set(int(f) for f in source_frames)))
        xyz, rgb = x.detach().cpu().numpy(), c.detach().cpu().numpy()
    sets = []
    for a in scene.assets:
        if frame not in a.object_to_world:  # an empty set keeps Sweep.source = the asset's 1-based place
            sets.append((np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)))
            continue
        dc = a.sh[:, 0, :].detach().cpu().numpy() if a.sh.shape[0] else np.zeros((0, 3))
        sets.append(gaussian_samples(a.means.detach().cpu().numpy(), a.opacities.detach().cpu().numpy(),
                                     0.5 + SH_C0 * dc, a.object_to_world[frame], origin, settings.opacity_min))
    return _cast(model, T, xyz, rgb, sets, T[:3, 3] - origin, settings)
