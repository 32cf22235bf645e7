"""Box proposals: objects of the reconstruction above the road that nothing in the job labels (docs/design.md §15).

A recorded drive shows objects (parked cars, a van, a pedestrian) that no recorded object describes; left alone they
are pixels of a car labelled as background. This module finds them in the points alone, so that each becomes a
recorded object (accepted), an ignore region (``RecordedObject.ignore``), or is rejected by a person.

How (world metres, Z up; the road of ``road.Road``, which these rules build on):

1. **Cells.** The road's *occupied* 0.25 m cells (at least ``road.MIN_OCCUPIED_POINTS`` points 0.3–2.5 m above the
   road) are grouped into clusters of 8-connected cells.
2. **Objects above the road.** A cluster is kept when it has at least ``MIN_CELLS`` cells, ``MIN_POINTS`` points
   and its highest points stand at least ``MIN_TOP_M`` above the road, and when it stands *on* the road: of the
   cells around it (a ring ``RING_CELLS`` wide, other occupied cells left out) whose low points were seen, at most
   ``MAX_RAISED_RING`` are raised (a sidewalk, a kerb top: ``Road.raised``). A pole or a facade on the sidewalk is
   ringed by raised cells; a car parked at the kerb has the road on three sides.
3. **Not labelled already.** A cluster is *covered*, and dropped, when at least ``COVERED_FRACTION`` of its cells'
   centres fall inside the footprint, grown by ``COVER_MARGIN_M``, of a recorded object's box at any of its frames,
   a removal box, or an inserted asset's box at any frame (``covering_boxes``).
4. **Box.** The points of the cluster's cells between ``GROUND_CLEARANCE_M`` and ``MAX_TOP_M`` above the road give
   the upright box (``core.geometry.boxes.estimate_box``, up = world +z); its bottom is lowered to the road under its
   centre (an object stands on the road; its lowest points are hidden or cut as road). The box covers what the
   points show: a car seen from one side only gets its length and height but a thin width.
5. **Class** from the box's size (``guess_class``, ``core.categories`` names): ``truck`` when the length is at least
   ``TRUCK_LENGTH_M``; ``car`` when the length is ``CAR_LENGTH_M`` and the height ``CAR_HEIGHT_M`` (the width is not
   asked: one side of a car is often all that was seen); ``misc`` otherwise.
6. **Score** 0–1: the share of the box's footprint cells that are occupied (a solid object fills its box, a loose
   scatter of floaters does not).
7. **Ids** ``proposal_NN`` (01, 02, …) in the order of the box centres' distance from the drive's first camera (ties:
   x, then y): the same points and job give the same ids.

numpy only (it runs in Blender's Python and in the backend). On the street fixture (1.2 M points): 1.3–1.4 s with the
points' loading (0.2 s), the road ~1 s of it, the three boxes ~0.15 s (2.1–2.5 s with the 2 cores busy);
``tests/core/variation/test_proposals.py`` measures it. ``scene_clusters`` computes a scene's clusters once per
process; ``with_proposals`` adds a job's to it (the backend's ``--proposals``, Blender's render plan).
"""

from __future__ import annotations

import json
import os
from collections import OrderedDict, deque
from dataclasses import dataclass, replace

import numpy as np

from .. import frame_keys, job_inputs
from .. import job as job_mod
from ..geometry import boxes, cameras
from . import placement
from .road import Road, footprint_samples
from .variants import recorded_path, reference_path, scene_points

