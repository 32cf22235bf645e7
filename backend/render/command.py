"""The body of ``python -m backend render``: every frame of a job, resumable, stoppable (docs/design.md §4.3,
§4.4)."""

from __future__ import annotations

import contextlib
import functools
import os
import time
from dataclasses import dataclass

import numpy as np

from scpainter_blender.core import frame_keys, locking, outputs
from scpainter_blender.core import job as job_mod
from scpainter_blender.core import job_inputs
from scpainter_blender.core import labels as labels_mod
from scpainter_blender.core.geometry import boxes
from scpainter_blender.core.backend_protocol import CAMERA_FIELD
from scpainter_blender.core.output_layout import FRAME_LABELS, OutputLayout

from .. import events, png
from ..errors import FolderBusyError
from . import channels
from . import frames as fr
from . import labelled, lidar_sweeps, rig_jobs, scene_cache, surround_pictures, writer


def frame_paths(job_path: str, job: job_mod.Job, frame: int) -> tuple[str, str]:
    """(EXR, PNG preview) of one output frame's condition layers."""
    layout = OutputLayout(job_mod.resolve(job_path, job.output_dir))
    return layout.condition_exr(frame), layout.condition_preview(frame)


def job_key(job_path: str, job: job_mod.Job, point_radius: int, half: bool = False) -> str:
    """The scene key of a job's condition layers (``core.frame_keys.scene_key``: everything every frame depends on;
    each frame's own key adds its camera and the assets it can see): what ``conditions/record.json`` records as
    ``key``. A changed point cleaning, precision or predictions file changes it."""
    return frame_keys.scene_key(job, frame_keys.Inputs.of(job_path, job), point_radius, half)


def asset_boxes(job: job_mod.Job, scene: fr.Scene, log) -> list:
    """(box_to_file, size, source) per asset: the job's box ("job"), else the upright box of its Gaussians' means
    (``core.geometry.boxes.estimate_box``, up = the file direction its first transform makes vertical) marked
    "estimated".

    ``estimate_box`` is a pure function of the means and the up direction, so it runs once per distinct pair
    (``_estimate_key``: the means' bytes and shape, the up vector's float64 bytes) and the result is reused: 100
    assets on the same file placed alike cost one estimate, and each gets the same (T, size) it would have got from
    its own (a copy: no asset shares arrays with another). Each asset still logs its own line."""
    out, estimated = [], {}
    for a, loaded in zip(job.assets, scene.assets):
        if a.box is not None:
            out.append((a.box.box_to_file, a.box.size, "job"))
            continue
        means = loaded.means.cpu().numpy()
        up = labels_mod.asset_up(a)
        key = _estimate_key(means, up)
        if key not in estimated:
            estimated[key] = _estimate(means, up)
        T, size = (x.copy() for x in estimated[key])
        placed = labels_mod.asset_box_to_world(a, (T, size), job.frames[0].frame)
        metres = "" if placed is None else (f" ({placed[1][1]:.2f} x {placed[1][0]:.2f} x {placed[1][2]:.2f} m at "
                                            f"frame {job.frames[0].frame})")
        log(f"labels: {a.name}: no box in the job; estimated {size[1]:.3g} x {size[0]:.3g} x {size[2]:.3g} "
            f"(length x width x height, file units){metres} from its Gaussians")
        out.append((T, size, "estimated"))
    return out


def _estimate(means: np.ndarray, up: np.ndarray) -> tuple:
    """(box_to_file (4, 4), size (3,)) of ``estimate_box(means, up)``; fewer than 4 usable Gaussians: a degenerate
    box (size 0) at their centre (identity without any)."""
    try:
        return boxes.estimate_box(means, up)
    except ValueError:  # fewer than 4 usable Gaussians
        T, size = np.eye(4), np.zeros(3)
        if len(means):
            T[:3, 3] = np.nanmean(means, axis=0)
        return T, size


def _estimate_key(means: np.ndarray, up: np.ndarray) -> tuple:
    """What ``_estimate`` depends on, as a dict key: the SHA-256 of the means' float64 bytes with their shape, and
    the up vector's float64 bytes (NaN included: the same bytes give the same result)."""
    import hashlib

    m = np.ascontiguousarray(means, np.float64)
    return hashlib.sha256(m.tobytes()).hexdigest(), m.shape, np.ascontiguousarray(up, np.float64).tobytes()


