"""What a job points at, checked before any work: every path it names resolved and confined to the job's folder
and the data roots the user trusts (``job_paths``), and the input files checked from their headers
(``check_inputs``). The document itself (structure, bounds) is ``core.job``'s. No bpy, no torch.
"""

from __future__ import annotations

import os

from . import files, outputs
from .job import Job, JobError, Scene, resolve


def job_paths(job_path, job: Job, allow_outside: bool = False, checkpoint: bool = False, data_roots=()) -> dict:
    """``{field: absolute path}`` of every path the job names (``output_dir``, ``scene.predictions``,
    ``assets[i].ply``, and ``generate.checkpoint`` with ``checkpoint``), relative ones taken from the job's folder.

    Unless ``allow_outside``, each must resolve inside the job's folder or inside one of ``data_roots`` (absolute
    folders the user trusts: ``--data-root``, a batch list's ``data-root:``), with no ``..``, absolute path or
    symbolic link leading elsewhere (``outputs.confined``): a job received from someone else reads and writes only
    its own folder and the shared recordings and assets the user named. The user allows everything with
    ``--allow-outside``; the add-on does, for the output folder the user chose. JobError names the field
    otherwise, with both folders and a hint."""
    job_path = os.fspath(job_path)
    base = os.path.dirname(os.path.abspath(job_path))

    def confine(field, value):
        return outputs.confined(base, value, lambda f, m, h: JobError(job_path, f, m, h), field, allow_outside,
                                data_roots)

    out = {"output_dir": confine("output_dir", job.output_dir)}
    if job.scene is not None:
        out["scene.predictions"] = confine("scene.predictions", job.scene.predictions)
    for i, a in enumerate(job.assets):
        out[f"assets[{i}].ply"] = confine(f"assets[{i}].ply", a.ply)
    if checkpoint and job.generate is not None and job.generate.checkpoint:
        out["generate.checkpoint"] = confine("generate.checkpoint", job.generate.checkpoint)
    return out


def reading(job_path, allow_outside: bool = False, data_roots=()):
    """``with reading(job_path, ...):`` the job's input files read (``files.open_regular``) only where
    ``job_paths`` allows them, checked on each file as opened (``files.confined_reads``): a path that passed
    ``job_paths`` and was swapped for a link leading out before it was read is refused, not read. No limit with
    ``allow_outside``."""
    if allow_outside:
        return files.confined_reads(None)
    return files.confined_reads([os.path.dirname(os.path.abspath(os.fspath(job_path))), *data_roots])


def check_inputs(job_path, job: Job, allow_outside: bool = False, data_roots=()) -> dict:
    """Everything about a validated job that can be checked before any work, from file headers: the paths
    (``job_paths``), that the predictions file is a readable ``.npz`` whose frames include every
    ``source_frames`` entry, and that each asset is a readable Gaussian file with Gaussians the renderer
    draws (read whole, ``splats.asset_verdict``: none valid, none above the renderer's ``splats.ALPHA_MIN``
    opacity, or an empty file, is a JobError naming ``assets[i].ply`` and the file; more than
    ``splats.MOSTLY_INVALID_SHARE`` invalid, or that share never drawn, is listed in ``asset_warnings`` as
    (i, message, code), for the caller's ``warning`` event). Returns the paths plus ``num_source_frames`` and ``asset_warnings``; raises an InputError
    (JobError, PredictionsError, SplatsError) naming file and field. ``allow_outside``, ``data_roots``:
    ``job_paths``'s. Every file is read within ``reading``."""
    paths = job_paths(job_path, job, allow_outside, data_roots=data_roots)
    with reading(job_path, allow_outside, data_roots):   # each file checked again as opened
        _check_files(job_path, job, paths)
    return paths


def _check_files(job_path, job: Job, paths: dict) -> None:
    """``check_inputs``' reading of the files (``paths`` filled in)."""
    from .splats import gaussians as splats, reader as splats_io
    from .vggt import predictions as vggt

    if job.scene is not None:
        pred = paths["scene.predictions"]
        shapes = files.npz_shapes(pred, ["extrinsic"], error=lambda p, k, m: vggt.PredictionsError(p, k, m))
        if "extrinsic" not in shapes:
            raise vggt.PredictionsError(pred, "extrinsic", "missing: the file has no camera poses")
        shape = shapes["extrinsic"]  # (S, 3, 4), a batch axis (1, S, 3, 4), or one squeezed frame (3, 4)
        S = shape[1] if len(shape) == 4 and shape[0] == 1 else 1 if len(shape) == 2 else shape[0]
        if S < 1:
            raise vggt.PredictionsError(pred, "extrinsic", f"holds no frames (shape {shape})")
        paths["num_source_frames"] = S
        for i, fr in enumerate(job.frames):
            bad = [s for s in fr.source_frames if s >= S]
            if bad:
                raise JobError(job_path, f"frames[{i}].source_frames", f"frame(s) {bad[:5]} do not exist: "
                                                                       f"{os.path.basename(pred)} has {S} frames")
    paths["asset_warnings"] = []
    checked = {}  # a file many assets share (a scenario's library car) is read once
    for i in range(len(job.assets)):
        ply_path = paths[f"assets[{i}].ply"]
        if ply_path not in checked:
            ply = splats_io.read(ply_path)
            keep, dropped = splats.valid_rows(ply)  # the rows decode() drops
            checked[ply_path] = splats.asset_verdict(len(ply), dropped, splats.transparent_rows(ply, keep))
        found = checked[ply_path]
        if found is not None and found.refused:
            raise JobError(job_path, f"assets[{i}].ply", f"{ply_path}: {found.text}", found.hint)
        if found is not None:
            paths["asset_warnings"].append((i, f"asset {job.assets[i].name!r} ({ply_path}): {found.text}",
                                            found.code))


def scene_predictions(job_path, scene: Scene):
    """The predictions of a job's ``scene``, read as the import read them (same reading of the poses, same crop;
    NaN/inf pixels dropped): ``vggt.VGGTPredictions``, without ``world_points``. What the renderer and a variation
    run load; ``PredictionsError`` names the file and key."""
    from .vggt import npz as vggt_npz

    return vggt_npz.load_predictions(resolve(job_path, scene.predictions), world_points=False,
                                     extrinsic_convention=scene.extrinsic_convention, crop=list(scene.crop))
