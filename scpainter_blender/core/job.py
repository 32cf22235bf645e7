"""The job contract: ``job.json`` (schema ``scpainter.job/2``), as typed dataclasses built in one place.

One JSON file describes a render/generation: output resolution, per-frame cameras (our K, OpenCV
world_to_camera, the VGGT frames whose points project into it), the scene reconstruction with its
``vggt_to_world`` and removal boxes, Gaussian assets with a per-frame object_to_world (PLY file coordinates to
world metres), the output folder and generation settings; under ``scene``, how its points are cleaned
(``point_cleaning``); for labels (docs/design.md §15), each asset's ``class`` and ``box``, the recording's frames
and tracked objects, and the frame rate (``Job.LABEL_ONLY``). Paths are relative to the job file. ``scene`` and
``assets`` may be absent. A rig job (``Job.rig``, docs/design.md §17) has a ``rig`` (``core.rig.Rig``) instead of a
resolution and ``ego_to_world`` per frame instead of K and world_to_camera; ``Job.camera_jobs`` makes it one
single-camera job per rig camera, which is what every command runs. ``Job.from_dict`` validates every field, and
each error names the file and the field (``frames[3].K``), never a numpy traceback; ``Job.to_dict`` is the file's content. The Blender export, the
evaluation protocol, the training pairs and the backend commands build and read jobs only through these classes
(docs/design.md §4.2).

Schema versions: ``scpainter.job/2`` names every transform ``a_to_b`` (``scene.vggt_to_world``). Files of
``scpainter.job/1`` (``scene.world_from_vggt``) are still read; ``save`` always writes the current version.

No bpy, no torch: numpy for the matrix checks only. (About 800 lines: the ten classes of one document, a rig
job's frames and camera jobs included (docs/design.md §17; the rig itself is ``core.rig``), each field's rule
beside its ``to_dict``, read together; what the job points at on disk is ``core.job_inputs``.)
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, fields, replace
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from . import fields as fields_mod
from . import categories, errors, files, outputs
from . import rig as rig_mod
from .geometry import point_cloud, similarity
from .output_layout import OutputLayout
# what a usable K is (its bounds, job fields and rig cameras alike): the cameras' module owns it
from .geometry.cameras import MAX_FOCAL_RATIO, MAX_K, MIN_FOCAL_RATIO, PRINCIPAL_POINT_MARGIN, intrinsics_problem  # noqa: F401
from .vggt.predictions import EXTRINSIC_CONVENTIONS  # scene.extrinsic_convention: what the predictions' extrinsic holds

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable

    from .rig import Rig

SCHEMA = "scpainter.job/2"
#: Older schemas still read, each with its fields renamed since: {schema: {old field: current field}} (scene level)
OLD_SCHEMAS = {"scpainter.job/1": {"world_from_vggt": "vggt_to_world"}}
_OLD_NAMES = {old: new for names in OLD_SCHEMAS.values() for old, new in names.items()}
#: Bounds that keep a job inside what the renderer and the model can do (validated, with the field named).
MAX_SIDE = 16384                   # pixels, each of width and height
MAX_PIXELS = 8192 * 8192           # width x height
MAX_FRAMES = 100_000               # output frames in one job
FRAME_RANGE = (-1048574, 1048574)  # Blender's MINAFRAME..MAXFRAME
MAX_SOURCE_FRAME = 1_000_000
MAX_SEED = 2 ** 63 - 1
#: ``generate`` settings: (low, high) of each; the checkpoint's own values obey the same (backend.model.checkpoint)
GENERATE_INT_BOUNDS = {"steps": (1, 1000), "window": (1, 256), "overlap": (0, 255), "seed": (0, MAX_SEED),
                       "decode_chunk": (1, 256), "feature_reuse": (1, 16)}
GENERATE_NUMBER_BOUNDS = {"min_guidance": (0.0, 100.0), "max_guidance": (0.0, 100.0), "fps": (1.0, 240.0),
                          "guidance_sigma_min": (0.0, 1e10), "guidance_sigma_max": (0.0, 1e10)}

#: ``scene.point_cleaning``'s defaults, the only place they are written (bench/clean_points.py, measured on the
#: ground-truth street with VGGT-like depth errors; the table is in docs/design.md §4.2): the depth-edge test at
#: 0.05 cuts the shifted views' pixels showing a surface nearer than the true one from 7.7 % to 3.1 % of the image
#: (confidence percentile 0; harmless at the default 50) for 3 points more holes; open3d's outlier removal stays
#: off: on these errors it removes far, sparse, correct points (more holes) and no streaks, at 0.2-1.1 s per frame.
POINT_CLEANING = {"depth_edge_ratio": 0.05, "outliers": None}
#: Each outlier rule's fields with their defaults when the rule is chosen without them (the sweep's mildest useful
#: values), and bounds (low, high).
OUTLIER_FIELDS = {"statistical": {"neighbours": 16, "std_ratio": 2.0},
                  "radius": {"radius_m": 0.1, "min_points": 4}}
#: The cost of outlier removal grows with neighbours and with radius_m² × density (once per run, on every point:
#: at 1.2 M points statistical k = 16 took 3.3 s, radius 0.2 m 35–97 s, bench/clean_points.py): bounds that keep a
#: job from running for hours.
OUTLIER_BOUNDS = {"neighbours": (1, 100), "std_ratio": (0.01, 100.0), "radius_m": (1e-6, 0.5), "min_points": (1, 100)}
DEPTH_EDGE_RATIO_BOUNDS = (1e-4, 100.0)


#: Names a rig camera may not take: its folder (``<output_dir>/<camera>``) would be an output folder's own.
RESERVED_SENSOR_NAMES = (*OutputLayout.FOLDERS, OutputLayout.EXPORT)


class JobError(errors.InputError):
    """A job that cannot be run: ``str()`` is ``"<job file>: <field>: <what is wrong>"``."""


# The field validators are core.fields' (shared with the training clip reader), raising JobError here.
_matrix = partial(fields_mod.matrix, error=JobError)
_rigid = partial(fields_mod.rigid, error=JobError)
_affine = partial(fields_mod.affine, error=JobError)
_int = partial(fields_mod.integer, error=JobError)
_number = partial(fields_mod.number, error=JobError)
_str = partial(fields_mod.string, error=JobError)
_short = fields_mod.short


def _object(value, path, where) -> dict:
    if not isinstance(value, dict):
        raise JobError(path, where, "expected an object")
    return value


def _known(d: dict, path, where, known, old_names: dict | None = None) -> None:
    """Refuse a key that is not a field of this object (a typo would otherwise fall back to a default unseen);
    ``old_names`` {old: current} says which name this schema uses instead of an older schema's."""
    for key in d:
        if key in known:
            continue
        name = f"{where}.{key}" if where else key
        if old_names and key in old_names:
            raise JobError(path, name, f"is the name an older schema used: {SCHEMA} calls it {old_names[key]!r}",
                           hint="rename the field (or give the file the schema it was written for)")
        raise JobError(path, name, f"is not a field of {where or 'a job'} (fields: {', '.join(sorted(known))})",
                       hint="check the spelling: an unknown field would be ignored")