def file_hash(path: str) -> str:
    """SHA-256 (hex) of a file's content."""
    import hashlib

    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def asset_hashes(job_path: str, job: job_mod.Job) -> list:
    """``file_hash`` of each asset's file, read once per file: assets whose files have the same real path, size and
    mtime (``core.frame_keys.stamp``, the identity the frame keys take of a file) share one reading."""
    out, done = [], {}
    for a in job.assets:
        path = job_mod.resolve(job_path, a.ply)
        try:
            real = os.path.realpath(path)
            key = (real, *frame_keys.stamp(real))
        except OSError:  # gone since the inputs were checked: file_hash says so, as it would have
            out.append(file_hash(path))
            continue
        if key not in done:
            done[key] = file_hash(path)
        out.append(done[key])
    return out


def _warn(lab: dict) -> int:
    """A ``warning`` event for each flag of a frame's labels (``core.labels.warnings``); their number."""
    found = labels_mod.warnings(lab)
    for code, message, obj in found:
        events.warning(message, code, frame=lab["frame"], **({"object": obj} if obj else {}))
    return len(found)


def _frame_files(job: job_mod.Job) -> list:
    return OutputLayout.condition_names(e.frame for e in job.frames)


def warn_inputs(job: job_mod.Job, paths: dict) -> int:
    """A ``warning`` event (code ``splats.INVALID_GAUSSIANS`` or ``splats.TRANSPARENT_ASSET``, ``object``: the
    asset's name) for each asset that ``job_inputs.check_inputs`` found mostly invalid or mostly never drawn
    (``paths["asset_warnings"]``), every run and every ``--check``; their number."""
    for i, message, code in paths.get("asset_warnings", ()):
        events.warning(message, code, object=job.assets[i].name)
    return len(paths.get("asset_warnings", ()))


def render_job(job_path: str, job: job_mod.Job, device: str, force: bool = False, point_radius: int = 0,
               stop=(), log=None, allow_outside: bool = False, lock: bool = True, checked: dict | None = None,
               half: bool | None = None, data_roots=()) -> dict:
    """Render the frames not finished yet (all with ``force``, or when the job changed since they were made);
    emits progress and artifact events.

    First the job's paths and input files are checked (``job_inputs.check_inputs``: confined to the job's folder
    and ``data_roots`` unless ``allow_outside``); with ``lock`` the output folder is locked for the run
    (``locking.OutputLock``; a second run raises ``errors.FolderBusyError``). ``checked``: the paths
    ``job_inputs.check_inputs`` returned to a caller that already checked the inputs and the output folder
    (``generate.prepare``), so they are not read twice.
    ``stop``: a list that becomes non-empty when the caller wants to stop (checked between frames). ``half``: the
    EXRs store I, M and M_a as half floats, Z as float32 (``channels.write``), or all float32 (False); None (for
    callers that only need the conditions to exist: ``generate``, ``evaluate``) keeps the precision the folder's
    finished frames were rendered with (float32 when there are none), so a ``render --half-float`` followed by
    ``generate`` does not render every frame again. Returns counts and ``stopped``.
    """
    paths = checked
    if paths is None:
        paths = job_inputs.check_inputs(job_path, job, allow_outside, data_roots)
        outputs.check_output(paths["output_dir"], allow_outside)
    if job.rig is not None:
        return _render_rig(job_path, job, device, force, point_radius, stop, log, allow_outside, lock, paths,
                           checked is None, half, data_roots)
    warned = warn_inputs(job, paths)
    out = outputs.make_folder(paths["output_dir"], "output_dir", root=True)
    with (locking.OutputLock(out, "render", busy=FolderBusyError) if lock else contextlib.nullcontext()) as held, \
            events.log_scope():  # an exception from here on is marked with backend.log (events.report_bug)
        log = log or events.FileLog(OutputLayout(out).log)
        if held is not None and held.stale:
            log(f"render: {held.took_over()}")
        # the inputs read where job_paths allowed them, each file checked as opened (not swapped for a link since);
        # a caller that checked them itself (``checked``) keeps its own reading rules
        with job_inputs.reading(job_path, allow_outside, data_roots) if checked is None else contextlib.nullcontext():
            result = _render(job_path, job, device, force, point_radius, stop, log, out, allow_outside, half)
        return {**result, "warnings": result["warnings"] + warned}