#: The road's RANSAC seed for proposals: fixed, so the same input always gives the same proposals.
SEED = 0
MIN_CELLS = 3                 # 0.19 m²: a pedestrian or a cone counts, a lone noisy cell does not
MIN_POINTS = 30
MIN_TOP_M = 0.5
RING_CELLS = 2                # 0.5 m around the cluster
MAX_RAISED_RING = 0.5
COVER_MARGIN_M = 0.5
COVERED_FRACTION = 0.5
GROUND_CLEARANCE_M = 0.1      # points lower than this are the road's (its noise is a few cm)
MAX_TOP_M = 4.5               # a truck's roof; a tree's canopy above is not the object's
FIT_POINTS = 5000             # a seeded sample of a cluster's points fits its box (30 k took 0.3 s a box)
TRUCK_LENGTH_M = 6.0
CAR_LENGTH_M = (2.5, 6.0)
CAR_HEIGHT_M = (1.0, 2.5)
#: What ``--proposals`` and the review can do with a proposal: add it as a recorded object (labelled), add it as an
#: ignore region (a recorded object with ``ignore``), or nothing.
MODES = ("accept", "ignore", "off")
DEFAULT_MODE = "ignore"
#: The ``warning`` event's code for a proposal added as an ignore region (the backend's and Blender's render plan's).
UNLABELLED = "unlabelled_object"
#: Changes when the rules above change what is proposed (the per-scene cache key holds it).
VERSION = 2
#: Scenes whose clusters a process keeps (``scene_clusters``: the last used).
KEPT_SCENES = 4
_SCENES: OrderedDict = OrderedDict()


@dataclass
class Proposal:
    """One object above the road that nothing labels: ``id`` (``proposal_NN``), ``category`` (``guess_class``),
    ``box_to_world`` (4, 4) rigid (box frame: x across, y along the length, z up, centred; ``core.geometry.boxes``),
    ``size`` (3,) width, length, height metres, ``points`` (the cluster's points the box was fitted on), ``score``
    (0–1, module docstring) and ``cells`` (the occupied cells of its cluster)."""
    id: str
    category: str
    box_to_world: np.ndarray
    size: np.ndarray
    points: int
    score: float
    cells: int

    def recorded_object(self, frames, ignore: bool) -> job_mod.RecordedObject:
        """The proposal as a recorded object of the job: a static box at every output frame of ``frames``."""
        T = np.asarray(self.box_to_world, np.float64)
        return job_mod.RecordedObject(self.id, np.asarray(self.size, np.float64).copy(),
                                      {int(f): T.copy() for f in frames}, self.category, bool(ignore))

    def to_dict(self) -> dict:
        return {"id": self.id, "class": self.category, "box_to_world": np.asarray(self.box_to_world).tolist(),
                "size": [float(v) for v in self.size], "points": int(self.points), "score": float(self.score),
                "cells": int(self.cells)}

    @classmethod
    def from_dict(cls, d: dict) -> "Proposal":
        """The inverse of ``to_dict`` (a file this module wrote: the cache; KeyError/ValueError otherwise)."""
        T = np.asarray(d["box_to_world"], np.float64)
        size = np.asarray(d["size"], np.float64)
        if T.shape != (4, 4) or size.shape != (3,) or not (np.isfinite(T).all() and np.isfinite(size).all()):
            raise ValueError("not a proposal's box")
        return cls(str(d["id"]), str(d["class"]), T, size, int(d["points"]), float(d["score"]), int(d["cells"]))


def guess_class(size) -> str:
    """The class of an object from its box ``size`` (width, length, height metres): module docstring, step 5."""
    length, height = float(size[1]), float(size[2])
    if length >= TRUCK_LENGTH_M:
        return "truck"
    if CAR_LENGTH_M[0] <= length < CAR_LENGTH_M[1] and CAR_HEIGHT_M[0] <= height <= CAR_HEIGHT_M[1]:
        return "car"
    return "misc"


def covering_boxes(job: job_mod.Job, asset_boxes: list | None = None) -> list:
    """(box_to_world (4, 4), size (3,)) of every box that already accounts for an object: the recorded objects' at
    each of their frames, the removal boxes, and each inserted asset's at every output frame. ``asset_boxes``: per
    asset (box_to_file, size) or None (default: the job's ``assets[i].box``; an asset without one covers nothing
    here: the renderer estimates its box from the Gaussians, which ``propose``'s callers pass when they have it)."""
    out = []
    if job.scene is not None:
        for o in job.scene.recorded_objects:
            out += [(T, o.size) for T in o.boxes.values()]
        out += [(b.box_to_world, b.size) for b in job.scene.removal_boxes]
    if asset_boxes is None:
        asset_boxes = [None if a.box is None else (a.box.box_to_file, a.box.size) for a in job.assets]
    for a, box in zip(job.assets, asset_boxes):
        if box is None:
            continue
        for A in a.object_to_world.values():
            with np.errstate(all="ignore"):
                try:
                    placed = boxes.place_box(box[0], box[1], A)
                except np.linalg.LinAlgError:
                    continue
            if np.isfinite(placed[0]).all() and np.isfinite(placed[1]).all():
                out.append(placed)
    return out