def _list(value, path, where, what="a list") -> list:
    if not isinstance(value, list):
        raise JobError(path, where, f"expected {what}")
    return value


def _frame_key(key: str, path, where) -> int:
    """An object's key that is a frame number (``"12"``) as an int within ``FRAME_RANGE``."""
    try:
        f = int(key)
    except ValueError:  # not a number, or more digits than Python reads (4,300)
        f = None
    if f is None or not FRAME_RANGE[0] <= f <= FRAME_RANGE[1]:
        raise JobError(path, where, f"expected a frame number in [{FRAME_RANGE[0]}, {FRAME_RANGE[1]}] as the key")
    return f


def _matrix_list(m: np.ndarray) -> list:
    return np.asarray(m, np.float64).tolist()


@dataclass(eq=False)
class Frame:
    """One output frame: ``K`` (3, 3) our intrinsics in pixels (pixel centres at +0.5), ``world_to_camera``
    (4, 4) rigid, OpenCV axes (x right, y down, z forward), metres; ``source_frames``: the VGGT frames whose
    points project into it (empty: no points). A rig job's frame (``Job.rig``) has ``ego_to_world`` (4, 4) rigid,
    the ego frame (x forward, y left, z up, ``core.rig``) to world, instead: its ``K`` and ``world_to_camera`` are
    None (each camera's come from the rig, ``Job.camera_jobs``)."""
    frame: int
    K: np.ndarray | None
    world_to_camera: np.ndarray | None
    source_frames: list = field(default_factory=list)
    ego_to_world: np.ndarray | None = None

    @classmethod
    def from_dict(cls, d: dict, path: str | os.PathLike, where: str, rig: bool = False) -> "Frame":
        """A frame of a single-camera job (``K``, ``world_to_camera``) or, with ``rig``, of a rig job
        (``ego_to_world``); the other kind's fields are refused by name."""
        _object(d, path, where)
        _known(d, path, where, ("frame", "K", "world_to_camera", "ego_to_world", "source_frames"))
        f = _int(d.get("frame"), path, f"{where}.frame", *FRAME_RANGE)
        if rig:
            for key in ("K", "world_to_camera"):
                if key in d:
                    raise JobError(path, f"{where}.{key}", "a rig job's frames carry ego_to_world only: each camera's "
                                   "K and pose come from the rig (rig.cameras[].K, camera_to_ego)",
                                   hint=f"remove {key} from the frames (or remove rig for a single-camera job)")
            K = w2c = None
            e2w = _rigid(d.get("ego_to_world"), path, f"{where}.ego_to_world")
        else:
            if "ego_to_world" in d:
                raise JobError(path, f"{where}.ego_to_world", "only a rig job's frames carry ego_to_world (this job "
                               "has no rig)", hint="give the job a rig, or give the frame K and world_to_camera")
            K = _matrix(d.get("K"), path, f"{where}.K", (3, 3))
            problem = intrinsics_problem(K)
            if problem is not None:
                raise JobError(path, f"{where}.K", problem)
            w2c = _rigid(d.get("world_to_camera"), path, f"{where}.world_to_camera")
            e2w = None
        src = _list(d.get("source_frames", []), path, f"{where}.source_frames", "a list of frame indices")
        src = [_int(s, path, f"{where}.source_frames[{j}]", lo=0, hi=MAX_SOURCE_FRAME) for j, s in enumerate(src)]
        return cls(f, K, w2c, src, e2w)

    def to_dict(self) -> dict:
        d = {"frame": int(self.frame)}
        if self.ego_to_world is not None:
            d["ego_to_world"] = _matrix_list(self.ego_to_world)
        else:
            d.update(K=_matrix_list(self.K), world_to_camera=_matrix_list(self.world_to_camera))
        if self.source_frames:
            d["source_frames"] = [int(s) for s in self.source_frames]
        return d


@dataclass(eq=False)
class RemovalBox:
    """Points inside this box are removed: ``box_to_world`` (4, 4) rigid, ``size`` (3,) full extents in metres
    along the box's x, y (length), z."""
    box_to_world: np.ndarray
    size: np.ndarray

    @classmethod
    def from_dict(cls, d: dict, path: str | os.PathLike, where: str) -> "RemovalBox":
        return cls(*_box_fields(d, path, where, "box_to_world", "[x, y, z] in metres"))

    def to_dict(self) -> dict:
        return {"box_to_world": _matrix_list(self.box_to_world), "size": [float(v) for v in self.size]}