#: The render's counts, summed over a rig job's cameras.
COUNTS = ("frames", "rendered", "skipped", "relabelled", "warnings")


def _render_rig(job_path, job, device, force, point_radius, stop, log, allow_outside, lock, paths, reading, half,
                data_roots) -> dict:
    """A rig job (``rig_jobs``): each camera job rendered into ``<output_dir>/<camera>/`` as a single camera's,
    the inputs checked once (``paths``: the rig job's; ``reading``: this call checked them, so it also confines
    the reads), the scene loaded once."""
    root = outputs.make_folder(paths["output_dir"], "output_dir", root=True)
    warned = warn_inputs(job, paths)

    def one(cam, camera_job):
        out = rig_jobs.camera_output(root, cam.name)
        outputs.check_output(out, allow_outside)
        # the rig's checks stand for the camera's (the same inputs); its asset warnings were said once, above
        checked = {**paths, "output_dir": out, "asset_warnings": ()}
        return render_job(job_path, camera_job, device, force, point_radius, stop, log, allow_outside, lock,
                          checked, half, data_roots)

    sweeps = None
    with job_inputs.reading(job_path, allow_outside, data_roots) if reading else contextlib.nullcontext(), \
            scene_cache.shared("rig job", "its cameras"):   # the LiDAR casts from the points the cameras loaded
        results = rig_jobs.run_cameras(job, one, stop)
        if job.rig.lidar is not None and not stop and not any(r.get("stopped") for _, r in results):
            with events.tagged(**{CAMERA_FIELD: job.rig.lidar.name}):
                sweeps = lidar_sweeps.render_sweeps(job_path, job, root, device, force, stop, log, allow_outside)
    result = rig_jobs.combined(job, results, os.path.abspath(root), COUNTS, stop)
    result["warnings"] += warned
    if sweeps is not None:
        result["lidar"] = sweeps
        result["stopped"] = result["stopped"] or sweeps["stopped"]
    elif job.rig.lidar is not None:
        result["stopped"] = True   # the cameras stopped first: the sweeps are the next run's
    if not result["stopped"]:
        layout = OutputLayout(root)
        if result["rendered"] or (sweeps or {}).get("cast") or \
                not all(os.path.isfile(layout.surround(e.frame)) for e in job.frames):
            for path, e in zip(surround_pictures.write_pictures(root, job), job.frames):
                events.artifact(path, frame=e.frame, kind="surround")
    return result


