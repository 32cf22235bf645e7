"""The reconstructed road, found headless: where a car may stand, at what height, and what is already there.

Frame: world metres, Z up (Blender's, docs/design.md §3). Everything is computed relative to ``origin`` (the
reference path's first camera), so 1e5 m scenes stay exact.

How (each step is the rule a placement is checked against, ``Road.check_footprint``):

1. **Tiles.** The points are binned into ``tile_m`` squares; each tile with at least ``MIN_TILE_POINTS`` points
   gets the project's one RANSAC ground plane (``core.geometry.fits.fit_plane_ransac``, as *Snap to Ground*
   fits one under an asset: inliers closer than ``threshold_m``, level within ``max_tilt_deg``), seeded per tile.
   A tile whose points hold no level plane (a facade) has none.
2. **Road tiles.** Starting from the tiles under the reference path's cameras, a tile joins the road when a
   neighbour on the road meets it: their planes' heights at the middle of the shared edge differ by less than
   ``step_m`` and their normals by less than ``bend_deg``. A kerb (15 cm) or a wall ends the road, and so does
   a tile whose plane leans across a kerb (4° over 2 m); a slope or a camber, bending by a fraction of a degree
   per tile, does not.
3. **Cells** (``cell_m`` squares), heights measured above the *road*: a road tile's own plane, or for any other
   tile the plane of the nearest road tile (a tile under a parked car holds its roof, not the road). A cell is
   *occupied* when at least ``MIN_OCCUPIED_POINTS`` points stand ``min_object_m``–``max_object_m`` above the road
   (a parked car, a pole, a building), and *raised* when most of its lower points lie between ``step_m`` and
   ``min_object_m`` above it (a sidewalk, a kerb top). A cell without points (road hidden behind a car) is
   neither.

A footprint is **on a recorded object** when a sample under it falls in an occupied cell, and **off the road**
when a sample falls on a tile that is not road or more than ``MAX_RAISED_FRACTION`` of its observed samples are
raised.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from ..geometry import fits

if TYPE_CHECKING:
    from .placement import Path

MIN_TILE_POINTS = 30
MAX_TILE_SAMPLE = 3000          # points a tile's RANSAC sees at most (a fixed, seeded subsample)
MIN_OCCUPIED_POINTS = 3
MAX_RAISED_FRACTION = 0.05
SAMPLE_SPACING_M = 0.25         # the lattice a footprint is tested on


class Road:
    """The road of a reconstruction (module docstring). ``points`` (N, 3) world metres, ``path_centres`` (F, 3)
    the reference path's camera centres (the drive), ``seed`` for the RANSAC fits.

    ValueError when no tile under the path holds a level plane (no road under the drive)."""

    def __init__(self, points: np.ndarray, path_centres: np.ndarray, *, tile_m: float = 1.0, cell_m: float = 0.25,
                 threshold_m: float = 0.05, max_tilt_deg: float = 15.0, step_m: float = 0.08, bend_deg: float = 2.0,
                 min_object_m: float = 0.3, max_object_m: float = 2.5, reach_m: float = 60.0, seed: int = 0) -> None:
        C = np.asarray(path_centres, np.float64)
        self.origin = C[0].copy()
        self.tile_m, self.cell_m, self.step_m = float(tile_m), float(cell_m), float(step_m)
        self.cos_bend = float(np.cos(np.radians(bend_deg)))
        P = np.asarray(points, np.float64) - self.origin
        P = P[np.isfinite(P).all(1)]
        c = C - self.origin
        lo, hi = c[:, :2].min(0) - reach_m, c[:, :2].max(0) + reach_m
        P = P[np.all((P[:, :2] >= lo) & (P[:, :2] <= hi), axis=1)]
        self.lo = lo
        self.shape = tuple(np.ceil((hi - lo) / tile_m).astype(int) + 1)   # tiles along x, y
        self.planes = np.full(self.shape + (4,), np.nan)                 # (a, b, c, d), relative to origin
        self._fit_tiles(P, threshold_m, max_tilt_deg, seed)
        self.road = self._grow_road(c)
        self.reference = self._nearest_road()
        self._cells(P, min_object_m, max_object_m)

    # -- building ----------------------------------------------------------------------------------------------

    def _tile_index(self, xy) -> tuple:
        ij = np.floor((np.asarray(xy, np.float64) - self.lo) / self.tile_m).astype(np.int64)
        inside = np.all((ij >= 0) & (ij < np.array(self.shape)), axis=-1)
        return ij, inside

    def _fit_tiles(self, P, threshold_m, max_tilt_deg, seed) -> None:
        ij, inside = self._tile_index(P[:, :2])
        key = ij[:, 0] * self.shape[1] + ij[:, 1]
        key = np.where(inside, key, -1)
        order = np.argsort(key, kind="stable")
        keys, starts, counts = np.unique(key[order], return_index=True, return_counts=True)
        for k, a, n in zip(keys.tolist(), starts.tolist(), counts.tolist()):
            if k < 0 or n < MIN_TILE_POINTS:
                continue
            idx = order[a:a + n]
            rng = np.random.default_rng([seed, k])
            if n > MAX_TILE_SAMPLE:
                idx = np.sort(rng.choice(idx, MAX_TILE_SAMPLE, replace=False))
            try:
                plane, _, _ = fits.fit_plane_ransac(P[idx], threshold=threshold_m, iterations=128,
                                                    seed=int(rng.integers(2 ** 31)), max_tilt_deg=max_tilt_deg)
            except fits.PlaneFitError:
                continue                                   # a facade, a pole: no level ground here
            self.planes[k // self.shape[1], k % self.shape[1]] = plane

    def _plane_height(self, i, j, xy) -> np.ndarray:
        """Height of tile (i, j)'s plane (indices of any one shape) over points ``xy`` (..., 2) relative to the
        origin."""
        a, b, c, d = np.moveaxis(self.planes[i, j], -1, 0)
        return -(a * xy[..., 0] + b * xy[..., 1] + d) / c

    def _world_tiles(self, xy) -> tuple:
        """(tile index (..., 2), clamped into the grid; inside (...,)) of world points ``xy`` (..., 2)."""
        ij, inside = self._tile_index(np.asarray(xy, np.float64) - self.origin[:2])
        return np.where(inside[..., None], ij, 0), inside

    def _grow_road(self, c) -> np.ndarray:
        road = np.zeros(self.shape, bool)
        ij, inside = self._tile_index(c[:, :2])
        queue = deque()
        for (i, j), ok in zip(ij.tolist(), inside.tolist()):
            if ok and not road[i, j] and np.isfinite(self.planes[i, j, 0]):
                road[i, j] = True
                queue.append((i, j))
        if not queue:
            raise ValueError("no level ground under the drive's cameras: the reconstruction holds no road there")
        while queue:
            i, j = queue.popleft()
            for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                a, b = i + di, j + dj
                if not (0 <= a < self.shape[0] and 0 <= b < self.shape[1]) or road[a, b] \
                        or not np.isfinite(self.planes[a, b, 0]):
                    continue
                # the middle of the shared edge, in coordinates relative to the origin
                mid = self.lo + self.tile_m * (np.array([max(i, a), max(j, b)], np.float64)
                                               + np.array([0.5 * (di == 0), 0.5 * (dj == 0)]))
                if abs(self._plane_height(i, j, mid) - self._plane_height(a, b, mid)) < self.step_m \
                        and self.planes[i, j, :3] @ self.planes[a, b, :3] > self.cos_bend:
                    road[a, b] = True
                    queue.append((a, b))
        return road

    def _nearest_road(self) -> np.ndarray:
        """(tiles x, tiles y, 2) index of the road tile nearest each tile (4-neighbour steps, a breadth-first
        search from every road tile at once; itself for a road tile), −1 where no road is reachable."""
        ref = np.full(self.shape + (2,), -1, np.int64)
        queue = deque()
        for i, j in zip(*np.nonzero(self.road)):
            ref[i, j] = (i, j)
            queue.append((i, j))
        while queue:
            i, j = queue.popleft()
            for a, b in ((i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)):
                if 0 <= a < self.shape[0] and 0 <= b < self.shape[1] and ref[a, b, 0] < 0:
                    ref[a, b] = ref[i, j]
                    queue.append((a, b))
        return ref

    def _heights(self, P) -> tuple:
        """(height above the road (M,), cell index (M, 2), keep (N,)) of points ``P`` (N, 3) relative to the
        origin: the points kept are those inside the grid with a road tile reachable (module docstring, step 3)."""
        ij, inside = self._tile_index(P[:, :2])
        keep = np.zeros(len(P), bool)
        keep[inside] = self.reference[ij[inside, 0], ij[inside, 1], 0] >= 0
        Q, rij = P[keep], self.reference[ij[keep, 0], ij[keep, 1]]
        h = Q[:, 2] - self._plane_height(rij[:, 0], rij[:, 1], Q[:, :2])   # height above the road
        cij = np.floor((Q[:, :2] - self.lo) / self.cell_m).astype(np.int64)
        return h, np.minimum(cij, np.array(self.cell_shape) - 1), keep

    def _cells(self, P, min_object_m, max_object_m) -> None:
        per_tile = int(round(self.tile_m / self.cell_m))
        self.cell_shape = (self.shape[0] * per_tile, self.shape[1] * per_tile)
        h, cij, _ = self._heights(P)
        flat = cij[:, 0] * self.cell_shape[1] + cij[:, 1]
        size = self.cell_shape[0] * self.cell_shape[1]
        objects = (h >= min_object_m) & (h <= max_object_m)
        self.occupied = (np.bincount(flat[objects], minlength=size) >= MIN_OCCUPIED_POINTS).reshape(self.cell_shape)
        # raised: the median height above the plane of the cell's points below object height, in (step, object)
        low = h < min_object_m
        self.observed = np.bincount(flat[low], minlength=size).reshape(self.cell_shape) > 0
        raised_pts = low & (h > self.step_m)
        n_raised = np.bincount(flat[raised_pts], minlength=size)
        n_low = np.bincount(flat[low], minlength=size)
        self.raised = (n_raised * 2 > n_low).reshape(self.cell_shape)

    # -- queries -----------------------------------------------------------------------------------------------

    def heights(self, points: np.ndarray) -> tuple:
        """(height above the road (M,) metres, cell index (M, 2) into ``occupied``/``raised``, keep (N,) bool) of
        world ``points`` (N, 3): the points kept lie inside the grid where a road tile is reachable, their heights
        above that road tile's plane (module docstring, step 3: what makes a cell occupied)."""
        P = np.asarray(points, np.float64).reshape(-1, 3) - self.origin
        finite = np.flatnonzero(np.isfinite(P).all(1))
        h, cij, kept = self._heights(P[finite])
        keep = np.zeros(len(P), bool)
        keep[finite[kept]] = True
        return h, cij, keep

    def cell_centres(self, cij: np.ndarray) -> np.ndarray:
        """World x, y (..., 2) of the centres of cells ``cij`` (..., 2)."""
        return self.origin[:2] + self.lo + (np.asarray(cij, np.float64) + 0.5) * self.cell_m


    def ground(self, xy: np.ndarray) -> tuple:
        """(z (...,), unit normal (..., 3)) of the ground plane under world points ``xy`` (..., 2); NaN where no
        tile plane is known."""
        ij, inside = self._world_tiles(xy)
        z = self._plane_height(ij[..., 0], ij[..., 1], np.asarray(xy, np.float64) - self.origin[:2])
        normal = self.planes[ij[..., 0], ij[..., 1], :3]
        return np.where(inside, z + self.origin[2], np.nan), np.where(inside[..., None], normal, np.nan)

    def is_road(self, xy: np.ndarray) -> np.ndarray:
        """Whether world points ``xy`` (..., 2) lie on road tiles."""
        ij, inside = self._world_tiles(xy)
        return inside & self.road[ij[..., 0], ij[..., 1]]

    @property
    def area_m2(self) -> float:
        """The road's area: its tiles' (m²)."""
        return float(self.road.sum()) * self.tile_m ** 2

    def edge_distance(self, xy: np.ndarray, direction: np.ndarray, max_m: float,
                      step: float = SAMPLE_SPACING_M) -> float:
        """How far (metres, ≤ ``max_m``) the road reaches from world point ``xy`` (2,) along the unit horizontal
        ``direction`` (2,) before its first tile that is not road (the kerb, the road's end); 0 when ``xy`` itself
        is not on the road."""
        d = np.arange(0.0, max_m + 0.5 * step, step)
        on = self.is_road(np.asarray(xy, np.float64) + d[:, None] * np.asarray(direction, np.float64))
        off = np.flatnonzero(~on)
        return float(max_m if not len(off) else 0.0 if off[0] == 0 else d[off[0] - 1])

    def road_arc(self, path: Path, step: float = 0.5, beyond_m: float = 200.0, lane_m: float = 0.0) -> tuple:
        """(low, high) arc lengths along ``path`` (``placement.Path``, continued straight beyond its ends up to
        ``beyond_m``) over which the path's own line (or the line ``lane_m`` metres left of it) runs on the road:
        where cars can be drawn, where a car driving in that lane must stop. None when it never does."""
        s = np.arange(-beyond_m, path.length + beyond_m + step / 2, step)
        xy, head = path.at(s)
        if lane_m:
            xy = xy + lane_m * np.stack([-head[:, 1], head[:, 0]], axis=1)
        on = self.is_road(xy)
        if not on.any():
            return None
        idx = np.flatnonzero(on)
        return float(s[idx[0]]), float(s[idx[-1]])

    def known(self, xy: np.ndarray) -> np.ndarray:
        """Whether world points ``xy`` (..., 2) lie on tiles whose ground was seen (a plane was fitted)."""
        ij, inside = self._world_tiles(xy)
        return inside & np.isfinite(self.planes[ij[..., 0], ij[..., 1], 0])

    def check_footprint(self, corners_xy: np.ndarray, unseen_ok: bool = False) -> str | None:
        """None when the footprint (4, 2) world corners (a rectangle, in order) may stand here, else the rule it
        breaks: ``"off_road"`` or ``"recorded_object"`` (module docstring). ``unseen_ok``: ground never seen (behind
        the first camera, under the recording car) is taken as road, for the camera path, which drives where the
        recording drove; a car must stand on road that was seen."""
        S = footprint_samples(corners_xy)
        if unseen_ok:
            S = S[self.known(S)]
        cij = np.floor((S - self.origin[:2] - self.lo) / self.cell_m).astype(np.int64)
        inside = np.all((cij >= 0) & (cij < np.array(self.cell_shape)), axis=1)
        cij = cij[inside]
        if np.any(self.occupied[cij[:, 0], cij[:, 1]]):
            return "recorded_object"
        if not inside.all() or not np.all(self.is_road(S)):
            return "off_road"
        raised = self.raised[cij[:, 0], cij[:, 1]]
        seen = self.observed[cij[:, 0], cij[:, 1]]
        if seen.any() and raised[seen].mean() > MAX_RAISED_FRACTION:
            return "off_road"
        return None


def footprint_samples(corners_xy: np.ndarray, spacing: float = SAMPLE_SPACING_M) -> np.ndarray:
    """(M, 2) points covering a rectangle given by its 4 corners in order: a lattice of at most ``spacing``
    inside it, edges and corners included."""
    C = np.asarray(corners_xy, np.float64)
    u, v = C[1] - C[0], C[3] - C[0]
    nu = max(2, int(np.ceil(np.linalg.norm(u) / spacing)) + 1)
    nv = max(2, int(np.ceil(np.linalg.norm(v) / spacing)) + 1)
    a, b = np.meshgrid(np.linspace(0.0, 1.0, nu), np.linspace(0.0, 1.0, nv), indexing="ij")
    return C[0] + a.reshape(-1, 1) * u + b.reshape(-1, 1) * v