@dataclass(eq=False)
class OutlierRemoval:
    """open3d's outlier removal on the scene's cloud (``backend.render.cleaning`` states the rules exactly):
    ``method`` "statistical" (drop a point whose mean distance to its ``neighbours`` nearest, itself included, is
    more than ``std_ratio`` standard deviations above the cloud's mean of it) or "radius" (drop a point with fewer
    than ``min_points`` other points within ``radius_m`` metres). Only the chosen method's fields are read and
    written; the others keep their defaults."""
    method: str = "statistical"
    neighbours: int = OUTLIER_FIELDS["statistical"]["neighbours"]
    std_ratio: float = OUTLIER_FIELDS["statistical"]["std_ratio"]
    radius_m: float = OUTLIER_FIELDS["radius"]["radius_m"]
    min_points: int = OUTLIER_FIELDS["radius"]["min_points"]

    @classmethod
    def from_dict(cls, d: dict, path: str | os.PathLike, where: str) -> "OutlierRemoval":
        _object(d, path, where)
        method = d.get("method")
        if method not in OUTLIER_FIELDS:
            raise JobError(path, f"{where}.method", f"expected one of {list(OUTLIER_FIELDS)}, got {_short(method)}")
        _known(d, path, where, ("method",) + tuple(OUTLIER_FIELDS[method]))
        values = {}
        for key, default in OUTLIER_FIELDS[method].items():
            lo, hi = OUTLIER_BOUNDS[key]
            check = _int if isinstance(default, int) else _number
            values[key] = check(d.get(key, default), path, f"{where}.{key}", lo, hi)
        return cls(method, **values)

    def to_dict(self) -> dict:
        # an unknown method (built in code) writes every field, so save() refuses it by name instead of a KeyError
        names = OUTLIER_FIELDS.get(self.method, OUTLIER_BOUNDS)
        cast = {k: int if isinstance(v, int) else float for m in OUTLIER_FIELDS.values() for k, v in m.items()}
        return {"method": self.method, **{k: cast[k](getattr(self, k)) for k in names}}


def _default_outliers():
    o = POINT_CLEANING["outliers"]
    return None if o is None else OutlierRemoval.from_dict(o, "(defaults)", "scene.point_cleaning.outliers")


@dataclass(eq=False)
class PointCleaning:
    """How the scene's points are cleaned before rendering (``backend.render.frames.load_scene``, once per scene):
    ``depth_edge_ratio`` drops the pixels of each source frame's depth map whose depth jumps by more than that
    fraction of their own to one of their 8 neighbours (``core.geometry.point_cloud.depth_edges``); ``outliers`` removes
    floaters from the whole cloud (``OutlierRemoval``). None turns one off; in the file, ``null`` turns it off, an
    absent field takes the default (``POINT_CLEANING``), and ``"point_cleaning": null`` turns both off."""
    depth_edge_ratio: float | None = POINT_CLEANING["depth_edge_ratio"]
    outliers: OutlierRemoval | None = field(default_factory=_default_outliers)

    @classmethod
    def from_dict(cls, d: dict | None, path: str | os.PathLike, where: str = "scene.point_cleaning") -> "PointCleaning":
        if d is None:
            return cls(None, None)
        _object(d, path, where)
        _known(d, path, where, [f.name for f in fields(cls)])
        ratio = d.get("depth_edge_ratio", POINT_CLEANING["depth_edge_ratio"])
        if ratio is not None:
            lo, hi = DEPTH_EDGE_RATIO_BOUNDS
            if isinstance(ratio, bool) or not isinstance(ratio, (int, float)) or not lo <= ratio <= hi:
                raise JobError(path, f"{where}.depth_edge_ratio", f"expected a number in [{lo}, {hi}] (a fraction of "
                               f"the pixel's depth), got {_short(ratio)}", hint="null turns the depth-edge test off")
            ratio = float(ratio)  # (the test above is _number's, with the hint: a bool, NaN or inf fails it)
        outliers = d.get("outliers", POINT_CLEANING["outliers"])
        if outliers is not None:
            outliers = OutlierRemoval.from_dict(outliers, path, f"{where}.outliers")
        return cls(ratio, outliers)

    def to_dict(self) -> dict:
        return {"depth_edge_ratio": None if self.depth_edge_ratio is None else float(self.depth_edge_ratio),
                "outliers": None if self.outliers is None else self.outliers.to_dict()}


