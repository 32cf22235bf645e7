"""Write the scene as a ``job.json`` (DESIGN §4.2): active camera per frame, points, removal boxes, assets.

Per output frame the scene is evaluated, so keyframes, drivers, constraints and parents are all honoured:
K comes from the camera's lens, sensor, shift and the render settings; world_to_camera from its matrix_world; an
asset's object_to_world is its matrix_world composed with ``scpainter_data_from_file``. What the scene does not
use is left out: no reconstruction, no ``scene``; no (accepted) assets, no ``assets``; no checkpoint, no
``generate``.
"""

from __future__ import annotations

import os

import numpy as np

from ..core import cameras
from ..core import job as job_mod
from . import camera as camera_mod
from . import points as points_mod


def _m(value):
    return np.array(value, dtype=np.float64).reshape(4, 4)


def effective_world_from_vggt(obj) -> np.ndarray:
    """The points object's world_from_vggt after the artist moved it: matrix_world · (matrix at import)^-1 · W."""
    W = _m(obj["scpainter_world_from_vggt"])
    at_import = _m(obj.get("scpainter_matrix_world_at_import", np.eye(4).ravel().tolist()))
    return np.array(obj.matrix_world, dtype=np.float64) @ np.linalg.inv(at_import) @ W


def source_frames(obj, scene_frame: int) -> list:
    """VGGT frames whose points go into an output frame: the points object's frame window when it shows only
    the current frame, every frame otherwise."""
    n = int(obj.get("scpainter_num_frames", 0))
    mod = points_mod.points_modifier(obj)
    if mod is not None and points_mod.get_input(mod, "Current Frame Only"):
        k = int(points_mod.get_input(mod, "Frame Window"))
        centre = scene_frame - int(points_mod.get_input(mod, "Frame Offset"))
        return [i for i in range(centre - k, centre + k + 1) if 0 <= i < n]
    return list(range(n))


def removal_box(obj) -> dict:
    """A removal box from a cube empty: rigid box_to_world and full size in metres (scale · 2 · display size)."""
    M = np.array(obj.matrix_world, dtype=np.float64)
    scale = np.linalg.norm(M[:3, :3], axis=0)
    rigid = M.copy()
    rigid[:3, :3] = M[:3, :3] / scale
    return {"box_to_world": rigid.tolist(), "size": (2.0 * obj.empty_display_size * scale).tolist()}


def build_job(context, job_path: str, output_dir: str | None = None, checkpoint: str = "",
              camera=None) -> dict:
    """The job dict for the scene's frame range, seen by ``camera`` (default: the scene camera)."""
    scene = context.scene
    cam = camera or scene.camera
    if cam is None or cam.type != "CAMERA":
        raise ValueError("the scene has no active camera: add one (or a camera path) before exporting a job")
    job_dir = os.path.dirname(os.path.abspath(job_path))
    frames = list(range(scene.frame_start, scene.frame_end + 1))
    objs = list(scene.objects)
    pts = next((o for o in objs if o.get("scpainter_kind") == "points"), None)
    boxes = [o for o in objs if o.get("scpainter_kind") == "removal_box"]
    assets = [o for o in objs if o.get("scpainter_kind") == "gaussian_asset"
              and o.get("scpainter_review") != "rejected" and not o.hide_render]
    r = scene.render
    W = round(r.resolution_x * r.resolution_percentage / 100)
    H = round(r.resolution_y * r.resolution_percentage / 100)
    out_frames = []
    asset_m = {a.name: {} for a in assets}
    current = scene.frame_current
    try:
        for f in frames:
            scene.frame_set(f)
            M = np.array(cam.matrix_world, dtype=np.float64)
            M[:3, :3] /= np.linalg.norm(M[:3, :3], axis=0)
            entry = {"frame": f, "K": camera_mod.K_of_camera_object(scene, cam).tolist(),
                     "world_to_camera": cameras.world_to_camera_from_blender(M).tolist()}
            if pts is not None:
                entry["source_frames"] = source_frames(pts, f)
            out_frames.append(entry)
            for a in assets:
                asset_m[a.name][str(f)] = (np.array(a.matrix_world, dtype=np.float64)
                                           @ _m(a["scpainter_data_from_file"])).tolist()
    finally:
        scene.frame_set(current)
    job = {"schema": job_mod.SCHEMA, "resolution": [W, H], "frames": out_frames}
    if pts is not None:
        job["scene"] = {"predictions": os.path.relpath(pts["scpainter_source"], job_dir),
                        "world_from_vggt": effective_world_from_vggt(pts).tolist(),
                        "confidence_percentile": float(pts.get("scpainter_confidence_percentile", 50.0)),
                        # how the import read the file: the backend loads the same poses and pixels
                        "extrinsic_convention": str(pts.get("scpainter_extrinsic_convention", "world_to_camera")),
                        "crop": [int(v) for v in pts.get("scpainter_crop", [0, 0, 0, 0])]}
        if boxes:
            job["scene"]["removal_boxes"] = [removal_box(b) for b in boxes]
    if assets:
        job["assets"] = [{"name": a.name, "ply": os.path.relpath(a["scpainter_source"], job_dir),
                          "object_to_world": asset_m[a.name]} for a in assets]
    job["output_dir"] = os.path.relpath(output_dir or job_dir, job_dir)
    if checkpoint:
        job["generate"] = {"checkpoint": checkpoint, "steps": 25, "window": 14, "overlap": 4, "seed": 0}
    return job


def export_job(context, job_path: str, **kw) -> dict:
    job = build_job(context, job_path, **kw)
    job_mod.save(job_path, job)
    return job
