"""The body of ``python -m backend render``: every frame of a job, resumable, stoppable (docs/design.md §4.3,
§4.4)."""

from __future__ import annotations

import contextlib
import functools
import os
import time
from dataclasses import dataclass

import numpy as np

from scpainter_blender.core import errors, files, locking, outputs
from scpainter_blender.core import job as job_mod
from scpainter_blender.core import job_inputs
from scpainter_blender.core import labels as labels_mod
from scpainter_blender.core.geometry import boxes
from scpainter_blender.core.output_layout import OutputLayout

from .. import events, png
from ..errors import FolderBusyError
from . import channels
from . import frames as fr
from . import labelled, writer


def frame_paths(job_path: str, job: job_mod.Job, frame: int) -> tuple[str, str]:
    """(EXR, PNG preview) of one output frame's condition layers."""
    layout = OutputLayout(job_mod.resolve(job_path, job.output_dir))
    return layout.condition_exr(frame), layout.condition_preview(frame)


def job_key(job_path: str, job: job_mod.Job, point_radius: int, half: bool = False) -> str:
    """A hash of everything the condition layers depend on: the job without its generation settings, output
    folder and label-only fields (``Job.layers_dict``), the point radius, the EXR precision (``half``), and the
    size and time of each input file. Finished frames are reused only under the same key, so moving a car or a
    camera, or asking for another precision, and rendering again cannot keep stale frames. (``half`` enters the
    hash only when set, so the keys of folders rendered before the option existed, all float32, are unchanged.)"""
    import hashlib
    import json

    content = job.layers_dict()
    files = [job.scene.predictions] if job.scene is not None else []
    files += [a.ply for a in job.assets]
    stamps = []
    for f in files:
        st = os.stat(job_mod.resolve(job_path, f))
        stamps.append([f, st.st_size, st.st_mtime_ns])
    blob = {"job": content, "radius": point_radius, "files": stamps}
    if half:
        blob["exr"] = "half"
    return hashlib.sha256(json.dumps(blob, sort_keys=True).encode()).hexdigest()[:32]


