"""Per-frame labels of a rendered job: ``conditions/labels_NNNNNN.json``, schema ``SCHEMA``.

``render`` writes one file per output frame beside its condition EXR (``core/output_layout.FRAME_LABELS``); the
exporters (``backend/export``, one writer per format) read them with the EXR's ``instance`` pass. The file::

    {"schema": SCHEMA,
     "key": "…",                       what the labels were made from (the render's resume key for them)
     "layers_key": "…",                the condition layers' key they were made from (a label-only edit keeps it)
     "frame": 12, "index": 0,          scene frame number; position in the job's frames
     "timestamp_s": 0.0,               (frame − the job's first frame) / fps
     "fps": 10.0, "fps_source": "job", the job's ``fps``, or "default" (``Job.frame_rate``: the MP4 plays at it)
     "image_size": [W, H],
     "camera": {"K": 3x3, "world_to_camera": 4x4, "camera_to_world": 4x4, "vggt_to_world": 4x4 | null,
                "convention": CAMERA_CONVENTION},
     "coverage": 0.83,                 1 − the hole fraction (pixels with a point or an asset)
     "unlabelled_fraction": 0.0,       share of the image's pixels showing ignore regions (below)
     "in_recording": true,             within ``scene.recorded_frames`` (null: the job does not say)
     "flags": ["low_coverage", …],     FLAGS: why a training pipeline may want to drop the frame
     "objects": [OBJECT, …]}

    OBJECT = {"track_id": 1,            stable across frames: an asset's is its instance id (1-based index in
                                        ``job.assets``); a recorded object's is len(assets) + 1 + its index
              "name": "car_01", "class": "car",
              "synthetic": true,        an inserted asset (false: an object of the recording)
              "asset": {"file": "assets/car.ply", "sha256": "…"} | null,
              "box_source": "job" | "estimated" | "recording",
              "removed": false,         a recorded object inside a removal box (replaced or removed): not drawn
              "box_world":  {"center": [x, y, z], "size": [l, w, h], "yaw": rad, "quaternion": [w, x, y, z]},
              "box_camera": {"center": [x, y, z], "size": [l, w, h], "yaw": rotation_y, "quaternion": [w, x, y, z]},
              "velocity": [vx, vy, vz] | null,   world m/s from the neighbouring frames' boxes (null: one frame)
              "bbox_amodal": [x0, y0, x1, y1] | null,  the projected 3D box, clipped to the image
              "bbox_visible": [x0, y0, x1, y1] | null, the visible pixels' box (instance pass; depth for recorded)
              "visible_pixels": n, "amodal_pixels": n, "visible_fraction": f | null,
              "truncation": 0..1, "occlusion": 0 | 1 | 2 | 3,
              "in_view": bool, "camera_inside": bool,
              "ignore": false,          the recorded object's ``ignore``: seen but not labelled (assets: false)
              "points_missing": false,  a recorded object in view whose points are missing (below)
              "hole_fraction": f | null} share of its image region that is holes the generator fills (below)

(An OBJECT's keys are ``OBJECT_FIELDS``, in that order; the exporters carry its ``CARRIED_IDENTITY`` and
``CARRIED_MEASURES`` as extra attributes of each object.)

Conventions: world is the job's (Blender's: Z up, metres). Boxes use ``core.geometry.boxes``' object frame (x
forward, y left, z up) for ``quaternion`` (object_to_world, object_to_camera) and sizes (length, width, height);
``box_world.yaw`` is the forward axis' heading from world +x towards +y; ``box_camera.yaw`` is KITTI's
``rotation_y``. 2D boxes are in continuous pixel coordinates (pixel (u, v) covers [u, u+1) × [v, v+1)), x1/y1
exclusive edges. ``truncation`` = 1 − clipped/unclipped area of the projected box. ``occlusion`` (KITTI's levels):
0 when at most ``OCCLUSION_LEVELS[0]`` of the amodal pixels are hidden, 1 up to ``OCCLUSION_LEVELS[1]``, 2 above, 3
unknown (no amodal pixel).

Pixels of an inserted asset (``synthetic``): ``visible_pixels`` its pixels in the instance pass, ``amodal_pixels``
those it covers rendered alone, ``hole_fraction`` the share of its visible pixels that are holes (the instance pass
only names an asset where its opacity beats what lies behind it, so this is 0 in practice; null: none visible).

Pixels of a recorded object (``recorded_pixels``): the layers hold per pixel the depth ``Z`` of what wins it, a hole
flag and the winning asset. Each pixel whose centre lies inside the projected box is looked at along its ray
(pixel centre (u + 0.5, v + 0.5) through K⁻¹, into the box frame through camera_to_world and the box): the ray
meets the box grown by ``lateral_margin`` (half a pixel's diagonal footprint at the box's far depth: the point that
wins a pixel may lie anywhere in the pixel's footprint) between depths ``entry`` and ``exit``. A pixel showing a
point (no hole, no asset) is the object's (*visible*) when ``entry·(1 − DEPTH_NOISE) ≤ Z ≤ exit·(1 + DEPTH_NOISE)``
(the point lies inside the box, allowing the reconstruction's depth noise); *hidden* when ``Z`` is nearer than
that, or an inserted asset wins the pixel in front of ``exit``; *empty* when it sees beyond the box (or its ray
misses it); a *hole* when no point and no asset covers it; a pixel whose ``Z`` is NaN counts nowhere.
``visible_pixels`` and ``bbox_visible`` are the visible pixels (the object's shape, not its box's);
``amodal_pixels`` = visible + hidden (what the object alone would cover: where something hides it, the box's
silhouette stands for its unknown shape); so a wholly shown object has occlusion 0 whatever its box's empty
corners show. ``hole_fraction`` = holes / (visible + holes): the share of the pixels that show it, or may (holes
within its projected box), that the generator invents; null when there are none. ``points_missing``: in view, not
removed, more than ``POINTS_MISSING_EMPTY`` of its box pixels are empty or holes and fewer than
``POINTS_MISSING_SHARE`` of its *unhidden* box pixels (visible + empty + holes) are visible, i.e. its points were
cut (confidence, cleaning) or never reconstructed: its pixels are then taken from its box — ``visible_pixels`` and
``bbox_visible`` the unhidden box pixels, ``amodal_pixels`` those plus the hidden ones, ``hole_fraction`` holes /
unhidden — never 0 px silently. A ``removed`` object is not drawn: visible 0,
amodal its box's pixels.

An object is an ignore region (``ignore_region``: COCO ``iscrowd 1``, KITTI ``DontCare``, an OpenLABEL object of
type ignore, never a normal label) when it is not removed, in view, and ``ignore`` or ``points_missing``.
``unlabelled_fraction``: the share of the image's pixels that such objects show (an ignore object: its visible
pixels; a points-missing one: its unhidden box pixels), each pixel once. A frame with a points-missing object, or
with ``unlabelled_fraction`` above ``UNLABELLED_SHARE``, is flagged ``UNLABELLED_FLAG``.

Schemas: ``OLD_SCHEMAS`` are files of earlier versions: ``render`` makes them again from the frame's layers (their
assets' amodal counts are still good), never renders the frame again for them; readers of labels refuse them.

numpy only; ``render`` computes the pixel counts, this module the geometry and the file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import job as job_mod
from .geometry import boxes, cameras

SCHEMA = "scpainter.labels/2"
#: Earlier schemas (module docstring): /1 had neither ``ignore``, ``points_missing``, ``hole_fraction`` nor
#: ``unlabelled_fraction``, and counted a recorded object's pixels over its box's rectangle.
OLD_SCHEMAS = ("scpainter.labels/1",)

CAMERA_CONVENTION = ("OpenCV pinhole: world_to_camera maps world metres (Z up) to camera axes x right, y down, "
                     "z forward; K in pixels with pixel centres at +0.5; camera_to_world is its inverse; "
                     "vggt_to_world maps the recording's VGGT frame to world")

#: Why a frame may be dropped: its coverage is below the threshold (``LOW_COVERAGE``), it lies outside the
#: recording's frames, the camera is inside an object's box, or it shows objects that are not labelled (a
#: points-missing object, or ignore regions over more than ``UNLABELLED_SHARE`` of it).
LOW_COVERAGE_FLAG, OUTSIDE_FLAG, CAMERA_INSIDE_FLAG = "low_coverage", "outside_recording", "camera_inside_object"
UNLABELLED_FLAG = "unlabelled_objects"
FLAGS = (LOW_COVERAGE_FLAG, OUTSIDE_FLAG, CAMERA_INSIDE_FLAG, UNLABELLED_FLAG)
#: The default coverage below which a frame is flagged (a fraction of its pixels).
LOW_COVERAGE = 0.5
#: Share of a frame's pixels that ignore regions may show before it is flagged ``UNLABELLED_FLAG`` (1 %: about a
#: car 15 m away in a 518 x 294 frame; a points-missing object flags its frame whatever its size).
UNLABELLED_SHARE = 0.01
#: Hidden fraction of an object's amodal pixels at or below which it is level 0, then level 1.
OCCLUSION_LEVELS = (0.05, 0.5)
#: A recorded object's point may lie this fraction of its depth nearer or farther than its box and still be the
#: object's: the reconstruction's depth noise. The VGGT-like depth the point cleaning was tuned on (design §10:
#: 1 % smooth and 0.25 % per-pixel multiplicative error) stays within 3 % about three standard deviations out; a
#: point the depth-edge cleaning keeps differs from its neighbours by under 5 %.
DEPTH_NOISE = 0.03
#: Below this share of its unhidden box pixels showing its points, a recorded object in view is ``points_missing``
#: (a tenth: a car fills about 60-85 % of its box's silhouette, a loose box still far more than a tenth).
POINTS_MISSING_SHARE = 0.1
#: ... and more than this share of its box pixels (unhidden or hidden) are empty or holes: most of its box sees
#: through it (an object mostly hidden by nearer things is labelled, its occlusion saying so).
POINTS_MISSING_EMPTY = 0.5
#: Near plane of the box projection (metres; the renderer's).
NEAR = 0.05


@dataclass(frozen=True)
class ObjectField:
    """A field of an OBJECT (the module docstring says what each holds): its ``name``, its JSON ``type`` ("int",
    "number", "bool", "string" or a structure's name; "|null" when it may be null), and whether the exporters
    carry it as an extra attribute of each object: ``IDENTITY`` (which object: COCO annotation keys; OpenLABEL has
    them as the object's key and static data) or ``MEASURE`` (COCO annotation keys, OpenLABEL per-frame ``num``:
    numbers only), else ``""``."""
    name: str
    type: str
    carried: str = ""

    @property
    def nullable(self) -> bool:
        return self.type.endswith("|null")


IDENTITY, MEASURE = "identity", "measure"
#: An OBJECT's fields in the file's key order (both builders write them in it: ``_ordered``). A new field: an
#: entry here, its value in both builders (``_object`` for what the box gives), its words in the docstring.
OBJECT_FIELDS = (
    ObjectField("track_id", "int", IDENTITY), ObjectField("name", "string"), ObjectField("class", "string"),
    ObjectField("synthetic", "bool", IDENTITY),
    ObjectField("box_world", "box3d|null"), ObjectField("box_camera", "box3d|null"),
    ObjectField("velocity", "vec3|null"), ObjectField("bbox_amodal", "box2d|null"),
    ObjectField("truncation", "number", MEASURE), ObjectField("in_view", "bool"),
    ObjectField("camera_inside", "bool"), ObjectField("asset", "asset|null"), ObjectField("box_source", "string"),
    ObjectField("removed", "bool"), ObjectField("bbox_visible", "box2d|null"), ObjectField("visible_pixels", "int"),
    ObjectField("amodal_pixels", "int"), ObjectField("visible_fraction", "number|null", MEASURE),
    ObjectField("occlusion", "int", MEASURE), ObjectField("ignore", "bool"), ObjectField("points_missing", "bool"),
    ObjectField("hole_fraction", "number|null", MEASURE))
FIELDS = {f.name: f for f in OBJECT_FIELDS}
#: What the exporters carry of each object: its identity (in the table's order), then its measures, those that
#: may be null first, each group by name — the order the exports have written them since their first version.
CARRIED_IDENTITY = tuple(f.name for f in OBJECT_FIELDS if f.carried == IDENTITY)
CARRIED_MEASURES = tuple(f.name for f in sorted((f for f in OBJECT_FIELDS if f.carried == MEASURE),
                                                key=lambda f: (not f.nullable, f.name)))


def unlabelled(obj: dict) -> bool:
    """Whether an OBJECT is seen but not labelled: ``ignore`` (the recorded object says so) or ``points_missing``
    (its pixels cannot label it). Never exported as a normal label; an ignore region when in view
    (``ignore_region``)."""
    return bool(obj["ignore"] or obj["points_missing"])


def ignore_region(obj: dict) -> list | None:
    """[x0, y0, x1, y1] of an OBJECT exported as an ignore region (COCO ``iscrowd 1``, KITTI ``DontCare``, an
    OpenLABEL object of type ignore), else None: one that is not ``removed``, ``in_view`` and ``unlabelled``; its
    region is ``bbox_visible`` when not null, else ``bbox_amodal``. Such an object is never exported as a normal
    label."""
    if obj["removed"] or not obj["in_view"] or not unlabelled(obj):
        return None
    return obj["bbox_visible"] if obj["bbox_visible"] is not None else obj["bbox_amodal"]


def occlusion_level(visible: int, amodal: int) -> int:
    """KITTI's occlusion level from the visible and amodal (in-image) pixel counts (``OCCLUSION_LEVELS``)."""
    if amodal <= 0:
        return 3
    hidden = 1.0 - min(visible, amodal) / amodal
    return 0 if hidden <= OCCLUSION_LEVELS[0] else 1 if hidden <= OCCLUSION_LEVELS[1] else 2


def pixel_box(mask) -> list | None:
    """[x0, y0, x1, y1] (x1, y1 exclusive pixel edges) of the True pixels of (H, W) ``mask``; None when empty."""
    ys, xs = np.nonzero(mask)
    if not len(xs):
        return None
    return [float(xs.min()), float(ys.min()), float(xs.max() + 1), float(ys.max() + 1)]


def _id_box(ys: np.ndarray, xs: np.ndarray, sel: np.ndarray) -> list | None:
    """``pixel_box`` of the pixels (ys[sel], xs[sel]) (the same numbers as of their mask)."""
    if not sel.any():
        return None
    ys, xs = ys[sel], xs[sel]
    return [float(xs.min()), float(ys.min()), float(xs.max() + 1), float(ys.max() + 1)]


def _box_dict(pose: dict, yaw: float) -> dict:
    return {"center": [float(v) for v in pose["center"]], "size": [float(v) for v in pose["size"]],
            "yaw": float(yaw), "quaternion": [float(v) for v in pose["quaternion"]]}


def _in_camera(box_to_world, world_to_camera) -> np.ndarray:
    return np.asarray(world_to_camera, np.float64) @ np.asarray(box_to_world, np.float64)


def asset_box_to_world(asset: job_mod.Asset, box: tuple, frame: int):
    """(box_to_world rigid, size in metres) of an asset at an output frame; ``box`` = (box_to_file, size). None
    when the placement overflows (a transform scaled by 1e200 is a valid affine: such a box is not labelled)."""
    with np.errstate(all="ignore"):
        try:
            T, size = boxes.place_box(box[0], box[1], asset.object_to_world[frame])
        except np.linalg.LinAlgError:
            return None
    return (T, size) if _finite(T, size) else None


def _finite(*arrays) -> bool:
    return all(np.isfinite(np.asarray(a, np.float64)).all() and np.abs(a).max(initial=0) < 1e150 for a in arrays)


def asset_up(asset: job_mod.Asset) -> np.ndarray:
    """The file-frame direction the asset's transform at its first frame maps to world up (for estimating an
    upright box of a job that gives none): object_to_world⁻¹ applied to +z (linear part)."""
    A = asset.object_to_world[min(asset.object_to_world)]
    up = np.linalg.solve(np.asarray(A, np.float64)[:3, :3], [0.0, 0.0, 1.0])
    return up / np.linalg.norm(up)


def _velocity(centres: dict, frames: list, i: int, fps: float):
    """World m/s of a box centre at frames[i] from its neighbours in the job's frame list (central difference
    where both exist); None when it appears in no neighbour."""
    f = frames[i]
    before = frames[i - 1] if i > 0 and frames[i - 1] in centres else None
    after = frames[i + 1] if i + 1 < len(frames) and frames[i + 1] in centres else None
    a, b = (before if before is not None else f), (after if after is not None else f)
    if a == b:
        return None
    return [float(v) for v in (centres[b] - centres[a]) * fps / (b - a)]


#: An object's geometry when its box cannot be placed (non-finite or overflowing transforms).
_NO_GEOMETRY = {"box_world": None, "box_camera": None, "velocity": None, "bbox_amodal": None, "truncation": 1.0,
                "in_view": False, "camera_inside": False}
_NO_PROJECTION = boxes.unseen_projection()


def _ordered(fields: dict) -> dict:
    """An OBJECT with its keys in ``OBJECT_FIELDS``' order; KeyError naming a field a builder did not fill,
    ValueError for one the table does not have."""
    obj = {f.name: fields[f.name] for f in OBJECT_FIELDS}
    if len(obj) != len(fields):
        raise ValueError(f"fields not in OBJECT_FIELDS: {sorted(set(fields) - set(obj))}")
    return obj


def _pixel_fields(bbox_visible, visible: int, amodal: int) -> dict:
    """The fields of an object's pixel counts (``visible``, ``amodal``) and its visible pixels' box."""
    return {"bbox_visible": bbox_visible, "visible_pixels": visible, "amodal_pixels": amodal,
            "visible_fraction": min(1.0, visible / amodal) if amodal else None,
            "occlusion": occlusion_level(visible, amodal)}


def _object(track_id, name, category, synthetic, placed, entry, width, height, *, frames, index, fps, centres,
            poses=None, proj=None):
    """The object's identity and geometry (``placed`` = (box_to_world, size), or None: no geometry) and its box's
    projection (``poses``, ``proj``: as ``_recorded_geometry`` gives them, None: computed here)."""
    head = {"track_id": int(track_id), "name": name, "class": category, "synthetic": synthetic}
    if placed is None:
        return {**head, **_NO_GEOMETRY}, _NO_PROJECTION
    box_to_world, size = placed
    w2c = np.asarray(entry.world_to_camera, np.float64)
    cam_box = _in_camera(box_to_world, w2c)
    pose_w, pose_c = poses or (boxes.object_pose(box_to_world, size), boxes.object_pose(cam_box, size))
    if proj is None:
        proj = boxes.project_box(box_to_world, size, entry.K, w2c, width, height, NEAR)
    if not _finite(cam_box, proj["polygon"]):
        return {**head, **_NO_GEOMETRY}, _NO_PROJECTION
    centre = cameras.camera_centers(w2c)
    return {**head, "box_world": _box_dict(pose_w, pose_w["yaw"]),
            "box_camera": _box_dict(pose_c, boxes.rotation_y(pose_c["rotation"])),
            "velocity": _velocity(centres, frames, index, fps),
            "bbox_amodal": proj["bbox"], "truncation": float(proj["truncation"]),
            "in_view": proj["bbox"] is not None,
            "camera_inside": boxes.contains(box_to_world, size, centre)}, proj


def ray_frames(camera_to_box, K) -> tuple:
    """(origin (..., 3), rays (..., 3, 3)) of boxes seen by a camera, for ``recorded_pixels``: the camera centre in
    each box frame, and the matrix taking a pixel's homogeneous coordinates (u, v, 1) to its ray's direction in the
    box frame at unit depth (K's last row is (0, 0, 1), ``job``'s check: the ray's point at depth Z, metres along
    the optical axis, is origin + Z · rays @ (u, v, 1)). ``camera_to_box`` (..., 4, 4) rigid; K (3, 3)."""
    C = np.asarray(camera_to_box, np.float64)
    return C[..., :3, 3].copy(), C[..., :3, :3] @ np.linalg.inv(np.asarray(K, np.float64))


def lateral_margin(K, depth: float) -> float:
    """Half a pixel's diagonal footprint (metres) at ``depth`` metres: how far from a pixel's centre ray the point
    that wins the pixel may lie (``recorded_pixels`` grows boxes by it)."""
    Kinv = np.linalg.inv(np.asarray(K, np.float64))
    return 0.5 * float(depth) * float(np.hypot(Kinv[0, 0], Kinv[1, 1]))


def recorded_pixels(window, origin, rays, size, margin: float, depth, hole, asset) -> dict:
    """A recorded object's pixels in its projected box (the module docstring's rule): {"visible", "hidden", "empty",
    "holes"} each (h, w) bool over ``window`` = ((x0, y0), inside (h, w) bool) (``boxes.polygon_window`` of the
    projected box), disjoint, within ``inside``; a pixel whose depth is NaN is in none.

    ``origin``, ``rays``: ``ray_frames`` of the box; ``size`` (3,) its (width, length, height); ``margin`` metres it
    is grown by on every side (``lateral_margin``); ``depth`` (H, W) Z, metres along the optical axis (+inf where
    nothing), ``hole`` (H, W) bool, ``asset`` (H, W) bool (an inserted asset wins the pixel)."""
    (x0, y0), inside = window
    h, w = inside.shape
    rows, cols = slice(y0, y0 + h), slice(x0, x0 + w)
    Z, hl, asset = depth[rows, cols], hole[rows, cols], asset[rows, cols]
    u, v = np.arange(x0, x0 + w) + 0.5, (np.arange(y0, y0 + h) + 0.5)[:, None]
    o = np.asarray(origin, np.float64)[:, None, None]
    lim = (np.asarray(size, np.float64) / 2 + margin)[:, None, None]
    d = rays[:, 0, None, None] * u + rays[:, 1, None, None] * v + rays[:, 2, None, None]   # (3, h, w)
    if (d == 0).any():  # a ray parallel to a face: ±inf (NaN at its very edge, which fmin/fmax skip)
        with np.errstate(divide="ignore", invalid="ignore"):  # (only then: entering errstate costs ~50 µs)
            a, b = (-lim - o) / d, (lim - o) / d
    else:
        a, b = (-lim - o) / d, (lim - o) / d
    entry = np.fmax.reduce(np.fmin(a, b), axis=0)
    leave = np.fmin.reduce(np.fmax(a, b), axis=0)
    near, far = entry * (1.0 - DEPTH_NOISE), leave * (1.0 + DEPTH_NOISE)
    hits = inside & (entry <= leave)
    shown = ~hl
    visible = hits & shown & ~asset & (Z >= near) & (Z <= far)
    hidden = (hits & shown & ~asset & (Z < near)) | (inside & asset & ~(Z > far))
    holes = inside & hl
    empty = inside & shown & ~visible & ~hidden & (asset | ~np.isnan(Z))
    return {"visible": visible, "hidden": hidden, "empty": empty, "holes": holes}


def _recorded_geometry(placed: list, entry, width: int, height: int) -> list:
    """((world pose, camera pose), projection, (origin, rays)) of each box of ``placed`` ((box_to_world, size),
    finite) at output frame ``entry``, all boxes at once (the same numbers as ``_object`` and ``ray_frames`` one at
    a time): the poses as ``boxes.object_pose`` gives them, the projection as ``boxes.project_boxes`` does (a box
    that cannot show, behind the camera or off the image, costs no hull and no mask), the rays as ``ray_frames``
    of camera_to_box."""
    if not placed:
        return []
    T = np.array([p[0] for p in placed], np.float64)
    size = np.array([p[1] for p in placed], np.float64)
    w2c = np.asarray(entry.world_to_camera, np.float64)
    cam = w2c @ T
    world, camera = boxes.object_pose(T, size), boxes.object_pose(cam, size)
    projections = boxes.project_boxes(T, size, entry.K, w2c, width, height, NEAR)
    origin, rays = ray_frames(cameras.rigid_inverse(cam), entry.K)
    pose = lambda p, n: {"center": p["center"][n], "size": p["size"][n], "rotation": p["rotation"][n],  # noqa: E731
                         "quaternion": p["quaternion"][n], "yaw": float(p["yaw"][n])}
    return [((pose(world, n), pose(camera, n)), projections[n], (origin[n], rays[n])) for n in range(len(placed))]


def _recorded_fields(window, proj, ray, size, footprint: float, layers, removed: bool, ignore: bool,
                     unlabelled) -> dict:
    """A recorded object's pixel fields (the module docstring's rule) from its ``window`` (None: no pixel of the
    image), its projection, ``ray`` = (origin, rays), ``footprint`` = ``lateral_margin`` at 1 m and ``layers`` =
    (depth, hole, asset); the pixels it shows as
    an ignore region are set in ``unlabelled`` (H, W) bool, made on first use (``unlabelled[0]``)."""
    fields = {"ignore": bool(ignore), "points_missing": False, "hole_fraction": None}
    if window is None or removed:
        amodal = 0 if window is None else int(window[1].sum())
        return {**fields, **_pixel_fields(None, 0, amodal)}
    (x0, y0), inside = window
    m = recorded_pixels(window, *ray, size, footprint * proj["depth_range"][1], *layers)
    n = {k: int(v.sum()) for k, v in m.items()}
    unhidden = n["visible"] + n["empty"] + n["holes"]
    missing = (n["empty"] + n["holes"] > POINTS_MISSING_EMPTY * (unhidden + n["hidden"])
               and n["visible"] < POINTS_MISSING_SHARE * unhidden)
    mask = (m["visible"] | m["empty"] | m["holes"]) if missing else m["visible"]
    visible = unhidden if missing else n["visible"]
    region = visible if missing else visible + n["holes"]
    box = pixel_box(mask)
    if box is not None:
        box = [box[0] + x0, box[1] + y0, box[2] + x0, box[3] + y0]
    if (missing or ignore) and visible:
        if unlabelled[0] is None:
            unlabelled[0] = np.zeros(layers[0].shape, bool)
        unlabelled[0][y0:y0 + inside.shape[0], x0:x0 + inside.shape[1]] |= mask
    return {**fields, "points_missing": missing, "hole_fraction": n["holes"] / region if region else None,
            **_pixel_fields(box, visible, visible + n["hidden"])}


def frame_labels(job: job_mod.Job, index: int, *, instance, hole, depth, amodal_pixels, asset_boxes, asset_hashes,
                 key: str = "", layers_key: str = "", low_coverage: float = LOW_COVERAGE) -> dict:
    """The labels of output frame ``job.frames[index]`` (the module's schema).

    ``instance``, ``hole``, ``depth``: the frame's layers (H, W) (``backend.render.channels``); ``amodal_pixels``
    (A,) each asset's pixels when rendered alone (``backend.render.frames.amodal_pixels``); ``asset_boxes`` one
    (box_to_file, size, source) per asset, source "job" or "estimated"; ``asset_hashes`` one SHA-256 (hex) per
    asset file."""
    entry = job.frames[index]
    W, H = job.width, job.height
    frames = [e.frame for e in job.frames]
    fps, fps_source = job.frame_rate()
    w2c = np.asarray(entry.world_to_camera, np.float64)
    instance = np.asarray(instance)
    hole = np.asarray(hole) > 0.5
    coverage = float(1.0 - hole.mean())
    sc = job.scene
    in_recording = None
    if sc is not None and sc.recorded_frames is not None:
        in_recording = bool(sc.recorded_frames[0] <= entry.frame <= sc.recorded_frames[1])
    objects = []
    ids = np.rint(instance).astype(np.int64)
    visible_counts = np.bincount(ids.ravel(), minlength=len(job.assets) + 1)
    # the labelled pixels' coordinates once (a car covers a few % of the image), each asset's box from its own
    ys, xs = np.nonzero(ids)
    labelled = ids[ys, xs]
    hole_counts = np.bincount(ids[hole], minlength=len(job.assets) + 1)
    for a_i, (asset, (box_to_file, size, source)) in enumerate(zip(job.assets, asset_boxes)):
        track = a_i + 1
        # this frame and its neighbours (the velocity's): not every frame, once per frame of a long job
        placed = {f: asset_box_to_world(asset, (box_to_file, size), f) for f in frames[max(index - 1, 0):index + 2]}
        centres = {f: p[0][:3, 3] for f, p in placed.items() if p is not None}
        obj, _ = _object(track, asset.name, asset.category, True, placed[entry.frame], entry, W, H, frames=frames,
                         index=index, fps=fps, centres=centres)
        visible, amodal = int(visible_counts[track]), int(amodal_pixels[a_i])
        obj.update({"asset": {"file": asset.ply, "sha256": asset_hashes[a_i]}, "box_source": source,
                    "removed": False, **_pixel_fields(_id_box(ys, xs, labelled == track) if visible else None, visible,
                                                   amodal),
                    "ignore": False, "points_missing": False,
                    "hole_fraction": int(hole_counts[track]) / visible if visible else None})
        objects.append(_ordered(obj))
    layers = (np.asarray(depth, np.float64), hole, ids > 0)
    footprint = lateral_margin(entry.K, 1.0)
    unlabelled = [None]
    present = [(r_i, rec) for r_i, rec in enumerate(sc.recorded_objects if sc is not None else [])
               if entry.frame in rec.boxes]
    placed_all = [(rec.boxes[entry.frame], rec.size) if _finite(rec.boxes[entry.frame], rec.size) else None
                  for _, rec in present]
    geometry = iter(_recorded_geometry([p for p in placed_all if p is not None], entry, W, H))
    for (r_i, rec), placed in zip(present, placed_all):
        track = len(job.assets) + 1 + r_i
        bw = rec.boxes[entry.frame]
        # this frame and its neighbours (the velocity's), as for assets
        centres = {f: rec.boxes[f][:3, 3] for f in frames[max(index - 1, 0):index + 2]
                   if f in rec.boxes and _finite(rec.boxes[f])}
        poses, proj, ray = next(geometry) if placed is not None else (None, None, None)
        obj, proj = _object(track, rec.id, rec.category, False, placed, entry, W, H, frames=frames,
                            index=index, fps=fps, centres=centres, poses=poses, proj=proj)
        removed = any(boxes.contains(b.box_to_world, b.size, bw[:3, 3]) for b in sc.removal_boxes)
        window = boxes.polygon_window(proj["polygon"], W, H) if proj["bbox"] is not None else None
        obj.update({"asset": None, "box_source": "recording", "removed": removed,
                    **_recorded_fields(window, proj, ray, rec.size, footprint, layers, removed, rec.ignore,
                                       unlabelled)})
        objects.append(_ordered(obj))
    unlabelled_fraction = 0.0 if unlabelled[0] is None else float(unlabelled[0].mean())
    flags = []
    if coverage < low_coverage:
        flags.append(LOW_COVERAGE_FLAG)
    if in_recording is False:
        flags.append(OUTSIDE_FLAG)
    if any(o["camera_inside"] and not o["removed"] for o in objects):
        flags.append(CAMERA_INSIDE_FLAG)
    if unlabelled_fraction > UNLABELLED_SHARE or any(ignore_region(o) and o["points_missing"] for o in objects):
        flags.append(UNLABELLED_FLAG)
    return {"schema": SCHEMA, "key": key, "layers_key": layers_key, "frame": int(entry.frame), "index": int(index),
            "timestamp_s": float(job.frame_ticks()[index] / fps), "fps": fps, "fps_source": fps_source,
            "image_size": [W, H],
            "camera": {"K": np.asarray(entry.K, np.float64).tolist(), "world_to_camera": w2c.tolist(),
                       "camera_to_world": cameras.rigid_inverse(w2c).tolist(),
                       "vggt_to_world": None if sc is None else np.asarray(sc.vggt_to_world, np.float64).tolist(),
                       "convention": CAMERA_CONVENTION},
            "coverage": coverage, "unlabelled_fraction": unlabelled_fraction, "in_recording": in_recording,
            "flags": flags, "objects": objects}


def warnings(labels: dict) -> list:
    """(code, message, object name or None) for each flag of a frame's labels, in words for a warning event."""
    out, f = [], labels["frame"]
    if LOW_COVERAGE_FLAG in labels["flags"]:
        out.append((LOW_COVERAGE_FLAG, f"frame {f}: only {labels['coverage']:.0%} of the pixels have a point or an "
                    "asset (the rest are holes the generator must invent)", None))
    if OUTSIDE_FLAG in labels["flags"]:
        out.append((OUTSIDE_FLAG, f"frame {f} lies outside the recording's frames (scene.recorded_frames)", None))
    for o in labels["objects"]:
        if o["camera_inside"] and not o["removed"]:
            out.append((CAMERA_INSIDE_FLAG, f"frame {f}: the camera is inside the box of {o['name']!r} (the camera "
                        "path drives through it)", o["name"]))
    if UNLABELLED_FLAG in labels["flags"]:
        missing = [o["name"] for o in labels["objects"] if o["points_missing"] and ignore_region(o)]
        names = ", ".join(repr(n) for n in missing[:3]) + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
        said = (f"{len(missing)} object(s) in view have (almost) no points in their box ({names}: the reconstruction's "
                "confidence or cleaning cut dropped them)" if missing else "objects marked ignore are in view")
        out.append((UNLABELLED_FLAG, f"frame {f}: {said}; exported as ignore regions, not labels: "
                    f"{labels['unlabelled_fraction']:.1%} of the image shows objects without a label",
                    missing[0] if len(missing) == 1 else None))
    return out
