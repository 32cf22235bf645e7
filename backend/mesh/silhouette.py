"""How well a mesh asset's Gaussians cover the mesh: the rendered asset mask M_a = 1 - transmittance against the
mesh's own silhouette, seen from cameras around it (``bench/mesh_assets.py`` chooses ``mesh.asset.SIGMA_FACTOR``
with it; the tests check the default).

Cameras are OpenCV world_to_camera matrices (x right, y down, z forward) with pixel centres at (u + 0.5, v + 0.5),
as everywhere in the project. No bpy; torch only in ``render_mask`` (the condition renderer, on the CPU).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from scpainter_blender.core.splats import gaussians as splats

if TYPE_CHECKING:
    from collections.abc import Sequence


def look_at(eye: np.ndarray, target: np.ndarray, up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """4x4 world_to_camera (OpenCV: x right, y down, z forward) of a camera at ``eye`` looking at ``target``."""
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, (0.0, 1.0, 0.0))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    w2c = np.eye(4)
    w2c[:3, :3] = np.stack([x, y, z])
    w2c[:3, 3] = -w2c[:3, :3] @ eye
    return w2c


def orbit_cameras(center: np.ndarray, radius: float, width: int, height: int, views: int = 6,
                  elevation_deg: float = 15.0, fov_x_deg: float = 50.0,
                  azimuth0_deg: float = 20.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """``views`` cameras (K, world_to_camera) evenly around ``center`` at ``radius``, ``elevation_deg`` above the
    horizon, looking at it; square pixels, principal point at the image centre."""
    fx = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2)
    K = np.array([[fx, 0.0, width / 2], [0.0, fx, height / 2], [0.0, 0.0, 1.0]])
    c = np.asarray(center, np.float64)
    out = []
    for i in range(views):
        a = math.radians(azimuth0_deg + 360.0 * i / views)
        e = math.radians(elevation_deg)
        eye = c + radius * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
        out.append((K, look_at(eye, c)))
    return out


def silhouette(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, world_to_camera: np.ndarray, width: int,
               height: int, near: float = 1e-3, chunk: int = 4_000_000) -> np.ndarray:
    """The mesh's own silhouette: (H, W) bool, pixel centres (u + 0.5, v + 0.5) inside any projected triangle.

    Exact point-in-triangle tests on each triangle's pixel bounding box (edge functions; a centre on an edge
    counts). Triangles with a corner behind ``near`` or a non-finite corner are skipped: keep the camera outside
    the object.
    """
    V = np.asarray(vertices, np.float64)
    Fc = np.asarray(faces, np.int64)
    w2c = np.asarray(world_to_camera, np.float64)
    cam = V @ w2c[:3, :3].T + w2c[:3, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        uv = (cam @ np.asarray(K, np.float64).T)
        uv = uv[:, :2] / uv[:, 2:3]
    z = cam[:, 2]
    tri_ok = (np.isfinite(uv).all(1) & (z > near))[Fc].all(axis=1)
    P = uv[Fc[tri_ok]]                                  # (triangles, 3, 2)
    mask = np.zeros(height * width, bool)
    if not len(P):
        return mask.reshape(height, width)
    lo = np.clip(np.ceil(P.min(axis=1) - 0.5), 0, [width, height]).astype(np.int64)     # first centre >= min
    hi = np.clip(np.floor(P.max(axis=1) - 0.5), -1, [width - 1, height - 1]).astype(np.int64)
    w, h = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    keep = (w > 0) & (h > 0)
    P, lo, w, h = P[keep], lo[keep], w[keep], h[keep]
    counts = w * h
    start = 0
    while start < len(P):  # chunks of triangles with at most ``chunk`` candidate pixels
        cum = np.cumsum(counts[start:])
        stop = start + max(1, int(np.searchsorted(cum, chunk, side="right")))
        sl = slice(start, stop)
        c = counts[sl]
        t = np.repeat(np.arange(stop - start), c)
        k = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        px = lo[sl][t, 0] + k % w[sl][t]
        py = lo[sl][t, 1] + k // w[sl][t]
        q = np.stack([px + 0.5, py + 0.5], axis=1)
        A, B, C = P[sl][t, 0], P[sl][t, 1], P[sl][t, 2]

        def edge(a, b):
            return (b[:, 0] - a[:, 0]) * (q[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (q[:, 0] - a[:, 0])

        e0, e1, e2 = edge(A, B), edge(B, C), edge(C, A)
        inside = ((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0))
        mask[(py * width + px)[inside]] = True
        start = stop
    return mask.reshape(height, width)


def render_mask(g: splats.Gaussians, K: np.ndarray, world_to_camera: np.ndarray, width: int, height: int,
                reference: bool = False) -> np.ndarray:
    """The asset mask M_a = 1 - transmittance (H, W) float64 of Gaussians in world coordinates, rendered on the
    CPU by the condition renderer (``backend.render``: tile kernels, or the torch pair rasterizer with
    ``reference``)."""
    import torch

    from ..render import gaussians as gs
    from ..render import tiles

    t = lambda a: torch.as_tensor(np.asarray(a, np.float64))  # noqa: E731
    proj = gs.project(t(g.means), t(g.quats), t(g.scales), t(g.opacities), t(g.sh), K, world_to_camera,
                      width, height)
    raster = gs.rasterize if reference else tiles.rasterize
    asset_mask = raster(proj, width, height)[1]
    return asset_mask.numpy()


def mask_metrics(asset_mask: np.ndarray, sil: np.ndarray, threshold: float = 0.5) -> dict:
    """Compare a rendered asset mask M_a (H, W) in [0, 1] with a binary silhouette (H, W).

    * ``iou``: of (M_a >= threshold) and the silhouette;
    * ``mean_abs``: mean |M_a - sil| over the pixels of either (M_a > 1/255 or the silhouette);
    * ``leak``: Σ (1 - M_a) over the silhouette, ``spill``: Σ M_a outside it, both divided by the silhouette's
      area (leak: how transparent the car is, spill: how much it bleeds past its outline; their sum is the L1 error
      per silhouette pixel);
    * ``boundary_px``: the mean distance (pixels) from each boundary pixel of one mask to the other's boundary,
      averaged over both directions; ``boundary_p95_px``: the 95th percentile of those distances.
    """
    from scipy import ndimage

    a = np.clip(np.asarray(asset_mask, np.float64), 0.0, 1.0)
    s = np.asarray(sil, bool)
    m = a >= threshold
    union = m | s
    iou = float((m & s).sum() / max(union.sum(), 1))
    region = (a > 1.0 / 255.0) | s
    mean_abs = float(np.abs(a - s)[region].mean()) if region.any() else 0.0
    area = max(int(s.sum()), 1)

    def boundary(x):
        return x & ~ndimage.binary_erosion(x, border_value=0)

    bm, bs = boundary(m), boundary(s)
    if bm.any() and bs.any():
        d_ms = ndimage.distance_transform_edt(~bs)[bm]
        d_sm = ndimage.distance_transform_edt(~bm)[bs]
        bnd = 0.5 * (float(d_ms.mean()) + float(d_sm.mean()))
        p95 = float(np.percentile(np.concatenate([d_ms, d_sm]), 95))
    else:
        bnd = p95 = float("inf") if (bm.any() or bs.any()) else 0.0
    return {"iou": iou, "mean_abs": mean_abs, "leak": float((1.0 - a)[s].sum() / area),
            "spill": float(a[~s].sum() / area), "boundary_px": bnd, "boundary_p95_px": p95}