def components(mask: np.ndarray) -> list:
    """The 8-connected clusters of a boolean grid (H, W): a list of (M, 2) cell indices, in the order of each
    cluster's first cell in row-major order (deterministic)."""
    grid = np.asarray(mask, bool)
    label = np.full(grid.shape, -1, np.int64)
    out = []
    for start in map(tuple, np.argwhere(grid)):     # occupied cells are few (hundreds to thousands)
        if label[start] >= 0:
            continue
        label[start] = len(out)
        queue, cells = deque([start]), []
        while queue:
            i, j = queue.popleft()
            cells.append((i, j))
            for di in (-1, 0, 1):
                for dj in (-1, 0, 1):
                    a, b = i + di, j + dj
                    if 0 <= a < grid.shape[0] and 0 <= b < grid.shape[1] and grid[a, b] and label[a, b] < 0:
                        label[a, b] = len(out)
                        queue.append((a, b))
        out.append(np.array(cells, np.int64))
    return out


def _dilate(mask: np.ndarray, steps: int) -> np.ndarray:
    """``mask`` grown by ``steps`` cells in the 8 directions."""
    out = mask.copy()
    for _ in range(steps):
        grown = out.copy()
        grown[1:] |= out[:-1]
        grown[:-1] |= out[1:]
        out = grown.copy()
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        out = grown
    return out