def _render(job_path, job, device, force, point_radius, stop, log, out, allow_outside, half) -> dict:
    layout = OutputLayout(out)
    cond = outputs.output_folder(out, OutputLayout.CONDITIONS, allow_outside)
    W, H = job.resolution
    total, rendered, skipped = len(job.frames), 0, 0
    previous = frame_keys.read_record(layout)
    if half is None:
        half = previous is not None and previous.get("exr") == "half"
    # per-frame keys (core.frame_keys): the assets' extents from the record when their files did not change, else
    # from their Gaussians (loaded here, kept for the frames)
    inputs = frame_keys.Inputs.of(job_path, job)
    extents = frame_keys.recorded_extents(previous, job, inputs)
    scene = None
    if extents is None:
        scene = fr.load_scene(job, job_path, device, points=False)
        extents = [(a.bounds, a.max_sigma) for a in scene.assets]  # visibility.asset_bounds, as Blender reads them
    key = frame_keys.scene_key(job, inputs, point_radius, half)
    keys = frame_keys.frame_keys(job, key, inputs, extents)
    plan = frame_keys.plan(layout, job, keys, force)
    names = _frame_files(job)
    if force:
        # only files this project wrote for the job (its previous record's, and this job's own frame names), never
        # anything else in the folder
        outputs.remove_listed(cond, (previous or {}).get("files", []) + names)
    else:  # frames the job no longer has (a shorter range): never shown beside this job's
        outputs.remove_listed(cond, [n for n in (previous or {}).get("files", []) if n not in set(names)])
    outputs.remove_temporaries(cond, names + [OutputLayout.RECORD])  # left by a run killed mid-write
    outputs.write_json(layout.record, frame_keys.record(key, names, half, job, inputs, extents))
    with contextlib.suppress(FileNotFoundError):  # the record's former name (one line: the key)
        os.remove(layout.former_record)
    if plan.render and len(plan.render) < total:
        log(f"render: {len(plan.render)} of {total} frames changed since they were rendered (their cameras, or "
            f"the assets they can see); the other {total - len(plan.render)} are kept")
    warned = sum(_warn(plan.done[e.frame]) for e in job.frames if e.frame in plan.done)  # said again every run
    # the labels of the frames to render go first, all at once (one folder walk, not one per frame): a kill before a
    # frame's new labels are written leaves it unfinished, never its new EXR under its old labels' key (a frame in
    # the plan is out of date already: without its labels it is rendered again, as it would have been)
    outputs.remove_listed(cond, [FRAME_LABELS.name(e.frame) for e in job.frames if e.frame in plan.render])
    labelling = None
    relabelled = 0
    # the frames' files are written while the next frame renders; on leaving, every frame started is whole and
    # reported (also after a stop); the caller's own error only lets the frames being written finish
    with writer.FrameWriter() as frames_out:
        for n, entry in enumerate(job.frames):
            if stop:
                break
            f = entry.frame
            exr_path, png_path = frame_paths(job_path, job, f)
            if labelling is None and (f in plan.render or f in plan.relabel):  # loaded once, only when there is work
                # the points only when a frame is rendered: relabelling needs the assets alone
                if scene is None:
                    scene = fr.load_scene(job, job_path, device, points=bool(plan.render))
                elif plan.render:
                    fr.load_points(scene, job, job_path)
                if plan.render:
                    log(f"render {job_path}: {len(plan.render)} of {total} frames {W}x{H} on {device} "
                        f"({'half-float' if half else 'float32'} EXRs); "
                        f"{0 if scene.xyz is None else len(scene.xyz):,} points ({scene.removed_points:,} removed by "
                        f"boxes), {len(scene.assets)} assets")
                    _log_cleaning(scene, log)
                labelling = _Labelling(job, layout, asset_boxes(job, scene, log),
                                       asset_hashes(job_path, job), plan.keys,
                                       plan.labels_keys)
                if stop:  # asked to stop while the scene loaded (outlier removal can take a while)
                    break
            if f in plan.relabel:  # a label-only edit (a box, a class, the frame rate): the layers are kept
                warned += _relabel(labelling, n, plan.relabel[f])
                relabelled += 1
                skipped += 1
            elif f not in plan.render:
                skipped += 1
            else:
                t = time.perf_counter()
                kept = {}
                layers = fr.render_frame(scene, entry, W, H, point_radius, keep=kept)
                amodal = fr.frame_amodal(scene, entry, W, H, kept)  # from the frame's own walk on the CPU
                render_s = time.perf_counter() - t

                def finish(written, f=f, exr_path=exr_path, png_path=png_path, hole=layers[channels.HOLE].mean(),
                           render_s=render_s):  # this thread, in frame order, once the frame's files are on disk
                    nonlocal rendered, warned
                    lab, write_s = written
                    events.artifact(exr_path, frame=f, kind="conditions")
                    events.artifact(png_path, frame=f, kind="preview")
                    labelling.report(f)
                    rendered += 1
                    warned += _warn(lab)
                    log(f"frame {f}: {render_s:.3f} s rendering, {write_s:.3f} s writing (beside the next frame), "
                        f"hole {hole:.3f}, {sum(o['visible_pixels'] > 0 for o in lab['objects'])} objects visible")
                frames_out.submit(functools.partial(_write_frame, labelling, n, layers, amodal, half, exr_path,
                                                    png_path), finish)
            # reused: found up to date; said after the frames before it are finished
            frames_out.after(functools.partial(events.progress, "render", n + 1, total, frame=f,
                                               reused=f not in plan.render))
    return {"frames": total, "rendered": rendered, "skipped": skipped, "output_dir": out, "stopped": bool(stop),
            "relabelled": relabelled, "warnings": warned}


