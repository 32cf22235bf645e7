"""What a rig job looks like at one frame, as a picture (docs/design.md §17): its cameras' labelled previews tiled
in nuScenes' layout beside a bird's-eye view of the LiDAR sweep with every object's box, written by ``render`` as
``<output_dir>/surround_NNNNNN.png`` (``OutputLayout.surround``) once the frame's cameras and sweep exist.

Layout: the cameras named like nuScenes' six in two rows as the devkit's ``render_sample`` shows them (front
left, front, front right; back left, back, back right), any other rig's cameras in its order, three to a row;
each tile the camera's ``labelled_NNNNNN.png`` scaled to one tile height. The bird's-eye view (``bird_eye``):
the ego frame from above (x forward up the picture, y left to the left), ``BEV_RANGE_M`` around the ego; returns
as dots shaded by height, each labelled object's box footprint (``box_world``, moved into the ego frame) in the
labelled previews' colours (an inserted car its track's, a recorded object white, an ignore region grey) with its
track id, inserted cars drawn thicker, the ego as a triangle. OpenCV draws (as the
labelled previews do).
"""

from __future__ import annotations

import numpy as np

from scpainter_blender.core import errors, files, labels
from scpainter_blender.core.geometry import cameras
from scpainter_blender.core.output_layout import OutputLayout

from .. import png
from . import labelled

#: nuScenes' six cameras as the devkit's render_sample lays them out: two rows of three
NUSCENES_TILES = (("CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT"), ("CAM_BACK_LEFT", "CAM_BACK", "CAM_BACK_RIGHT"))
TILE_HEIGHT = 180          # px of each camera tile
BEV_RANGE_M = 40.0         # the bird's-eye view shows ± this around the ego
BEV_SIZE = 360             # px of the bird's-eye view (square)


def tile_rows(names: list) -> list:
    """Rows of camera names: nuScenes' layout when the rig has its six names, else the rig's order three a row."""
    if set(names) == {n for row in NUSCENES_TILES for n in row}:
        return [list(r) for r in NUSCENES_TILES]
    return [names[i:i + 3] for i in range(0, len(names), 3)]


def _fit(img: np.ndarray, h: int) -> np.ndarray:
    import cv2

    w = max(1, int(round(img.shape[1] * h / img.shape[0])))
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA if img.shape[0] > h else cv2.INTER_LINEAR)