@dataclass(eq=False)
class Scene:
    """The reconstruction: ``predictions`` (path, relative to the job file) read with ``extrinsic_convention``
    and ``crop`` as the import read it, points kept above ``confidence_percentile``, moved to world metres by
    ``vggt_to_world`` (4, 4 similarity), minus the points inside ``removal_boxes``, cleaned by ``point_cleaning``
    (absent from a file: the defaults, ``POINT_CLEANING``)."""
    predictions: str
    vggt_to_world: np.ndarray
    confidence_percentile: float = point_cloud.CONFIDENCE_PERCENTILE
    extrinsic_convention: str = "world_to_camera"
    crop: list = field(default_factory=lambda: [0, 0, 0, 0])
    removal_boxes: list = field(default_factory=list)
    point_cleaning: PointCleaning = field(default_factory=PointCleaning)
    recorded_frames: list | None = None     # [first, last] output frames the recording covers (None: not known)
    recorded_objects: list = field(default_factory=list)  # RecordedObject: the drive's own tracked objects

    @classmethod
    def from_dict(cls, d: dict, path: str | os.PathLike, where: str = "scene", renamed: dict | None = None) -> "Scene":
        d = dict(_object(d, path, where))
        _known(d, path, where, [f.name for f in fields(cls)] + list(renamed or {}),
               old_names=None if renamed else _OLD_NAMES)
        for old, new in (renamed or {}).items():  # an older schema's names
            if old in d:
                d[new] = d.pop(old)
        old_name = {v: k for k, v in (renamed or {}).items()}
        predictions = _str(d.get("predictions"), path, f"{where}.predictions")
        w_field = f"{where}.{old_name.get('vggt_to_world', 'vggt_to_world')}"
        W = _matrix(d.get("vggt_to_world"), path, w_field, (4, 4))
        try:  # the loader's own rule (point_cloud decomposes it), so what validates also runs
            similarity.decompose_similarity(W)
        except ValueError as e:
            raise JobError(path, w_field, f"is not a similarity: {e}") from None
        pct = _number(d.get("confidence_percentile", point_cloud.CONFIDENCE_PERCENTILE), path,
                      f"{where}.confidence_percentile", 0.0, 100.0)
        conv = d.get("extrinsic_convention", "world_to_camera")
        if conv not in EXTRINSIC_CONVENTIONS:
            raise JobError(path, f"{where}.extrinsic_convention",
                           f"expected one of {list(EXTRINSIC_CONVENTIONS)}, got {_short(conv)}")
        crop = d.get("crop", [0, 0, 0, 0])
        if not isinstance(crop, list) or len(crop) != 4:
            raise JobError(path, f"{where}.crop", f"expected [left, top, right, bottom] in pixels, got {_short(crop)}")
        crop = [_int(v, path, f"{where}.crop[{i}]", lo=0, hi=MAX_SIDE) for i, v in enumerate(crop)]
        boxes = _list(d.get("removal_boxes", []), path, f"{where}.removal_boxes")
        boxes = [RemovalBox.from_dict(b, path, f"{where}.removal_boxes[{i}]") for i, b in enumerate(boxes)]
        cleaning = PointCleaning.from_dict(d.get("point_cleaning", {}), path, f"{where}.point_cleaning")
        recorded = d.get("recorded_frames")
        if recorded is not None:
            if not isinstance(recorded, list) or len(recorded) != 2:
                raise JobError(path, f"{where}.recorded_frames", f"expected [first, last] output frame numbers, got "
                               f"{_short(recorded)}")
            recorded = [_int(v, path, f"{where}.recorded_frames[{i}]", *FRAME_RANGE) for i, v in enumerate(recorded)]
            if recorded[1] < recorded[0]:
                raise JobError(path, f"{where}.recorded_frames", f"last frame {recorded[1]} before first {recorded[0]}")
        objects = _list(d.get("recorded_objects", []), path, f"{where}.recorded_objects")
        objects = [RecordedObject.from_dict(o, path, f"{where}.recorded_objects[{i}]") for i, o in enumerate(objects)]
        ids = [o.id for o in objects]
        for i, o in enumerate(objects):
            if o.id in ids[:i]:
                raise JobError(path, f"{where}.recorded_objects[{i}].id", f"{o.id!r} appears twice")
        return cls(predictions, W, pct, conv, crop, boxes, cleaning, recorded, objects)

    def to_dict(self) -> dict:
        # point_cleaning always written out, as resolved: the render's job key (backend.render.command.job_key)
        # hashes this, so changed settings, or changed defaults, render again
        d = {"predictions": self.predictions, "vggt_to_world": _matrix_list(self.vggt_to_world),
             "confidence_percentile": float(self.confidence_percentile),
             "extrinsic_convention": self.extrinsic_convention, "crop": [int(v) for v in self.crop],
             "point_cleaning": None if self.point_cleaning is None else self.point_cleaning.to_dict()}
        if self.removal_boxes:
            d["removal_boxes"] = [b.to_dict() for b in self.removal_boxes]
        if self.recorded_frames is not None:
            d["recorded_frames"] = [int(v) for v in self.recorded_frames]
        if self.recorded_objects:
            d["recorded_objects"] = [o.to_dict() for o in self.recorded_objects]
        return d


#: The class an asset or a recorded object is labelled with when the job names none.
DEFAULT_CLASS = "car"
#: A class name: at most this many characters (it becomes a KITTI type, a COCO category, an OpenLABEL type).
MAX_CLASS = 64


def _class(d, path, where) -> str:
    """The ``class`` of an asset or recorded object: a name of the fixed class table (``core.categories``: every
    export gives each class the same id), default ``DEFAULT_CLASS``."""
    c = d.get("class", DEFAULT_CLASS)
    if not isinstance(c, str) or not c or len(c) > MAX_CLASS or any(ch.isspace() for ch in c):
        raise JobError(path, where, f"expected a class name without spaces (at most {MAX_CLASS} characters), "
                       f"got {_short(c)}", hint=f"for example {DEFAULT_CLASS!r}")
    if c not in categories.NAMES:
        raise JobError(path, where, f"class {c!r} is not in the class table",
                       hint=f"one of {', '.join(categories.NAMES)} (core/categories.py; the table only grows)")
    return c


def _box_size(size, path, where, what="[width, length, height]") -> np.ndarray:
    if not isinstance(size, list) or len(size) != 3:
        raise JobError(path, where, f"expected {what}, got {_short(size)}")
    return np.array([_number(v, path, f"{where}[{j}]", lo=0.0, hi=1e7) for j, v in enumerate(size)])


def _box_fields(d, path, where, matrix: str, what: str) -> tuple:
    """(rigid matrix, size) of a box object {``matrix``: 4x4, "size": [3 numbers ≥ 0]} (removal and asset boxes)."""
    _object(d, path, where)
    _known(d, path, where, (matrix, "size"))
    return _rigid(d.get(matrix), path, f"{where}.{matrix}"), _box_size(d.get("size"), path, f"{where}.size", what)


@dataclass(eq=False)
class AssetBox:
    """An asset's 3D box in its own file coordinates: ``box_to_file`` (4, 4) rigid from the box frame (centre at
    the origin; x across the width, y along the length with +y the front, z up: the convention of removal boxes
    and of the clip format's cars) to the file's coordinates, ``size`` (3,) full extents along x, y, z (width,
    length, height) in file units. ``object_to_world`` then places it per frame (``core.geometry.boxes``)."""
    box_to_file: np.ndarray
    size: np.ndarray

    @classmethod
    def from_dict(cls, d: dict, path: str | os.PathLike, where: str) -> "AssetBox":
        return cls(*_box_fields(d, path, where, "box_to_file", "[width, length, height]"))

    def to_dict(self) -> dict:
        return {"box_to_file": _matrix_list(self.box_to_file), "size": [float(v) for v in self.size]}