@dataclass
class _Labelling:
    """What a run's labels are made from, once per run: the job, its output folder, each asset's box
    (``asset_boxes``) and file hash, and each frame's layers key and labels key."""
    job: job_mod.Job
    layout: OutputLayout
    boxes: list
    hashes: list
    layers_keys: dict   # {frame: layers key} (core.frame_keys.Plan.keys)
    keys: dict          # {frame: labels key}

    def write(self, index: int, layers: dict, amodal) -> dict:
        """The labels of ``job.frames[index]`` from its layers (``channels`` keys) and its assets' amodal pixel
        counts: the labelled preview, then the labels file (last: its key marks the frame finished), and their
        artifact events; returns the labels."""
        lab = self.write_files(index, layers, amodal)
        self.report(lab["frame"])
        return lab

    def report(self, f: int) -> None:
        """The artifact events of frame ``f``'s labelled preview and labels file (once both are on disk)."""
        events.artifact(self.layout.labelled_preview(f), frame=f, kind="labelled")
        events.artifact(self.layout.frame_labels(f), frame=f, kind="labels")

    def write_files(self, index: int, layers: dict, amodal, image=None) -> dict:
        """``write`` without its events (for a writer thread: ``report`` says them on the events' thread).
        ``image``: the condition image as the preview wrote it ((H, W, 3) uint8), else made from ``layers``."""
        f = self.job.frames[index].frame
        lab = labels_mod.frame_labels(self.job, index, instance=layers[channels.INSTANCE],
                                      hole=layers[channels.HOLE], depth=layers[channels.DEPTH], amodal_pixels=amodal,
                                      asset_boxes=self.boxes, asset_hashes=self.hashes, key=self.keys[f],
                                      layers_key=self.layers_keys[f])
        labelled.write(self.layout.labelled_preview(f),
                       np.stack([layers[c] for c in channels.IMAGE], -1) if image is None else image, lab)
        outputs.write_json(self.layout.frame_labels(f), lab)
        return lab


def _write_frame(labelling: _Labelling, index: int, layers: dict, amodal, half: bool, exr_path: str,
                 png_path: str) -> tuple:
    """A rendered frame's files (on a ``writer.FrameWriter`` thread): the condition EXR (``half``: its precision)
    and its preview, then its labels (``_Labelling.write_files``: last, they mark the frame finished). Returns
    (labels, seconds taken)."""
    t = time.perf_counter()
    entry = labelling.job.frames[index]
    W, H = labelling.job.resolution
    channels.write(exr_path, layers, half=half, camera=channels.camera_attributes(entry.K, entry.world_to_camera, W, H))
    # the 8-bit image once, for the preview and the labelled preview (write_png's rounding)
    image = png.eight_bit(np.stack([layers[c] for c in channels.IMAGE], axis=-1))
    png.write_png(png_path, image)
    return labelling.write_files(index, layers, amodal, image), time.perf_counter() - t


def _relabel(labelling: _Labelling, index: int, old: dict) -> int:
    """New labels (and labelled preview) for a frame whose layers are up to date: the instance, hole and depth
    layers read back from its EXR, each asset's amodal pixel count from its previous labels (made under the same
    layers, so the same asset renders alone the same). Returns the number of warnings it said."""
    n_assets = len(labelling.job.assets)
    layers = channels.read(labelling.layout.condition_exr(labelling.job.frames[index].frame))
    amodal = np.zeros(n_assets, np.int64)
    for o in old.get("objects", []):
        if o.get("synthetic") and 1 <= o.get("track_id", 0) <= n_assets:
            amodal[o["track_id"] - 1] = int(o.get("amodal_pixels") or 0)
    return _warn(labelling.write(index, layers, amodal))


def _log_cleaning(scene: fr.Scene, log) -> None:
    """What the scene's point cleaning dropped and took, and a warning when it dropped most of the points (a
    depth-edge ratio too small for the clip's resolution, or outlier settings too strict)."""
    c = scene.cleaning
    if not c:
        return
    kept = 0 if scene.xyz is None else len(scene.xyz)
    dropped = c["depth_edge_points"] + c["outlier_points"]
    log(f"point cleaning: {c['depth_edge_points']:,} points on depth edges and {c['outlier_points']:,} outliers "
        f"left out ({c['cloud_s']:.2f} s for the cloud, {c['outliers_s']:.2f} s for outliers)")
    if dropped > kept:
        log(f"warning: point cleaning left out {dropped:,} of {dropped + kept:,} points: check "
            "scene.point_cleaning (a larger depth_edge_ratio, or null to turn a filter off)")
