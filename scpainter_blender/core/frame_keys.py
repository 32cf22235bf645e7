"""Per-frame keys of the condition layers: which frames of a job are up to date, which need new labels only, and
which must be rendered (docs/design.md §12, "Incremental rendering").

A frame's layers depend on: the scene (the job's layer fields but its frames and assets, the point radius, the EXR
precision, the predictions file's size and time, and the scene origin, the first output camera, since the
renderer's float32 arithmetic is relative to it), the frame itself (its camera, K, source frames), and the assets
its camera can see (``visibility.asset_unseen``, the renderer's own conservative test) with their instance id,
file, file stamp and transform at that frame. That is a frame's **layers key**. Moving a car changes the keys of
the frames where it could be seen before or after the move and no other; a frame whose key is unchanged renders
bit for bit what it rendered before, so it is kept.

Where the keys live: a frame's labels file (written last for a frame: ``core.labels``) records the layers key its
EXR was made under (``layers_key``) and the labels' own key (``key``: ``labels_key``, which also covers the
label-only fields of the whole job). ``conditions/record.json`` (``RECORD_SCHEMA``) records the scene key, the
files the render wrote, the precision and, per asset file, its stamp and ``visibility.asset_bounds``, so that
Blender (no torch, and no wish to read a 100 MB PLY per click) computes the same keys from the record and the job
alone and knows, without starting the backend, that nothing has to be rendered (``plan``).

numpy only: the backend's render command and the add-on both plan with this module.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field

import numpy as np

from . import errors, files
from . import job as job_mod
from . import labels as labels_mod
from .geometry import cameras, visibility
from .output_layout import OutputLayout

#: ``conditions/record.json``'s schema. ``/1`` held one key for the whole job; its frames render again once.
RECORD_SCHEMA = "scpainter.conditions/2"


def _hash(blob) -> str:
    return hashlib.sha256(json.dumps(blob, sort_keys=True).encode()).hexdigest()[:32]


def stamp(path: str) -> list[int]:
    """[size in bytes, mtime in ns] of a file (what the keys take of an input file's identity). OSError when it
    is gone (the caller checked the job's inputs before)."""
    st = os.stat(path)
    return [int(st.st_size), int(st.st_mtime_ns)]


@dataclass
class Inputs:
    """The stamps of a job's input files: ``points`` (the predictions; None without a scene) and one per asset."""
    points: list | None
    assets: list

    @classmethod
    def of(cls, job_path: str, job: job_mod.Job) -> "Inputs":
        pts = None if job.scene is None else stamp(job_mod.resolve(job_path, job.scene.predictions))
        return cls(pts, [stamp(job_mod.resolve(job_path, a.ply)) for a in job.assets])


def scene_key(job: job_mod.Job, inputs: Inputs, point_radius: int, half: bool) -> str:
    """What every frame's layers depend on: ``Job.layers_dict`` without its frames and assets, the first output
    camera (the renderer's scene origin), the point radius, the precision and the predictions file's stamp."""
    content = {k: v for k, v in job.layers_dict().items() if k not in ("frames", "assets")}
    origin = job.frames[0].world_to_camera if job.frames else np.eye(4)
    return _hash({"job": content, "origin": np.asarray(origin, np.float64).tolist(), "radius": int(point_radius),
                  "exr": "half" if half else "float32", "points": inputs.points})


def frame_keys(job: job_mod.Job, key_of_scene: str, inputs: Inputs, extents: list) -> dict[int, str]:
    """{frame: layers key} for every output frame. ``extents``: per asset ``(bounds, max_sigma)``
    (``visibility.asset_bounds`` of its Gaussians as the renderer loads them). An asset enters a frame's key (as its
    1-based instance id, file, stamp and transform at that frame) unless ``visibility.asset_unseen`` rules it out,
    exactly as the renderer leaves its Gaussian pass out."""
    W, H = job.resolution
    origin = cameras.camera_centers(job.frames[0].world_to_camera) if job.frames else np.zeros(3)
    out = {}
    for e in job.frames:
        w2c = visibility.relative_camera(e.world_to_camera, origin)
        seen = []
        for i, (a, (bounds, max_sigma)) in enumerate(zip(job.assets, extents)):
            A = a.object_to_world[e.frame]
            if not visibility.asset_unseen(bounds, max_sigma, A, origin, e.K, w2c, W, H):
                seen.append([i + 1, a.ply, inputs.assets[i], np.asarray(A, np.float64).tolist()])
        out[e.frame] = _hash({"scene": key_of_scene, "frame": e.to_dict(), "assets": seen})
    return out


def sweep_keys(job: job_mod.Job, inputs: Inputs, settings: dict) -> dict[int, str]:
    """{frame: LiDAR sweep key} of a rig job with a LiDAR (docs/design.md §17): what its sweep at that frame depends
    on. The scene (``Job.layers_dict``'s, with the predictions' stamp), the renderer's scene origin (the first
    camera at the first frame: where float32 starts), the LiDAR (name, model, mount), the caster's ``settings``,
    and per frame the ego pose and every asset's file, stamp and pose there: a LiDAR sees all around, so no asset
    is left out of any frame's key."""
    rig = job.rig
    first_cam = rig.cameras[0].camera_to_ego
    origin = np.asarray(job.frames[0].ego_to_world, np.float64) @ np.asarray(first_cam, np.float64)
    base = _hash({"scene": job.layers_dict().get("scene"), "points": inputs.points,
                  "origin": origin[:3, 3].tolist(), "lidar": rig.lidar.to_dict(), "settings": settings})
    out = {}
    for e in job.frames:
        assets = [[i + 1, a.ply, inputs.assets[i], np.asarray(a.object_to_world[e.frame], np.float64).tolist()]
                  for i, a in enumerate(job.assets) if e.frame in a.object_to_world]
        out[e.frame] = _hash({"base": base, "ego_to_world": np.asarray(e.ego_to_world, np.float64).tolist(),
                              "assets": assets})
    return out


def job_digest(job: job_mod.Job) -> str:
    """A hash of what every frame's labels depend on beyond its layers: the whole job but its generation settings
    and output folder (so editing a box, a class or the frame rate, or moving a car anywhere, makes new labels:
    every frame's labels list every object), and the labels' schema. Once per job: hashing the job per frame made
    planning quadratic in the frames (14 s for 1,000)."""
    content = {k: v for k, v in job.to_dict().items() if k not in ("generate", "output_dir")}
    return _hash({"job": content, "schema": labels_mod.SCHEMA})


def labels_key(layers_key: str, digest: str) -> str:
    """A frame's labels key: its layers key and the job's ``job_digest``."""
    return _hash({"layers": layers_key, "job": digest})


# -- the record ---------------------------------------------------------------------------------------------------

def read_record(layout: OutputLayout) -> dict | None:
    """The conditions folder's record as a dict (any schema: its ``files`` and ``exr`` are read from both), None
    when there is none or it is unreadable."""
    try:
        record = files.read_json(layout.record)
    except errors.InputError:
        return None
    ok = isinstance(record, dict) and isinstance(record.get("files"), list)
    return record if ok else None


def record(key_of_scene: str, frame_names: list, half: bool, job: job_mod.Job, inputs: Inputs, extents: list) -> dict:
    """The record ``render`` writes before its first frame (``RECORD_SCHEMA``): the scene key (``key``), the files
    it writes, the precision, and per asset file its stamp and extent (``recorded_extents`` reads them back)."""
    assets = {}
    for a, st, (bounds, max_sigma) in zip(job.assets, inputs.assets, extents):
        assets[a.ply] = {"stamp": st, "bounds": None if bounds is None else np.asarray(bounds).tolist(),
                         "max_sigma": None if not np.isfinite(max_sigma) else float(max_sigma)}
    return {"schema": RECORD_SCHEMA, "key": key_of_scene, "files": list(frame_names),
            "exr": "half" if half else "float32", "assets": assets}


def recorded_extents(rec: dict | None, job: job_mod.Job, inputs: Inputs) -> list | None:
    """Each asset's ``(bounds, max_sigma)`` from a record whose entry for its file has the file's current stamp;
    None when any asset is missing there (the backend then computes them from the Gaussians)."""
    table = rec.get("assets") if isinstance(rec, dict) and rec.get("schema") == RECORD_SCHEMA else None
    if not isinstance(table, dict):
        return None if job.assets else []
    out = []
    for a, st in zip(job.assets, inputs.assets):
        entry = table.get(a.ply)
        if not isinstance(entry, dict) or entry.get("stamp") != st:
            return None
        try:
            b = entry.get("bounds")
            bounds = None if b is None else np.asarray(b, np.float64).reshape(2, 3)
            sigma = entry.get("max_sigma")
            max_sigma = float("inf") if sigma is None else float(sigma)
        except (TypeError, ValueError):
            return None  # a damaged record: computed again
        out.append((bounds, max_sigma))
    return out


# -- the plan -----------------------------------------------------------------------------------------------------

def frame_labels(path: str) -> dict:
    """A frame's labels as render wrote them ({} when missing, unreadable or of an unknown schema: not finished).
    Labels of an older schema (``labels.OLD_SCHEMAS``) are returned too: their key never matches (it holds the
    schema), so the plan makes them again from the frame's layers when those are current, never renders it again."""
    try:
        lab = files.read_json(path)
    except errors.InputError:
        return {}
    known = (labels_mod.SCHEMA, *labels_mod.OLD_SCHEMAS)
    return lab if isinstance(lab, dict) and lab.get("schema") in known else {}


@dataclass
class Plan:
    """What a render of a job has to do, per output frame: ``render`` (frames to render: their layers key
    changed, or files are missing), ``relabel`` ({frame: previous labels}: the layers are up to date, the labels
    are not) and ``done`` ({frame: labels}: nothing to do). ``keys``/``labels_keys``: each frame's layers and
    labels key."""
    keys: dict
    labels_keys: dict
    render: set = field(default_factory=set)
    relabel: dict = field(default_factory=dict)
    done: dict = field(default_factory=dict)

    @property
    def up_to_date(self) -> bool:
        return not self.render and not self.relabel


def plan(layout: OutputLayout, job: job_mod.Job, keys: dict, force: bool = False) -> Plan:
    """Which frames of ``job`` (its layers ``keys``, ``frame_keys``) are finished in ``layout``'s conditions
    folder: a frame is done when its EXR, preview, labelled preview and labels exist and the labels carry both
    keys; relabelled when only the labels key differs; rendered otherwise (every frame with ``force``)."""
    digest = job_digest(job)
    lkeys = {f: labels_key(k, digest) for f, k in keys.items()}
    p = Plan(keys, lkeys)
    for e in job.frames:
        f = e.frame
        lab = {}
        if not force and os.path.isfile(layout.condition_exr(f)) and os.path.isfile(layout.condition_preview(f)):
            lab = frame_labels(layout.frame_labels(f))
        if lab and lab.get("key") == lkeys[f] and lab.get("layers_key") == keys[f] \
                and os.path.isfile(layout.labelled_preview(f)):
            p.done[f] = lab
        elif lab and lab.get("layers_key") == keys[f]:
            p.relabel[f] = lab
        else:
            p.render.add(f)
    return p


def plan_from_record(output_dir: str, job_path: str, job: job_mod.Job, point_radius: int = 0) -> Plan | None:
    """The render plan as Blender makes it before starting the backend: the precision and asset extents from the
    folder's record (None when there is no current record, or an asset file changed since: only the backend can
    say then). ``point_radius``: the run's (0 unless set). OSError when an input file is gone (the backend reports
    it properly: the caller starts it)."""
    layout = OutputLayout(output_dir)
    rec = read_record(layout)
    if rec is None or rec.get("schema") != RECORD_SCHEMA:
        return None
    inputs = Inputs.of(job_path, job)
    extents = recorded_extents(rec, job, inputs)
    if extents is None:
        return None
    half = rec.get("exr") == "half"
    keys = frame_keys(job, scene_key(job, inputs, point_radius, half), inputs, extents)
    return plan(layout, job, keys)