@dataclass(eq=False)
class Asset:
    """A Gaussian asset: ``ply`` (path, relative to the job file; any format ``core.splats.reader.read`` accepts) and,
    for every output frame, ``object_to_world`` (4, 4) affine from the file's coordinates to world metres; its label
    ``category`` (the file's ``class``, default ``DEFAULT_CLASS``) and its ``box`` (``AssetBox``; None: estimated
    from the Gaussians when labels are made, and marked so)."""
    name: str
    ply: str
    object_to_world: dict  # {frame number (int): (4, 4) ndarray}
    category: str = DEFAULT_CLASS
    box: AssetBox | None = None

    @classmethod
    def from_dict(cls, d: dict, path: str | os.PathLike, where: str, frames: Iterable[int]) -> "Asset":
        _object(d, path, where)
        _known(d, path, where, ("name", "ply", "object_to_world", "class", "box"))
        name = _str(d.get("name"), path, f"{where}.name")
        ply = _str(d.get("ply"), path, f"{where}.ply")
        o2w = d.get("object_to_world")
        if not isinstance(o2w, dict):
            raise JobError(path, f"{where}.object_to_world", "expected an object of frame -> 4x4 matrix")
        missing = [f for f in sorted(frames) if str(f) not in o2w]
        if missing:
            raise JobError(path, f"{where}.object_to_world", f"no transform for frames {missing[:5]}")
        out = {}
        for k, m in o2w.items():
            M = _affine(m, path, f"{where}.object_to_world[{k!r}]")
            out[_frame_key(k, path, f"{where}.object_to_world[{k!r}]")] = M
        box = d.get("box")
        box = None if box is None else AssetBox.from_dict(box, path, f"{where}.box")
        return cls(name, ply, out, _class(d, path, f"{where}.class"), box)

    def to_dict(self) -> dict:
        d = {"name": self.name, "ply": self.ply,
             "object_to_world": {str(f): _matrix_list(m) for f, m in self.object_to_world.items()}}
        if self.category != DEFAULT_CLASS:
            d["class"] = self.category
        if self.box is not None:
            d["box"] = self.box.to_dict()
        return d


@dataclass(eq=False)
class RecordedObject:
    """An object of the recording (a tracked car of the drive): ``id`` (its track name), ``category`` (the file's
    ``class``), ``size`` (3,) [width, length, height] metres and ``boxes`` {output frame: (4, 4) rigid
    box_to_world} for the frames it is in (the box convention of ``AssetBox``). Labelled as a recorded
    (``synthetic: false``) object; one inside a removal box is listed as removed. ``ignore`` (the file's
    ``"ignore": true``): an object seen but not labelled (a rejected-as-unsure proposal, a blurred far car): its
    pixels become an ignore region in every export (``core.categories.IGNORE``), never a label."""
    id: str
    size: np.ndarray
    boxes: dict
    category: str = DEFAULT_CLASS
    ignore: bool = False

    @classmethod
    def from_dict(cls, d: dict, path: str | os.PathLike, where: str) -> "RecordedObject":
        _object(d, path, where)
        _known(d, path, where, ("id", "class", "size", "boxes", "ignore"))
        ignore = d.get("ignore", False)
        if not isinstance(ignore, bool):
            raise JobError(path, f"{where}.ignore", f"expected true or false, got {_short(ignore)}")
        boxes = d.get("boxes")
        if not isinstance(boxes, dict) or not boxes:
            raise JobError(path, f"{where}.boxes", "expected a non-empty object {output frame: box_to_world 4x4}")
        out = {}
        for k, m in boxes.items():
            out[_frame_key(k, path, f"{where}.boxes[{k!r}]")] = _rigid(m, path, f"{where}.boxes[{k!r}]")
        return cls(_str(d.get("id"), path, f"{where}.id"), _box_size(d.get("size"), path, f"{where}.size"), out,
                   _class(d, path, f"{where}.class"), ignore)

    def to_dict(self) -> dict:
        d = {"id": self.id, "size": [float(v) for v in self.size],
             "boxes": {str(f): _matrix_list(m) for f, m in sorted(self.boxes.items())}}
        if self.category != DEFAULT_CLASS:
            d["class"] = self.category
        if self.ignore:
            d["ignore"] = True
        return d


#: The generation settings' defaults, the only place they are written. ``window``, ``min_guidance``,
#: ``max_guidance`` and ``fps`` have none here: they default to the checkpoint's own (its ``scpainter.json``).
#: The speed settings (docs/design.md §11; chosen from bench/generate.py's error-against-time table): ``sampler``
#: (``GENERATE_SAMPLERS``, backend/model/edm.py), ``feature_reuse`` N (the whole UNet every N-th step, deep features
#: reused between; 1 = off), ``guidance_sigma_min``/``guidance_sigma_max`` (a guidance interval: no unconditional
#: branch at σ outside it; 0 and 1e10 = guidance at every step), ``compile`` (``GENERATE_COMPILE``: torch.compile of the UNet on CUDA, ``reduce-overhead`` with CUDA graphs)
#: and ``gpu_tuning`` (cuDNN autotuning, channels-last UNet, SDPA kernel order; CUDA only).
GENERATE_DEFAULTS = {"steps": 18, "overlap": 4, "seed": 0, "decode_chunk": 8, "sampler": "euler",
                     "feature_reuse": 2, "guidance_sigma_min": 0.0, "guidance_sigma_max": 30.0, "compile": "off",
                     "gpu_tuning": "on"}
#: The settings that make stock SVD's sampler (diffusers' StableVideoDiffusionPipeline: Euler, 25 steps, guidance
#: at every step, the whole UNet at every step): tests/backend/model/test_pipeline.py compares against diffusers
#: with them, and bench/generate.py measures every other setting against this video.
STOCK_SAMPLING = {"sampler": "euler", "steps": 25, "feature_reuse": 1, "guidance_sigma_min": 0.0,
                  "guidance_sigma_max": 1e10}
GENERATE_SAMPLERS = ("euler", "heun", "dpmpp2m")
GENERATE_COMPILE = ("off", "default", "reduce-overhead", "max-autotune")
#: The generate settings that take one of a list of words.
GENERATE_CHOICES = {"sampler": GENERATE_SAMPLERS, "compile": GENERATE_COMPILE, "gpu_tuning": ("on", "off")}
CHECKPOINT_SETTINGS = ("window", "min_guidance", "max_guidance", "fps")
#: ``generate.model``: ``scpainter`` needs a checkpoint; ``baseline`` fills the condition holes by OpenCV inpainting
#: (backend/generate/baseline.py) and needs none; ``auto`` (the default) is ``scpainter`` when a checkpoint is
#: configured (the command line's or the job's), else ``baseline``.
GENERATE_MODELS = ("auto", "scpainter", "baseline")
#: The baseline's settings: ``inpaint`` (OpenCV's method), ``inpaint_radius`` (px) and its ``fps``. The fps is the
#: stock SVD's (a checkpoint's own default), so a job plays at one speed with either generator.
INPAINT_METHODS = ("telea", "navier-stokes")
#: How people are shown each method (logs, the MP4's tags, the Blender UI).
INPAINT_NAMES = {"telea": "Telea", "navier-stokes": "Navier-Stokes"}
BASELINE_DEFAULTS = {"model": "auto", "inpaint": "telea", "inpaint_radius": 3, "fps": 7.0}
INPAINT_RADIUS_BOUNDS = (1, 64)