def camera_tiles(root: str, names: list, frame: int, height: int = TILE_HEIGHT) -> np.ndarray:
    """(H, W, 3) uint8: the cameras' labelled previews (the condition preview where a labelled one is missing) of
    ``frame`` tiled by ``tile_rows``, each named in its corner."""
    import cv2

    layout = OutputLayout(root)
    rows = []
    for row in tile_rows(names):
        tiles = []
        for name in row:
            cam = layout.camera(name)
            img = _read(cam.labelled_preview(frame))
            img = _read(cam.condition_preview(frame)) if img is None else img
            img = np.zeros((height, height * 16 // 9, 3), np.uint8) if img is None else img
            tile = np.ascontiguousarray(_fit(img, height))
            cv2.putText(tile, name, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
            tiles.append(tile)
        rows.append(np.concatenate(tiles, axis=1))
    width = max(r.shape[1] for r in rows)
    return np.concatenate([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows], axis=0)


def _read(path: str) -> np.ndarray | None:
    """A PNG this render wrote, as RGB uint8 (a regular file only: never a FIFO), or None when it is not there."""
    import cv2

    try:
        with files.open_regular(path) as f:
            data = f.read()
    except (errors.InputError, OSError):
        return None
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    return None if img is None else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def bird_eye(points_ego: np.ndarray, objects: list, world_to_ego: np.ndarray, size: int = BEV_SIZE,
             range_m: float = BEV_RANGE_M) -> np.ndarray:
    """(size, size, 3) uint8: returns ``points_ego`` (R, 3) in the ego frame (x forward, y left, z up, metres) from
    above, shaded by height, and each object of a frame's labels (``box_world``: centre, size [l, w, h], yaw) moved
    into the ego frame by ``world_to_ego`` (4, 4), its footprint in the labelled previews' colours with
    ``#track_id``."""
    import cv2

    img = np.full((size, size, 3), 24, np.uint8)
    s = size / (2.0 * range_m)

    def px(xy):  # ego (x forward, y left) -> picture (column right, row down): forward is up
        xy = np.asarray(xy, np.float64)
        return np.stack([size / 2 - xy[..., 1] * s, size / 2 - xy[..., 0] * s], -1)

    for r in (10, 20, 30, 40):
        if r < range_m:
            cv2.circle(img, (size // 2, size // 2), int(r * s), (60, 60, 60), 1, cv2.LINE_AA)
    p = np.asarray(points_ego, np.float64).reshape(-1, 3)
    if len(p):
        uv = np.round(px(p[:, :2])).astype(np.int64)
        ok = (uv[:, 0] >= 0) & (uv[:, 0] < size) & (uv[:, 1] >= 0) & (uv[:, 1] < size)
        shade = np.clip((p[ok, 2] + 0.5) / 3.0, 0, 1)
        img[uv[ok, 1], uv[ok, 0]] = (np.stack([0.4 + 0.6 * shade, 0.7 + 0.3 * shade, 1.0 - 0.5 * shade], -1)
                                     * 220).astype(np.uint8)
    R, t = np.asarray(world_to_ego, np.float64)[:3, :3], np.asarray(world_to_ego, np.float64)[:3, 3]
    for o in objects:
        b = o.get("box_world")
        if not b or o.get("removed"):
            continue
        l, w = float(b["size"][0]), float(b["size"][1])
        rot = cameras.quaternion_to_rotation(np.asarray(b["quaternion"], np.float64))
        corners = np.array([[l / 2, w / 2, 0], [l / 2, -w / 2, 0], [-l / 2, -w / 2, 0], [-l / 2, w / 2, 0]])
        world = corners @ rot.T + np.asarray(b["center"], np.float64)
        ego = world @ R.T + t
        poly = np.round(px(ego[:, :2])).astype(np.int32)
        # the labelled previews' colours: an inserted car its track's, a recorded object white, ignore grey
        colour = labelled.IGNORE_COLOUR if labels.unlabelled(o) else \
            labelled.track_colour(o["track_id"]) if o.get("synthetic") else labelled.RECORDED_COLOUR
        cv2.polylines(img, [poly], True, colour, 2 if o.get("synthetic") else 1, cv2.LINE_AA)
        front = np.round(px(((ego[0] + ego[1]) / 2)[:2])).astype(int)
        centre = np.round(px(ego[:, :2].mean(0))).astype(int)
        cv2.line(img, tuple(int(v) for v in centre), tuple(int(v) for v in front), colour, 1, cv2.LINE_AA)
        cv2.putText(img, f"#{o.get('track_id')}", (int(centre[0]) + 4, int(centre[1]) - 4),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.35, colour, 1, cv2.LINE_AA)
    ego_tri = np.round(px(np.array([[2.5, 0.0], [-1.0, 1.0], [-1.0, -1.0]]))).astype(np.int32)
    cv2.fillPoly(img, [ego_tri], (255, 255, 255))
    return img


def surround(root: str, names: list, frame: int, sweep_rows: np.ndarray | None, lidar_to_ego: np.ndarray | None,
             labels_path: str, ego_to_world: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: ``camera_tiles`` with the ``bird_eye`` view of the frame's sweep (``sweep_rows`` (R, ≥3)
    in the sensor frame, moved by ``lidar_to_ego``; None: no LiDAR) and the objects of ``labels_path`` (a
    camera's labels of the frame: every object's world box, in view of that camera or not) on its right."""
    tiles = camera_tiles(root, names, frame)
    pts = np.zeros((0, 3))
    if sweep_rows is not None and lidar_to_ego is not None and len(sweep_rows):
        L = np.asarray(lidar_to_ego, np.float64)
        pts = sweep_rows[:, :3].astype(np.float64) @ L[:3, :3].T + L[:3, 3]
    objects = files.read_json(labels_path).get("objects", [])
    bev = bird_eye(pts, objects, cameras.rigid_inverse(np.asarray(ego_to_world, np.float64)), size=tiles.shape[0])
    return np.concatenate([tiles, bev], axis=1)


def write_pictures(root: str, job, frames=None) -> list:
    """``surround`` of each frame of rig job ``job`` (``frames``: those; None: all) written to
    ``OutputLayout(root).surround(frame)`` (``png.write_png``, atomic); the paths. The objects are the first
    camera's labels' (every object's world box is in each camera's labels)."""
    from backend.lidar import sweep as sweep_mod

    layout = OutputLayout(root)
    rig = job.rig
    names = [c.name for c in rig.cameras]
    first = layout.camera(names[0])
    out = []
    for e in job.frames:
        if frames is not None and e.frame not in frames:
            continue
        rows = None
        if rig.lidar is not None:
            try:
                rows = sweep_mod.read_pcd_bin(layout.lidar_sweep(e.frame, rig.lidar.name))
            except (OSError, errors.InputError):
                rows = None
        picture = surround(root, names, e.frame, rows, None if rig.lidar is None else rig.lidar.lidar_to_ego,
                           first.frame_labels(e.frame), e.ego_to_world)
        path = layout.surround(e.frame)
        png.write_png(path, picture)
        out.append(path)
    return out
