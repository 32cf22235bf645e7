"""The body of ``python -m backend export JOB --format FORMAT [--out DIR]`` (docs/design.md §15); the formats:
``FORMATS``.

Steps: the job's inputs and output folder are checked and the folder locked (``locking.OutputLock``, as
``render`` does); ``render_job`` renders what is missing (it resumes: after ``render`` or ``generate`` it renders
nothing) and writes each frame's labels (``conditions/labels_NNNNNN.json``, ``core.labels``); each frame's labels
are read (a missing or other-schema file is an ``InputError`` naming it: render again), for COCO with the frame's
``instance`` layer (``backend.render.channels``). Images: the generated frames when a finished generation
(``generated/manifest.json`` listing the job's frames, every PNG present, written after the condition EXRs) is
there, else the condition previews, with a ``warning`` event (code ``NO_GENERATED``) saying so; the ``done`` event
says which (``images``). The destination (default ``OutputLayout(output_dir).export(format)``) is written whole
(``outputs.atomic_folder``): a killed export leaves no half dataset, and a previous export there (a folder whose
``OutputLayout.EXPORT_RECORD`` lists every file in it) is replaced only when the new one is complete. A folder with
anything else is refused (``--out``), never overwritten, also when the file appeared while the frames rendered;
an empty folder the user made is filled, never replaced.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import numpy as np

from scpainter_blender.core import errors, files, job_inputs, labels, locking, outputs
from scpainter_blender.core import job as job_mod
from scpainter_blender.core.output_layout import OutputLayout

from .. import events
from ..errors import FolderBusyError
from . import coco, common, kitti, kitti_tracking, nuscenes, openlabel

#: The writer of each ``export --format``: a module of this package (named after the format, ``-`` spelled ``_``)
#: with ``write(folder, frames, progress)`` and
#: ``NEEDS_INSTANCE`` (it reads the frames' instance layers). The names are ``core.backend_protocol.EXPORT_FORMATS``',
#: in its order (a test says so), which gives each its label and description: Blender lists them without the
#: backend. A new format: its writer module, an entry here and there, its tests and docs.
FORMATS = {"kitti": kitti, "coco": coco, "openlabel": openlabel, "kitti-tracking": kitti_tracking,
           "nuscenes": nuscenes}
#: The formats whose writer needs the instance layer.
NEEDS_INSTANCE = tuple(name for name, writer in FORMATS.items() if writer.NEEDS_INSTANCE)
NO_GENERATED = "no_generated_frames"
RENDER_AGAIN = "render again: python -m backend render JOB --force (this export renders only missing frames)"
EXPORT_SCHEMA = "scpainter.export/1"


def check_format(fmt: str) -> str:
    if fmt not in FORMATS:
        raise errors.ArgumentError("--format", f"expected one of {list(FORMATS)}, got {fmt!r}")
    return fmt


def check_destination(out: str, output_dir: str, given: bool, fmt: str | None = None) -> None:
    """What an export may replace: nothing, an empty folder, or a previous export (its ``EXPORT_RECORD``, listing
    every file it wrote: ``outputs.foreign_files``) — of the same format ``fmt`` when given; never a file, a link,
    a folder with a file its record does not list (a planted ``export.json`` protects nothing), a folder holding
    the job's output folder, a name longer than its file system allows (``outputs.name_too_long``), or (the
    default) one under an ``export/`` that is a link. ``given``: the user named
    it (``--out``: an ``ArgumentError``), else the default (an ``InputError`` naming the folder)."""
    def refuse(message, hint="give a new or empty folder, or a previous export of this command"):
        raise (errors.ArgumentError("--out", f"{out} {message}", hint) if given
               else errors.InputError(out, "(folder)", message, hint))

    if (long := outputs.name_too_long(out)) is not None:   # before anything is made: named, not its temporary
        raise errors.InputError(out, "--out" if given else "(folder)",
                                f"has a name too long for its file system ({long})",
                                hint="choose a shorter destination or a folder nearer the root")
    real, real_out = os.path.realpath(out), os.path.realpath(output_dir)
    if real == real_out or real_out.startswith(real.rstrip(os.sep) + os.sep):
        refuse("holds the job's output folder: an export there would replace it")
    parent = os.path.dirname(out)
    if not given and os.path.islink(parent):   # export/ in the output folder: never written through a link
        refuse(f"lies in {parent}, a symbolic link: an export is never written through one",
               hint="remove the link, then run again")
    if not os.path.lexists(out):
        return
    if os.path.islink(out) or not os.path.isdir(out):
        refuse("exists and is not a folder")
    record = os.path.join(out, OutputLayout.EXPORT_RECORD)
    foreign = outputs.foreign_files(out, OutputLayout.EXPORT_RECORD)
    if foreign:
        refuse(f"is a folder with other content (not an export of this command: {foreign[0]!r}"
               f"{' and more' if len(foreign) > 1 else ''} not in its record): it is never overwritten")
    if fmt is not None and os.path.isfile(record):
        try:
            previous = files.read_json(record).get("format")
        except (errors.InputError, AttributeError):
            previous = None
        if previous != fmt:
            from .dataset import FORMAT as DATASET   # (dataset.py imports this module)

            wanted = "a dataset (several formats, or --list)" if fmt == DATASET else fmt
            refuse(f"holds a {previous or 'damaged'} export, not {wanted}: another format is never written over it",
                   hint=f"give a new --out folder (the {previous or 'damaged'} export there is kept)")


def read_labels(path: str, frame: int) -> dict:
    """A frame's labels file (``core.labels``' schema); InputError naming it when missing, unreadable, of another
    schema or of another frame."""
    lab = files.read_json(path)
    hint = RENDER_AGAIN
    if not isinstance(lab, dict) or lab.get("schema") != labels.SCHEMA:
        got = lab.get("schema") if isinstance(lab, dict) else type(lab).__name__
        raise errors.InputError(path, "schema", f"expected {labels.SCHEMA!r}, got {got!r}", hint=hint)
    if lab.get("frame") != frame or not isinstance(lab.get("objects"), list):
        raise errors.InputError(path, "frame", f"expected the labels of frame {frame}, got {lab.get('frame')!r}",
                                hint=hint)
    return lab


def image_source(layout: OutputLayout, job: job_mod.Job) -> tuple[str, str]:
    """("generated", "") when a finished generation of these frames is newer than their conditions, else
    ("conditions", why not)."""
    return frames_image_source(layout, [e.frame for e in job.frames])


def frames_image_source(layout: OutputLayout, frames: list) -> tuple[str, str]:
    """``image_source`` of the scene frames ``frames`` of the output folder ``layout`` (a rig camera's)."""
    try:
        manifest = files.read_json(layout.manifest)
    except errors.InputError:
        return "conditions", "no finished generation (generated/ has no manifest)"
    if not isinstance(manifest, dict) or manifest.get("frames") != frames:
        return "conditions", "the finished generation is of other frames"
    if not all(os.path.isfile(layout.generated_frame(f)) for f in frames):
        return "conditions", "generated frames are missing"
    newest = max(os.stat(layout.condition_exr(f)).st_mtime_ns for f in frames)
    if os.stat(layout.manifest).st_mtime_ns < newest:
        return "conditions", "the generated frames are older than the conditions (the job changed since)"
    return "generated", ""


def read_frame(layout: OutputLayout, frame: int, images: str, instance: bool) -> common.ExportFrame:
    """Output frame ``frame`` of ``layout`` as the writers take it: its labels (``read_labels``), its image (the
    generated frame when ``images`` is "generated", else the condition preview) and, with ``instance``, its
    instance layer."""
    from ..render import channels

    lab = read_labels(layout.frame_labels(frame), frame)
    image = layout.generated_frame(frame) if images == "generated" else layout.condition_preview(frame)
    layer = channels.read(layout.condition_exr(frame), required=(channels.INSTANCE,))[channels.INSTANCE] \
        if instance else None
    return common.ExportFrame(lab, image, layer)


def export_job(job_path: str, job: job_mod.Job, fmt: str, out: str | None = None, device: str = "cpu",
               allow_outside: bool = False, stop=(), data_roots=(), options: dict | None = None,
               sweeps: dict | None = None) -> dict:
    """Export a job's labels as ``fmt`` into ``out`` (None: ``OutputLayout(output_dir).export(fmt)``), rendering
    what is missing first; emits progress and warning events. Returns the counts, ``out``, ``images``,
    ``stopped`` (SIGTERM during the render: nothing exported). The job's paths are confined to its folder and
    ``data_roots`` unless ``allow_outside`` (``job_inputs.check_inputs``). ``options``: the format's own
    (nuscenes: ``version``, ``keyframe_hz``, checked by ``nuscenes.check_options``).

    nuScenes is the one format of several cameras: a rig job is exported whole (§17). In any other format a rig job
    is exported camera by camera, each camera job as a single camera's export of its own frames and labels, into
    ``<out>/<camera>/`` (without ``out``: each camera's ``<output_dir>/<camera>/export/<format>``); every
    destination is checked before the first is written (``out`` itself too: ``check_destination``, a previous rig
    export's record, ``_write_rig_record``, listing what it wrote); the result's ``outs`` is {camera: destination}
    and its counts are summed over the cameras. A rig job with a LiDAR exported as KITTI or KITTI tracking
    (``LIDAR_FORMATS``) is rendered whole first (its sweeps too) and each camera's export carries the LiDAR
    (``sweeps``: ``job_sweeps``, {scene frame: ``common.ExportSweep``}, for a camera job of that rig; its
    ``velodyne/``, ``Tr_velo_to_cam``); the result then adds the render's ``lidar`` counts."""
    check_format(fmt)
    if fmt == nuscenes.FORMAT:
        options = nuscenes.check_options(**(options or {}))
    elif job.rig is not None:
        return _export_rig(job_path, job, fmt, out, device, allow_outside, stop, data_roots)
    paths = checked_paths(job_path, job, allow_outside, data_roots)
    layout = OutputLayout(paths["output_dir"])
    dest = os.path.abspath(out) if out else layout.export(fmt)
    check_destination(dest, layout.root, given=bool(out), fmt=fmt)
    with job_inputs.reading(job_path, allow_outside, data_roots), \
            rendered_job(job_path, job, device, paths, allow_outside, stop) as (rendered, log):  # inputs as opened
        result = {"format": fmt, "out": dest, "output_dir": layout.root, "rendered": rendered["rendered"]}
        if rendered["stopped"]:
            return {**result, "stopped": True}
        return {**result, **write_export(job_path, job, layout, fmt, dest, log, options, sweeps), "stopped": False}


#: The formats that carry a rig job's LiDAR in each camera's export (``common.ExportFrame.sweep``).
LIDAR_FORMATS = ("kitti", "kitti-tracking")


def job_sweeps(job: job_mod.Job, root: str) -> dict:
    """{scene frame: ``common.ExportSweep``} of a rig job with a LiDAR whose output folder is ``root``: each frame's
    ``<LIDAR>/sweep_NNNNNN.pcd.bin`` (``OutputLayout.lidar_sweep``) and the pose ``render`` cast it from,
    ego_to_world · lidar_to_ego (``lidar_sweeps.render_sweeps``)."""
    layout, lidar = OutputLayout(root), job.rig.lidar
    return {e.frame: common.ExportSweep(layout.lidar_sweep(e.frame, lidar.name),
                                        np.asarray(e.ego_to_world, np.float64) @ np.asarray(lidar.lidar_to_ego))
            for e in job.frames}


def _export_rig(job_path, job, fmt, out, device, allow_outside, stop, data_roots) -> dict:
    from ..render import rig_jobs

    root = checked_paths(job_path, job, allow_outside, data_roots)["output_dir"]
    if out:   # <out> itself as a single export's: new, empty, or a previous rig export of this format
        out = os.path.abspath(out)
        check_destination(out, root, given=True, fmt=fmt)
        previous = outputs.created_files(out, OutputLayout.EXPORT_RECORD)
        if previous is not None and not isinstance(_record(out).get("cameras"), list):
            raise errors.ArgumentError("--out", f"{out} holds a single camera's {fmt} export, not a rig's: it is "
                                       "never written into", "give a new --out folder (the export there is kept)")
    dests = {}
    for cam in job.rig.cameras:   # all refused before any is written
        cam_out = rig_jobs.camera_output(root, cam.name)
        dests[cam.name] = os.path.join(os.path.abspath(out), cam.name) if out else OutputLayout(cam_out).export(fmt)
        check_destination(dests[cam.name], cam_out, given=bool(out), fmt=fmt)
    sweeps, pre = None, {}
    if job.rig.lidar is not None and fmt in LIDAR_FORMATS:
        # the whole rig rendered first, as ``render`` does it: the cameras, then the LiDAR's sweeps (a camera job
        # alone never casts them); each camera's export then renders nothing
        from ..render import command as render_cmd

        pre = render_cmd.render_job(job_path, job, device, stop=stop, allow_outside=allow_outside,
                                    data_roots=data_roots)
        if pre["stopped"]:
            return {"format": fmt, "out": out or None, "outs": dests, "output_dir": root,
                    "rendered": pre["rendered"], "lidar": pre.get("lidar"), "stopped": True}
        sweeps = job_sweeps(job, root)
    done: list = []

    def one(cam, camera_job):
        r = export_job(job_path, camera_job, fmt, dests[cam.name], device, allow_outside, stop, data_roots,
                       sweeps=sweeps)
        done.append(cam.name)
        if out and os.path.isdir(out):   # after each camera: a run that fails or is killed later leaves <out> a
            _write_rig_record(out, fmt, job_path, list(done), previous or set())   # rig export the next replaces
        return r

    results = rig_jobs.run_cameras(job, one, stop)
    first = results[0][1] if results else {}
    counts = [k for k, v in first.items() if isinstance(v, int) and not isinstance(v, bool)]
    result = rig_jobs.combined(job, results, root, counts, stop)
    result.update(out=out or None, outs=dests)
    if sweeps is not None:
        result.update(rendered=result.get("rendered", 0) + pre["rendered"], lidar=pre.get("lidar"))
    return result


def _record(folder: str) -> dict:
    """``folder``'s ``EXPORT_RECORD`` ({} when missing or unreadable: ``check_destination`` judged it already)."""
    try:
        with files.confined_reads(None):   # a destination's record: read wherever the destination is
            content = files.read_json(os.path.join(folder, OutputLayout.EXPORT_RECORD))
    except errors.InputError:
        return {}
    return content if isinstance(content, dict) else {}


def _write_rig_record(out: str, fmt: str, job_path: str, cameras: list, previous: set) -> None:
    """The record of a rig job's ``--out`` (its ``EXPORT_RECORD``: format, cameras, and ``outputs.CREATED_KEY``
    listing every file the camera exports wrote there, and those of the previous rig export still present), so the
    next rig export of this format may replace it and anything else there stays refused (``check_destination``)."""
    created = [f for f in outputs.tree_files(out) if f != OutputLayout.EXPORT_RECORD
               and (f.split("/")[0] in cameras or f in previous)]
    outputs.write_json(os.path.join(out, OutputLayout.EXPORT_RECORD), {
        "schema": EXPORT_SCHEMA, "format": fmt, "job": os.path.abspath(job_path), "cameras": cameras,
        outputs.CREATED_KEY: created})


def checked_paths(job_path: str, job: job_mod.Job, allow_outside: bool = False, data_roots=()) -> dict:
    """The job's paths (``job_inputs.check_inputs``: its inputs confined to its folder and ``data_roots`` unless
    ``allow_outside``), its output folder checked and made (``paths["output_dir"]``, absolute)."""
    paths = job_inputs.check_inputs(job_path, job, allow_outside, data_roots)
    outputs.check_output(paths["output_dir"], allow_outside)
    return {**paths, "output_dir": outputs.make_folder(paths["output_dir"], "output_dir", root=True)}


@contextlib.contextmanager
def rendered_job(job_path: str, job: job_mod.Job, device: str, paths: dict, allow_outside: bool = False,
                 stop=()) -> Iterator[tuple]:
    """``with rendered_job(...) as (rendered, log):`` the job's output folder (``paths``: ``checked_paths``)
    locked for an export (``locking.OutputLock``; busy: ``FolderBusyError``), what is missing rendered
    (``render_job``, which resumes: after ``render`` or ``generate`` it renders nothing; ``rendered["stopped"]``
    after SIGTERM), the folder's log open; the lock held until the block ends, while the frames are read."""
    output_dir = paths["output_dir"]
    with locking.OutputLock(output_dir, "export", busy=FolderBusyError) as held, events.log_scope():
        log = events.FileLog(OutputLayout(output_dir).log)
        if held.stale:
            log(f"export: {held.took_over()}")
        from ..render import command as render_cmd

        yield render_cmd.render_job(job_path, job, device, stop=stop, log=log, allow_outside=allow_outside,
                                    lock=False, checked=paths), log


def write_export(job_path: str, job: job_mod.Job, layout: OutputLayout, fmt: str, dest: str, log=None,
                 options: dict | None = None, sweeps: dict | None = None) -> dict:
    """The export itself, once the frames are rendered (labels and layers in ``layout``): the images chosen (a
    warning event when they are the condition previews), every frame read, the destination written whole (a
    previous export there replaced only when this one is complete). Returns the format's counts and ``images``.
    nuScenes reads the job's cameras and LiDAR itself (``nuscenes.job_clip``: a rig job's output folder holds one
    folder per sensor). ``sweeps``: a rig camera's LiDAR sweeps by scene frame (``job_sweeps``), given to each
    frame (``common.ExportFrame.sweep``)."""
    progress = lambda i: events.progress("export", i + 1, total, frame=job.frames[i].frame)  # noqa: E731
    if fmt == nuscenes.FORMAT:
        clip, images, why = nuscenes.job_clip(job, layout.root, nuscenes.job_scene_name(job_path),
                                              nuscenes.job_description(job_path), nuscenes.job_identity(job_path))
        write = lambda tmp: nuscenes.write_clips(tmp, [clip], progress, **(options or {}))  # noqa: E731
    else:
        images, why = image_source(layout, job)
        frames = [read_frame(layout, e.frame, images, fmt in NEEDS_INSTANCE) for e in job.frames]
        for fr, e in zip(frames, job.frames):
            fr.sweep = (sweeps or {}).get(e.frame)
        write = lambda tmp: FORMATS[fmt].write(tmp, frames, progress=progress)  # noqa: E731
    if images == "conditions":
        events.warning(f"exporting the condition previews as images: {why} (run generate first for the "
                       "generated video's frames)", NO_GENERATED)
    total = len(job.frames)
    if os.path.dirname(dest) == os.path.join(layout.root, OutputLayout.EXPORT):   # the default: never via a link
        outputs.own_folder(layout.root, OutputLayout.EXPORT)
    else:
        outputs.make_folder(os.path.dirname(dest), "(folder)")
    # check_destination said what may be replaced (nothing, an empty folder, a previous export); atomic_folder
    # checks again at the rename: a file put there meanwhile is never deleted
    with outputs.atomic_folder(dest, replace=True, usual_mode=True, record=OutputLayout.EXPORT_RECORD) as tmp:
        counts = write(tmp)
        outputs.write_json(os.path.join(tmp, OutputLayout.EXPORT_RECORD), {
            "schema": EXPORT_SCHEMA, "format": fmt, "job": os.path.abspath(job_path), "images": images,
            **counts, "scene_frames": [e.frame for e in job.frames]})
    if log:
        log(f"export {fmt}: {counts['frames']} frames, {counts['objects']} objects ({images} images) -> {dest}")
    return {**counts, "images": images}