@dataclass(eq=False)
class GenerateSettings:
    """The job's ``generate`` object: what the user chose; None = not chosen (``resolve`` fills it in)."""
    checkpoint: str | None = None
    steps: int | None = None
    window: int | None = None
    overlap: int | None = None
    seed: int | None = None
    min_guidance: float | None = None
    max_guidance: float | None = None
    fps: float | None = None
    decode_chunk: int | None = None
    sampler: str | None = None         # GENERATE_SAMPLERS
    feature_reuse: int | None = None
    guidance_sigma_min: float | None = None
    guidance_sigma_max: float | None = None
    compile: str | None = None         # GENERATE_COMPILE
    gpu_tuning: str | None = None      # "on" | "off"
    model: str | None = None           # GENERATE_MODELS; None: auto
    inpaint: str | None = None         # INPAINT_METHODS (the baseline's)
    inpaint_radius: int | None = None

    @classmethod
    def from_dict(cls, d: dict, path: str | os.PathLike, where: str = "generate") -> "GenerateSettings":
        _object(d, path, where)
        _known(d, path, where, [f.name for f in fields(cls)])
        if d.get("checkpoint") is not None:
            _str(d["checkpoint"], path, f"{where}.checkpoint")
        check_generate_settings(d, path, where)
        values = {k: v for k, v in d.items() if v is not None}  # every key is a field (_known)
        for k in GENERATE_NUMBER_BOUNDS:
            if k in values:
                values[k] = float(values[k])
        return cls(**values)

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    def resolve(self, checkpoint_config, overrides: dict | None = None, path="job.json") -> dict:
        """The complete settings of a run: the command line's ``overrides``, else this job's, else (window,
        guidance, fps) the checkpoint's own ``checkpoint_config`` (a ``ScpainterConfig``), else
        ``GENERATE_DEFAULTS``. Raises JobError when they do not fit together (overlap ≥ window, naming where the
        window came from)."""
        chosen = {**self.to_dict(), **{k: v for k, v in (overrides or {}).items() if v is not None}}
        for key in ("checkpoint", *BASELINE_DEFAULTS):  # not the model's settings (fps: its own, below)
            if key != "fps":
                chosen.pop(key, None)
        out = {}
        for key in list(GENERATE_INT_BOUNDS) + list(GENERATE_NUMBER_BOUNDS):
            value = chosen.get(key, GENERATE_DEFAULTS.get(key))
            if value is None and key in CHECKPOINT_SETTINGS:
                value = getattr(checkpoint_config, key)
            out[key] = float(value) if key in GENERATE_NUMBER_BOUNDS else int(value)
        for key in GENERATE_CHOICES:
            out[key] = str(chosen.get(key, GENERATE_DEFAULTS[key]))
        out = {k: out[k] for k in ("steps", "window", "overlap", "seed", "min_guidance", "max_guidance", "fps",
                                   "decode_chunk", "sampler", "feature_reuse", "guidance_sigma_min",
                                   "guidance_sigma_max", "compile",
                                   "gpu_tuning")}
        try:
            check_generate_settings(out, path)
        except JobError as e:
            if e.field != "generate.overlap" or ("overlap" in chosen and "window" in chosen):
                raise
            overlap = f"the default overlap ({out['overlap']})" if "overlap" not in chosen else str(out["overlap"])
            window = f"the checkpoint's window ({out['window']}, from its scpainter.json)" if "window" not in chosen \
                else f"generate.window ({out['window']})"
            raise JobError(path, e.field, f"{overlap} must be smaller than {window}",
                           hint="set generate.overlap below the window") from None
        return out

    def model_choice(self, overrides: dict | None = None) -> str:
        """``generate.model`` as chosen: the command line's ``model``, else the job's, else ``auto``."""
        return (overrides or {}).get("model") or self.model or BASELINE_DEFAULTS["model"]

    def resolve_baseline(self, overrides: dict | None = None) -> dict:
        """The complete settings of a baseline run: ``inpaint``, ``inpaint_radius`` and ``fps``, each the command
        line's ``overrides``, else this job's, else ``BASELINE_DEFAULTS``. The model's settings do not apply."""
        chosen = {**self.to_dict(), **{k: v for k, v in (overrides or {}).items() if v is not None}}
        out = {k: chosen.get(k, BASELINE_DEFAULTS[k]) for k in ("inpaint", "inpaint_radius", "fps")}
        return {**out, "inpaint_radius": int(out["inpaint_radius"]), "fps": float(out["fps"])}