def labels_key(layers_key: str, job: job_mod.Job) -> str:
    """What a frame's labels depend on beyond its layers: the layers' key and the whole job but its generation
    settings and output folder (so editing a box, a class or the frame rate makes new labels)."""
    import hashlib
    import json

    content = {k: v for k, v in job.to_dict().items() if k not in ("generate", "output_dir")}
    blob = json.dumps({"layers": layers_key, "job": content, "schema": labels_mod.SCHEMA}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


def _labels_file(path: str) -> dict:
    """A frame's labels as render wrote them ({} when missing, unreadable or of another schema: not finished)."""
    try:
        lab = files.read_json(path)
    except errors.InputError:
        return {}
    return lab if isinstance(lab, dict) and lab.get("schema") == labels_mod.SCHEMA else {}


def asset_boxes(job: job_mod.Job, scene: fr.Scene, log) -> list:
    """(box_to_file, size, source) per asset: the job's box ("job"), else the upright box of its Gaussians' means
    (``core.geometry.boxes.estimate_box``, up = the file direction its first transform makes vertical) marked
    "estimated"."""
    out = []
    for a, loaded in zip(job.assets, scene.assets):
        if a.box is not None:
            out.append((a.box.box_to_file, a.box.size, "job"))
            continue
        means = loaded.means.cpu().numpy()
        try:
            T, size = boxes.estimate_box(means, labels_mod.asset_up(a))
        except ValueError:  # fewer than 4 usable Gaussians: a degenerate box at their centre
            T, size = np.eye(4), np.zeros(3)
            if len(means):
                T[:3, 3] = np.nanmean(means, axis=0)
        placed = labels_mod.asset_box_to_world(a, (T, size), job.frames[0].frame)
        metres = "" if placed is None else (f" ({placed[1][1]:.2f} x {placed[1][0]:.2f} x {placed[1][2]:.2f} m at "
                                            f"frame {job.frames[0].frame})")
        log(f"labels: {a.name}: no box in the job; estimated {size[1]:.3g} x {size[0]:.3g} x {size[2]:.3g} "
            f"(length x width x height, file units){metres} from its Gaussians")
        out.append((T, size, "estimated"))
    return out


def file_hash(path: str) -> str:
    """SHA-256 (hex) of a file's content."""
    import hashlib

    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def _warn(lab: dict) -> int:
    """A ``warning`` event for each flag of a frame's labels (``core.labels.warnings``); their number."""
    found = labels_mod.warnings(lab)
    for code, message, obj in found:
        events.warning(message, code, frame=lab["frame"], **({"object": obj} if obj else {}))
    return len(found)


def _frame_files(job: job_mod.Job) -> list:
    return OutputLayout.condition_names(e.frame for e in job.frames)


def _previous_record(layout: OutputLayout) -> dict | None:
    """The conditions folder's record ({"key", "files"}), None when there is none or it is unreadable."""
    try:
        record = files.read_json(layout.record)
    except errors.InputError:
        return None
    ok = isinstance(record, dict) and isinstance(record.get("key"), str) and isinstance(record.get("files"), list)
    return record if ok else None


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
    out = outputs.make_folder(paths["output_dir"], "output_dir")
    with (locking.OutputLock(out, "render", busy=FolderBusyError) if lock else contextlib.nullcontext()) as held, \
            events.log_scope():  # an exception from here on is marked with backend.log (events.report_bug)
        log = log or events.FileLog(OutputLayout(out).log)
        if held is not None and held.stale:
            log(f"render: {held.took_over()}")
        return _render(job_path, job, device, force, point_radius, stop, log, out, allow_outside, half)


def _render(job_path, job, device, force, point_radius, stop, log, out, allow_outside, half) -> dict:
    layout = OutputLayout(out)
    cond = outputs.output_folder(out, OutputLayout.CONDITIONS, allow_outside)
    W, H = job.resolution
    total, rendered, skipped = len(job.frames), 0, 0
    previous = _previous_record(layout)
    if half is None:
        half = previous is not None and previous.get("exr") == "half"
    key = job_key(job_path, job, point_radius, half)
    if not force and previous is not None and previous["key"] != key:
        log("render: the job changed since the finished frames were made: rendering every frame again")
        force = True
    if force or previous is None:
        # stale frames go first, so a stop half-way cannot mix old and new; only files this project wrote for the
        # job (its previous record's, and this job's own frame names), never anything else in the folder
        outputs.remove_listed(cond, (previous or {}).get("files", []) + _frame_files(job))
        force = True
    outputs.remove_temporaries(cond, _frame_files(job) + [OutputLayout.RECORD])  # left by a run killed mid-write
    outputs.write_json(layout.record, {"schema": "scpainter.conditions/1", "key": key,
                                       "files": _frame_files(job), "exr": "half" if half else "float32"})
    with contextlib.suppress(FileNotFoundError):  # the record's former name (one line: the key)
        os.remove(layout.former_record)
    lkey = labels_key(key, job)
    todo, relabel, warned = set(), {}, 0
    for e in job.frames:
        lab = {}
        if not force and all(os.path.isfile(p) for p in frame_paths(job_path, job, e.frame)):
            lab = _labels_file(layout.frame_labels(e.frame))
        if lab.get("key") == lkey and os.path.isfile(layout.labelled_preview(e.frame)):
            warned += _warn(lab)  # a finished frame's flags are reported again: every run says what is weak
        elif lab.get("layers_key") == key:  # the layers are up to date: only the labels are made again
            relabel[e.frame] = lab
        else:
            todo.add(e.frame)
    scene = labelling = None
    relabelled = 0
    frames_out = writer.FrameWriter()  # the frames' files are written while the next frame renders
    for n, entry in enumerate(job.frames):
        if stop:
            break
        f = entry.frame
        exr_path, png_path = frame_paths(job_path, job, f)
        if scene is None and (f in todo or f in relabel):  # loaded once, only when there is work
            # the points only when a frame is rendered: relabelling needs the assets alone
            scene = fr.load_scene(job, job_path, device, points=bool(todo))
            if todo:
                log(f"render {job_path}: {len(todo)} of {total} frames {W}x{H} on {device} "
                    f"({'half-float' if half else 'float32'} EXRs); "
                    f"{0 if scene.xyz is None else len(scene.xyz):,} points ({scene.removed_points:,} removed by "
                    f"boxes), {len(scene.assets)} assets")
                _log_cleaning(scene, log)
            labelling = _Labelling(job, layout, asset_boxes(job, scene, log),
                                   [file_hash(job_mod.resolve(job_path, a.ply)) for a in job.assets], key, lkey)
            if stop:  # asked to stop while the scene loaded (outlier removal can take a while)
                break
        if f in relabel:  # a label-only edit (a box, a class, the frame rate): the layers are kept
            warned += _relabel(labelling, n, relabel[f])
            relabelled += 1
            skipped += 1
        elif f not in todo:
            skipped += 1
        else:
            t = time.perf_counter()
            kept = {}
            layers = fr.render_frame(scene, entry, W, H, point_radius, keep=kept)
            amodal = fr.amodal_pixels(scene, entry, W, H, projection=kept["projection"])
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
            frames_out.submit(functools.partial(_write_frame, labelling, n, layers, amodal, half, exr_path, png_path),
                              finish)
        # reused: found up to date; said after the frames before it are finished
        frames_out.after(functools.partial(events.progress, "render", n + 1, total, frame=f, reused=f not in todo))
    frames_out.close()  # every frame started is whole and reported, also after a stop
    return {"frames": total, "rendered": rendered, "skipped": skipped, "output_dir": out, "stopped": bool(stop),
            "relabelled": relabelled, "warnings": warned}


@dataclass
class _Labelling:
    """What a run's labels are made from, once per run: the job, its output folder, each asset's box
    (``asset_boxes``) and file hash, the layers' key and the labels' key."""
    job: job_mod.Job
    layout: OutputLayout
    boxes: list
    hashes: list
    layers_key: str
    key: str

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

    def write_files(self, index: int, layers: dict, amodal) -> dict:
        """``write`` without its events (for a writer thread: ``report`` says them on the events' thread)."""
        f = self.job.frames[index].frame
        lab = labels_mod.frame_labels(self.job, index, instance=layers[channels.INSTANCE],
                                      hole=layers[channels.HOLE], depth=layers[channels.DEPTH], amodal_pixels=amodal,
                                      asset_boxes=self.boxes, asset_hashes=self.hashes, key=self.key,
                                      layers_key=self.layers_key)
        labelled.write(self.layout.labelled_preview(f), np.stack([layers[c] for c in channels.IMAGE], -1), lab)
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
    png.write_png(png_path, np.stack([layers[c] for c in channels.IMAGE], axis=-1))
    return labelling.write_files(index, layers, amodal), time.perf_counter() - t


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
