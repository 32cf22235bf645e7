"""A single-camera job made a rig job (``python -m backend rig``, docs/design.md §17): the base job's camera path
becomes the ego path on which one rig camera (``follow``) rides exactly where the base camera was
(``rig.ego_path``); everything else of the base (scene, assets, recorded objects, fps, generate) is kept, its paths
rewritten for the new job's own folder.

No bpy, no torch: numpy.
"""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np

from . import job_inputs, outputs
from . import job as job_mod
from . import rig as rig_mod
from .errors import ArgumentError
from .geometry import cameras

#: ``--lidar``'s word for a rig without a LiDAR.
NO_LIDAR = "none"


def choose_rig(value: str, scale: float = 1.0, lidar: str | None = None) -> rig_mod.Rig:
    """The rig ``--preset`` names: a preset's name (``rig.PRESETS``) or a rig file (``*.json``, ``rig.load``: its
    errors name the file and field), its cameras scaled by ``scale`` (``Rig.scaled``); ``lidar``: None keeps the
    rig's own LiDAR, ``NO_LIDAR`` removes it, a model name (``core.lidar_model.MODELS``) gives the rig that model
    (a rig without a LiDAR gets nuScenes' ``LIDAR_TOP`` mount). ArgumentError names the option otherwise."""
    if not (np.isfinite(scale) and 0.0 < scale <= 4.0):
        raise ArgumentError("--scale", f"expected a number in (0, 4], got {scale!r}",
                            hint="0.25 renders every camera at a quarter of its width and height")
    if value.lower().endswith(".json") or os.path.sep in value or (os.path.altsep or "/") in value:
        if not os.path.isfile(value):
            raise ArgumentError("--preset", f"{value!r}: no such rig file",
                                hint=f"a rig file (scpainter.rig/1) or one of {list(rig_mod.PRESETS)}")
        rig = rig_mod.load(value)
        rig = rig if scale == 1.0 else rig.scaled(scale)
    else:
        rig = rig_mod.preset(value, scale=scale, field="--preset")
    if lidar is not None:
        if lidar == NO_LIDAR:
            rig = replace(rig, lidar=None)
        else:
            problem = rig_mod.lidar_model_problem(lidar)
            if problem is not None:
                raise ArgumentError("--lidar", problem, hint=f"or {NO_LIDAR!r} for a rig without a LiDAR")
            mount = rig.lidar or rig_mod.preset("nuscenes", lidar=True).lidar
            rig = replace(rig, lidar=replace(mount, model=lidar))
    for i, cam in enumerate(rig.cameras):  # (a scaled camera): within the job's bounds, or the option is named
        W, H = cam.resolution
        if max(W, H) > job_mod.MAX_SIDE or W * H > job_mod.MAX_PIXELS:
            raise ArgumentError("--scale", f"makes {cam.name} {W} x {H} pixels: more than a job may render "
                                f"(sides <= {job_mod.MAX_SIDE}, <= {job_mod.MAX_PIXELS:,} pixels)")
    return rig


def rig_job(base: job_mod.Job, rig: rig_mod.Rig, follow: str | None = None) -> job_mod.Job:
    """The rig job of single-camera job ``base``: per frame ``ego_to_world`` = camera_to_world · camera_to_ego⁻¹ of
    rig camera ``follow`` (default the rig's first), so that camera's pose is the base camera's at every frame (its
    K is the rig's: the base's K is not used); frames, source frames, scene, assets, fps, generate and output_dir
    as the base's. ArgumentError on ``--follow`` for a camera the rig lacks."""
    follow = rig.cameras[0].name if follow is None else follow
    if follow not in [c.name for c in rig.cameras]:
        raise ArgumentError("--follow", f"the rig {rig.name!r} has no camera {follow!r}",
                            hint=f"one of {[c.name for c in rig.cameras]}")
    c2w = cameras.rigid_inverse(np.stack([np.asarray(f.world_to_camera, np.float64) for f in base.frames]))
    ego = rig_mod.ego_path(c2w, rig, follow)
    frames = [job_mod.Frame(f.frame, None, None, list(f.source_frames), e) for f, e in zip(base.frames, ego)]
    return replace(base, resolution=None, frames=frames, rig=rig)


def relocated(job: job_mod.Job, paths: dict, folder: str) -> job_mod.Job:
    """``job`` with every path it names (``paths``: ``job_inputs.job_paths``'s, absolute) written for a job file in
    ``folder``: relative when the file lies inside ``folder`` (the folder moves as one), else absolute; the output
    folder is ``folder`` itself (``"."``: the job file lives in its output folder, as Blender and ``vary`` write
    jobs)."""
    def at(field):
        p = os.path.abspath(paths[field])
        return os.path.relpath(p, folder) if outputs.inside(p, folder) else p

    scene = job.scene if job.scene is None else replace(job.scene, predictions=at("scene.predictions"))
    assets = [replace(a, ply=at(f"assets[{i}].ply")) for i, a in enumerate(job.assets)]
    generate = job.generate
    if "generate.checkpoint" in paths:
        generate = replace(generate, checkpoint=at("generate.checkpoint"))
    return replace(job, scene=scene, assets=assets, generate=generate, output_dir=".")


def make(base_path: str | os.PathLike, rig: rig_mod.Rig, out_path: str | os.PathLike, follow: str | None = None,
         allow_outside: bool = False, data_roots=()) -> tuple:
    """Write the rig job of the single-camera job at ``base_path`` to ``out_path`` (atomically, validated:
    ``job.save``); an existing ``out_path`` is an ArgumentError naming ``--out`` unless it holds byte for byte what
    would be written (then nothing is written). The base's paths are confined as ``render`` confines them (``job_inputs.job_paths``: its folder
    and ``data_roots`` unless ``allow_outside``; a JobError naming the field). Returns (the new job, the folders
    outside the new job's folder that its paths lead into: a render of it needs them as ``--data-root``)."""
    base_path, out_path = os.path.abspath(base_path), os.path.abspath(out_path)
    base = job_mod.load(base_path).require_single_camera(base_path, "rig")
    if os.path.exists(out_path) and os.path.samefile(base_path, out_path):
        raise ArgumentError("--out", f"{out_path} is the base job itself",
                            hint="write the rig job to a file of its own (e.g. surround/job.json)")
    paths = job_inputs.job_paths(base_path, base, allow_outside, checkpoint=True, data_roots=data_roots)
    folder = os.path.dirname(out_path)
    job = relocated(rig_job(base, rig, follow), paths, folder)
    outside = sorted({os.path.dirname(p) for f, p in paths.items() if f != "output_dir"
                      and not outputs.inside(p, folder)})
    if os.path.lexists(out_path):   # never replaced: a rendered job's outputs would be left behind another job's
        job = job_mod.Job.from_dict(job.to_dict(), out_path)
        if not _holds(out_path, outputs.json_text(job.to_dict())):
            raise ArgumentError("--out", f"{out_path} exists (another job): it is never overwritten",
                                hint="give a new path, or delete the old job and its outputs first")
        return job, outside   # the very job: nothing to write
    return job_mod.save(out_path, job), outside


def _holds(path: str, text: str) -> bool:
    """Whether the regular file ``path`` holds exactly ``text`` (UTF-8)."""
    if os.path.islink(path) or not os.path.isfile(path):
        return False
    with open(path, "rb") as f:
        return f.read() == text.encode("utf-8")