@dataclass(eq=False)
class Job:
    """A whole job. ``resolution`` (width, height) pixels; ``frames`` in output order; ``output_dir`` relative to
    the job file; ``scene`` None = no points; ``assets`` empty = no Gaussian pass; ``generate`` None = the
    defaults and the checkpoint given on the command line.

    A **rig job** (``rig``: a ``core.rig.Rig``; docs/design.md §17) renders every camera of its rig along one ego
    path: its ``resolution`` is None (each camera has its own) and its frames carry ``ego_to_world`` instead of K
    and world_to_camera. The commands run it as its camera jobs (``camera_jobs``), each an ordinary single-camera
    job writing ``<output_dir>/<camera name>/``."""
    resolution: tuple | None
    frames: list
    output_dir: str
    scene: Scene | None = None
    assets: list = field(default_factory=list)
    generate: GenerateSettings | None = None
    fps: float | None = None   # output frames per second (the scene's); None: not known (LABEL_FPS for timestamps)
    rig: Rig | None = None     # a rig job's cameras (and LiDAR); None: a single-camera job

    @property
    def width(self) -> int:
        return int(self._single("width").resolution[0])

    @property
    def height(self) -> int:
        return int(self._single("height").resolution[1])

    def _single(self, what: str) -> "Job":
        if self.rig is not None:  # a caller that forgot camera_jobs: say so rather than compute with None
            raise ValueError(f"a rig job has no single {what}: each camera has its own (Job.camera_jobs)")
        return self

    def require_single_camera(self, path: str | os.PathLike, what: str, hint: str | None = None) -> "Job":
        """This job, when it is a single-camera job; a rig job raises JobError on ``rig`` saying that ``what`` (a
        command) takes one camera, and (``hint``, else the default) how to run the rig's cameras instead."""
        if self.rig is not None:
            raise JobError(path, "rig", f"{what} takes a single-camera job; this is a rig job "
                           f"({', '.join(c.name for c in self.rig.cameras)})",
                           hint=hint or "render / generate / export run a rig job camera by camera "
                                        "(<output_dir>/<camera>/); use one of them, or a job without a rig")
        return self

    def camera_jobs(self) -> list:
        """[(RigCamera, Job)]: a rig job as one ordinary single-camera job per rig camera, in the rig's order: the
        camera's resolution and K, per frame ``world_to_camera`` = (ego_to_world · camera_to_ego)⁻¹ (float64,
        ``rig.world_to_camera``), the same frame numbers and source frames, scene, assets, generate and fps, and
        ``output_dir`` = ``<output_dir>/<camera name>``. A single-camera job gives ``[(None, self)]``. The camera
        jobs share this job's scene and assets (read only)."""
        if self.rig is None:
            return [(None, self)]
        out = []
        for cam in self.rig.cameras:
            K = np.asarray(cam.K, np.float64)
            frames = [Frame(f.frame, K.copy(), rig_mod.world_to_camera(f.ego_to_world, cam.camera_to_ego),
                            list(f.source_frames)) for f in self.frames]
            out.append((cam, replace(self, resolution=tuple(int(v) for v in cam.resolution), frames=frames,
                                     output_dir=os.path.join(self.output_dir, cam.name), rig=None)))
        return out

    @classmethod
    def from_dict(cls, job: dict, path: str | os.PathLike = "job.json") -> "Job":
        """Validate every field of a job's JSON content (current or older schema); JobError names the field."""
        path = os.fspath(path)
        if not isinstance(job, dict):
            raise JobError(path, "(top level)", "expected a JSON object")
        schema = job.get("schema")
        if schema != SCHEMA and schema not in OLD_SCHEMAS:
            raise JobError(path, "schema", f"expected {SCHEMA!r}, got {_short(schema)}")
        _known(job, path, "", ("schema", "resolution", "rig", "frames", "scene", "assets", "output_dir", "generate",
                               "fps"))
        rig = None
        if job.get("rig") is not None:
            rig = rig_mod.Rig.from_dict(job["rig"], path, "rig", error=JobError)
            for i, c in enumerate(rig.cameras):  # its folder beside the rig folder's own (a run's, an export's)
                if c.name in RESERVED_SENSOR_NAMES:
                    raise JobError(path, f"rig.cameras[{i}].name", f"{c.name!r} is the name of an output folder's "
                                   f"own folder: a camera's folder cannot take it", hint="rename the camera")
            if "resolution" in job:
                raise JobError(path, "resolution", "a rig job has no resolution of its own: each camera has its own "
                               "(rig.cameras[].resolution)", hint="remove resolution (or remove rig)")
            res = None
        else:
            res = job.get("resolution")
            if not isinstance(res, list) or len(res) != 2:
                raise JobError(path, "resolution", f"expected [width, height], got {_short(res)}")
            for i, v in enumerate(res):
                _int(v, path, f"resolution[{i}]", lo=1, hi=MAX_SIDE)
            if res[0] * res[1] > MAX_PIXELS:
                raise JobError(path, "resolution", f"{res[0]} x {res[1]} is more than {MAX_PIXELS:,} pixels")
            res = (int(res[0]), int(res[1]))
        frames = job.get("frames")
        if not isinstance(frames, list) or not frames:
            raise JobError(path, "frames", "expected a non-empty list")
        if len(frames) > MAX_FRAMES:
            raise JobError(path, "frames", f"{len(frames):,} frames: at most {MAX_FRAMES:,} in one job (split it)")
        out_frames, seen = [], set()
        for i, fr in enumerate(frames):
            f = Frame.from_dict(fr, path, f"frames[{i}]", rig=rig is not None)
            if f.frame in seen:
                raise JobError(path, f"frames[{i}].frame", f"frame {f.frame} appears twice")
            seen.add(f.frame)
            out_frames.append(f)
        scene = None
        if "scene" in job:
            scene = Scene.from_dict(job["scene"], path, renamed=OLD_SCHEMAS.get(schema))
        assets, names = [], set()
        for i, a in enumerate(_list(job.get("assets", []), path, "assets")):
            asset = Asset.from_dict(a, path, f"assets[{i}]", seen)
            if asset.name in names:
                raise JobError(path, f"assets[{i}].name", f"{asset.name!r} appears twice")
            names.add(asset.name)
            assets.append(asset)
        output_dir = _str(job.get("output_dir"), path, "output_dir")
        gen = job.get("generate")
        gen = None if gen is None else GenerateSettings.from_dict(gen, path)
        fps = job.get("fps")
        fps = None if fps is None else _number(fps, path, "fps", *GENERATE_NUMBER_BOUNDS["fps"])
        return cls(res, out_frames, output_dir, scene, assets, gen, fps, rig)

    def to_dict(self) -> dict:
        """The job file's content, in the current schema."""
        d = {"schema": SCHEMA}
        if self.rig is not None:
            d["rig"] = self.rig.to_dict()
        else:
            d["resolution"] = [self.width, self.height]
        d["frames"] = [f.to_dict() for f in self.frames]
        if self.scene is not None:
            d["scene"] = self.scene.to_dict()
        if self.assets:
            d["assets"] = [a.to_dict() for a in self.assets]
        d["output_dir"] = self.output_dir
        if self.generate is not None:
            d["generate"] = self.generate.to_dict()
        if self.fps is not None:
            d["fps"] = float(self.fps)
        return d

    def frame_rate(self) -> tuple:
        """(fps, source) of the output frames' timeline: the job's ``fps`` ("job"), else the baseline video's
        rate ("default", ``BASELINE_DEFAULTS``), which the MP4 then plays at too."""
        return (float(self.fps), "job") if self.fps is not None else (float(BASELINE_DEFAULTS["fps"]), "default")

    def frame_ticks(self) -> list:
        """Each output frame's scene-frame offset from the first, ``frame − frames[0].frame`` (ints): its time in
        frames of the timeline. A job of every 2nd frame (Blender's Frame Step 2) has ticks 0, 2, 4, …: the labels'
        ``timestamp_s`` is ticks / fps (``core.labels``), and the MP4 shows each frame at its tick of 1/fps
        (``backend/generate/video.py``), so both say 0, 0.2 s, … at 10 fps."""
        first = self.frames[0].frame
        return [int(f.frame) - int(first) for f in self.frames]

    #: What labels depend on and the condition layers do not: left out of the render's layer key
    #: (``backend.render.command.job_key``), so editing a box or a class rewrites labels, not layers.
    LABEL_ONLY = ("fps", "assets[].class", "assets[].box", "scene.recorded_frames", "scene.recorded_objects")

    def layers_dict(self) -> dict:
        """``to_dict`` without the generation settings, the output folder and the ``LABEL_ONLY`` fields: what the
        condition layers depend on. A rig job's also leaves out the rig's LiDAR (no camera layer depends on it);
        the render keys each camera by its camera job's own (``camera_jobs``), which holds that camera alone."""
        # the recorded objects (LABEL_ONLY) left out before serialising, not popped after: a job's 1000 of them
        # cost more to write out than all the rest, and the render asks for this twice
        job = self
        if self.scene is not None and self.scene.recorded_objects:
            job = replace(self, scene=replace(self.scene, recorded_objects=[]))
        d = {k: v for k, v in job.to_dict().items() if k not in ("generate", "output_dir")}
        for name in self.LABEL_ONLY:
            where, _, key = name.rpartition(".")
            parents = d.get("assets", []) if where == "assets[]" else [d.get("scene", {})] if where == "scene" else [d]
            for parent in parents:
                parent.pop(key, None)
        if "rig" in d:
            d["rig"].pop("lidar", None)
        return d