def _covered(xy: np.ndarray, covers: list) -> bool:
    """Step 3: whether ``COVERED_FRACTION`` of cell centres ``xy`` (M, 2) lie in the grown footprints of
    ``covers``."""
    if not covers:
        return False
    inside = np.zeros(len(xy), bool)
    for T, size in covers:
        fp = placement.box_footprint(T, size, COVER_MARGIN_M)
        u, v = fp[1] - fp[0], fp[3] - fp[0]
        d = xy - fp[0]
        a, b = d @ u / (u @ u), d @ v / (v @ v)
        inside |= (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        if inside.mean() >= COVERED_FRACTION:
            return True
    return False


def _on_road(road: Road, cells: np.ndarray) -> bool:
    """Step 2's ring test: few raised cells around the cluster (module docstring)."""
    lo, hi = np.maximum(cells.min(0) - RING_CELLS - 1, 0), np.minimum(cells.max(0) + RING_CELLS + 2,
                                                                      road.cell_shape)
    own = np.zeros(tuple(hi - lo), bool)
    own[cells[:, 0] - lo[0], cells[:, 1] - lo[1]] = True
    ring = _dilate(own, RING_CELLS) & ~road.occupied[lo[0]:hi[0], lo[1]:hi[1]]
    seen = ring & road.observed[lo[0]:hi[0], lo[1]:hi[1]]
    if not seen.any():
        return False                                 # nothing seen around it: no evidence of a road under it
    return float(road.raised[lo[0]:hi[0], lo[1]:hi[1]][seen].mean()) <= MAX_RAISED_RING


@dataclass
class Cluster:
    """A cluster of occupied cells standing on the road (steps 1, 2, 4 and 6), before the job's boxes are asked:
    its box (``box_to_world``, ``size``), ``points``, ``score`` and the world x, y of its cells' centres
    ``cells_xy`` (M, 2)."""
    box_to_world: np.ndarray
    size: np.ndarray
    points: int
    score: float
    cells_xy: np.ndarray


def clusters(points: np.ndarray, path_centres: np.ndarray | None, road: Road | None = None) -> list:
    """The ``Cluster`` list of a reconstruction: ``points`` (N, 3) world metres as the renderer loads them
    (``variants.scene_points``), the road grown from the drive's camera centres ``path_centres`` (F, 3) (or
    ``road``, the ``Road`` of these points when the caller has it; ``path_centres`` may then be None). ValueError when the reconstruction holds no road
    under the drive (``Road``)."""
    if road is None:
        road = Road(points, path_centres, seed=SEED)
    P = np.asarray(points, np.float64).reshape(-1, 3)
    # only the points over occupied cells matter: found by their cell first (cheap), heights for those alone
    c = np.floor((P[:, :2] - road.origin[:2] - road.lo) / road.cell_m)
    inside = np.all((c >= 0) & (c < np.array(road.cell_shape)), axis=1)
    over = np.zeros(len(P), bool)
    over[inside] = road.occupied[c[inside, 0].astype(np.int64), c[inside, 1].astype(np.int64)]
    P = P[over]
    h, cij, keep = road.heights(P)
    P = P[keep]
    body = (h >= GROUND_CLEARANCE_M) & (h <= MAX_TOP_M)
    P, h, cij = P[body], h[body], cij[body]
    flat = cij[:, 0] * road.cell_shape[1] + cij[:, 1]
    order = np.argsort(flat, kind="stable")
    flat_sorted = flat[order]
    found = []
    for cells in components(road.occupied):
        if len(cells) < MIN_CELLS:
            continue
        keys = np.sort(cells[:, 0] * road.cell_shape[1] + cells[:, 1])
        lo, hi = np.searchsorted(flat_sorted, keys, "left"), np.searchsorted(flat_sorted, keys, "right")
        idx = order[np.concatenate([np.arange(a, b) for a, b in zip(lo, hi)])]
        if len(idx) < MIN_POINTS or h[idx].max() < MIN_TOP_M or not _on_road(road, cells):
            continue
        found.append(_fit(road, P[idx], cells))
    return found


def select(found: list, job: job_mod.Job, asset_boxes: list | None = None) -> list:
    """The proposals of a job among a scene's ``clusters``: those no box of the job covers (step 3:
    ``covering_boxes`` with ``asset_boxes``), classed and numbered (steps 5 and 7; a number a recorded object of
    the job already uses as its id is skipped)."""
    covers = covering_boxes(job, asset_boxes)
    kept = [c for c in found if not _covered(c.cells_xy, covers)]
    first = cameras.camera_centers(job.frames[0].world_to_camera) if job.frames else np.zeros(3)
    kept.sort(key=lambda c: (round(float(np.linalg.norm(c.box_to_world[:2, 3] - first[:2])), 3),
                             float(c.box_to_world[0, 3]), float(c.box_to_world[1, 3])))
    taken = {o.id for o in job.scene.recorded_objects} if job.scene is not None else set()
    out, n = [], 0
    for c in kept:
        n += 1
        while f"proposal_{n:02d}" in taken:
            n += 1
        out.append(Proposal(f"proposal_{n:02d}", guess_class(c.size), c.box_to_world, c.size, c.points, c.score,
                            len(c.cells_xy)))
    return out


def propose(points: np.ndarray, job: job_mod.Job, asset_boxes: list | None = None) -> list:
    """``select(clusters(points, the job's first camera path's centres), job, asset_boxes)``: the proposals
    (``Proposal``) of one job."""
    return select(clusters(points, reference_path(job).centres), job, asset_boxes)


def describe(p: Proposal) -> str:
    """``proposal_01: a car (4.4 x 1.8 x 1.6 m) at (6.2, 17.5)``: a proposal in words (events, the Blender UI)."""
    T = p.box_to_world
    return (f"{p.id}: a {p.category} ({p.size[1]:.1f} x {p.size[0]:.1f} x {p.size[2]:.1f} m) at "
            f"({T[0, 3]:.1f}, {T[1, 3]:.1f})")


def _fit(road: Road, pts: np.ndarray, cells: np.ndarray) -> Cluster:
    """The ``Cluster`` of one cluster's cells and points (steps 4 and 6)."""
    sample = pts if len(pts) <= FIT_POINTS else pts[np.random.default_rng(SEED).choice(len(pts), FIT_POINTS, False)]
    T, size = boxes.estimate_box(sample)
    bottom, top = T[2, 3] - size[2] / 2, T[2, 3] + size[2] / 2
    above, _, kept = road.heights(T[None, :3, 3])   # the centre's height above the road (the nearest road tile)
    road_z = T[2, 3] - above[0] if kept[0] else bottom
    T = T.copy()
    size = np.array([size[0], size[1], top - min(bottom, road_z)])
    T[2, 3] = top - size[2] / 2
    S = footprint_samples(placement.box_footprint(T, size))
    c = np.floor((S - road.origin[:2] - road.lo) / road.cell_m).astype(np.int64)
    inside = np.all((c >= 0) & (c < np.array(road.cell_shape)), axis=1)
    c = np.unique(c[inside], axis=0)
    score = float(road.occupied[c[:, 0], c[:, 1]].mean()) if len(c) else 0.0
    return Cluster(T, size, len(pts), score, road.cell_centres(cells))


def unlabelled_message(p: Proposal) -> str:
    """The ``warning`` event's message for a proposal made an ignore region."""
    return (describe(p) + ": nothing labels it, so it is an ignore region in every export (accept it in Blender, "
            "or pass --proposals accept to label it)")


# -- a job's proposals, once per scene ----------------------------------------------------------------------------

def _scene_key(job: job_mod.Job, job_path: str | os.PathLike) -> str:
    """What a scene's clusters depend on: the predictions file (real path, size, mtime: ``frame_keys.stamp``) and
    the settings its cloud is made from (``Job.layers_dict()["scene"]``: transform, confidence, removal boxes,
    cleaning). Not the job's camera path: the road grows from the recording's own drive (``recorded_path``), so
    every camera path and variant of a drive shares one entry."""
    pred = os.path.realpath(job_mod.resolve(job_path, job.scene.predictions))
    scene = {k: v for k, v in job.layers_dict()["scene"].items() if k != "predictions"}
    return json.dumps({"points": [pred, *frame_keys.stamp(pred)], "scene": scene, "version": VERSION},
                      sort_keys=True)


def scene_clusters(job: job_mod.Job, job_path: str | os.PathLike) -> tuple:
    """(``clusters`` of the job's reconstruction, None) computed once per scene in a process (``_scene_key``; the
    last ``KEPT_SCENES`` kept: a warm backend, a batch, many variants of one drive, Blender's render clicks), or
    ([], why) when it holds no road under the recording's drive. The points are read as the renderer reads them
    (``variants.scene_points``; its InputErrors name the file); the road grows from the recording's own cameras
    (``variants.recorded_path``), not the job's: a variant 3 m to the side finds the drive's proposals."""
    key = _scene_key(job, job_path)
    if key not in _SCENES:
        predictions = job_inputs.scene_predictions(job_path, job.scene)
        points, drive = scene_points(job, job_path, predictions), recorded_path(job, predictions).centres
        try:
            _SCENES[key] = clusters(points, drive), None
        except ValueError as e:   # the Road's: no level ground under the drive
            _SCENES[key] = [], str(e)
        while len(_SCENES) > KEPT_SCENES:
            _SCENES.popitem(last=False)
    _SCENES.move_to_end(key)
    return _SCENES[key]


def with_proposals(job: job_mod.Job, job_path: str | os.PathLike, mode: str) -> tuple:
    """(the job with its proposals added as ``mode`` says, the proposals, why there are none or None): ``accept``
    adds each as a recorded object (a static box at every output frame, its class guessed), ``ignore`` as one with
    ``ignore`` (an ignore region in every export), ``off`` nothing. Label-only (``Job.LABEL_ONLY``): the layers'
    key does not change. A job without a scene or frames is returned as it is; a rig job gets one set, its first
camera's, which all its camera jobs then share. ValueError for another mode."""
    if mode not in MODES:
        raise ValueError(f"proposals mode {mode!r} is not one of {MODES}")   # the callers' choices
    if mode == "off" or job.scene is None or not job.frames:
        return job, [], None
    found, why = scene_clusters(job, job_path)
    # a rig job's proposals are its first camera's (numbered by distance from it): one set for every camera
    chosen = select(found, job.camera_jobs()[0][1])
    if not chosen:
        return job, [], why
    frames = [e.frame for e in job.frames]
    added = [p.recorded_object(frames, mode == "ignore") for p in chosen]
    return replace(job, scene=replace(job.scene, recorded_objects=list(job.scene.recorded_objects) + added)), \
        chosen, None