def validate(job: dict, path: str | os.PathLike = "job.json") -> Job:
    """``Job.from_dict``: check every field of a job's JSON content; JobError names the field."""
    return Job.from_dict(job, path)


def check_generate_settings(gen: dict, path: str | os.PathLike = "job.json", where: str = "generate") -> dict:
    """Bounds of the ``generate`` settings present in ``gen``: job fields (named ``<where>.<key>``) or, with
    ``where="--"``, command-line overrides (named ``--<key>``); ``overlap < window`` and ``min_guidance <=
    max_guidance`` when both are given. Returns ``gen``; JobError names the field."""
    name = (lambda k: f"--{k.replace('_', '-')}") if where == "--" else (lambda k: f"{where}.{k}")
    for key, (lo, hi) in GENERATE_INT_BOUNDS.items():
        if gen.get(key) is not None:
            _int(gen[key], path, name(key), lo, hi)
    for key, (lo, hi) in GENERATE_NUMBER_BOUNDS.items():
        if gen.get(key) is not None:
            _number(gen[key], path, name(key), lo, hi)
    for key, allowed in (("model", GENERATE_MODELS), ("inpaint", INPAINT_METHODS), *GENERATE_CHOICES.items()):
        if gen.get(key) is not None and gen[key] not in allowed:
            raise JobError(path, name(key), f"expected one of {list(allowed)}, got {_short(gen[key])}")
    if gen.get("inpaint_radius") is not None:
        _int(gen["inpaint_radius"], path, name("inpaint_radius"), *INPAINT_RADIUS_BOUNDS)
    if gen.get("overlap") is not None and gen.get("window") is not None and gen["overlap"] >= gen["window"]:
        raise JobError(path, name("overlap"), f"{gen['overlap']} must be smaller than {name('window')} "
                                              f"({gen['window']})")
    if gen.get("min_guidance") is not None and gen.get("max_guidance") is not None and \
            gen["min_guidance"] > gen["max_guidance"]:
        raise JobError(path, name("min_guidance"), f"must not exceed {name('max_guidance')}")
    if gen.get("guidance_sigma_min") is not None and gen.get("guidance_sigma_max") is not None and \
            gen["guidance_sigma_min"] > gen["guidance_sigma_max"]:
        raise JobError(path, name("guidance_sigma_min"), f"must not exceed {name('guidance_sigma_max')}")
    return gen


def read_json(path: str | os.PathLike, error: Callable[..., Exception] = JobError) -> object:
    """A JSON file's content within ``files.read_json``'s limits; a missing, irregular, oversized or malformed
    file raises ``error(path, field, message)``."""
    return files.read_json(path, error)


def load(path: str | os.PathLike) -> Job:
    """Read and validate a job file (structure and bounds; ``check_inputs`` checks what it points at)."""
    path = os.fspath(path)
    return Job.from_dict(read_json(path), path)


def save(path: str | os.PathLike, job: Job | dict) -> Job:
    """Validate, then write a job atomically (a unique temporary file, renamed), in the current schema. ``job``: a
    ``Job``, or a job's JSON content. Returns the validated Job; JobError names the field."""
    path = os.fspath(path)
    content = job.to_dict() if isinstance(job, Job) else job
    job = Job.from_dict(content, path)  # a Job built in code is validated too: nothing invalid is ever written
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    outputs.write_json(path, job.to_dict())
    return job


def resolve(job_path: str | os.PathLike, relative: str) -> str:
    """A path of the job, absolute (paths in a job are relative to the job file's folder)."""
    return os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(job_path)), relative))
