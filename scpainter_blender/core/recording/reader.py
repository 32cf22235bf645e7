"""Read a recording's tracked boxes in any of its formats (``detect``: by content) and map them into the import's
world (``recorded_objects``): the one entry point the import and the Blender operator use.

``FORMATS``: ``nuscenes`` (a folder of the devkit's tables, or one table in it), ``kitti`` (a tracking
``label_02/NNNN.txt``), ``openlabel`` (a JSON with the ``openlabel`` root), ``plain`` (``scpainter.objects/1``, see
``plain.py``). ``recorded_objects`` takes each track's box in frame ``i``'s camera (``tracks``' convention) through
the reconstruction's camera of that frame, ``camera_to_world = world_to_camera[i]⁻¹`` (the imported recorded camera
in metres: the predictions' poses through the import's ``vggt_to_world``), giving ``core.job.RecordedObject`` boxes
keyed by output (scene) frame ``frame_start + i``. Its checks, before anything is made: the recording has as many
frames as the reconstruction (when it says), no track names a frame beyond them, and, when the file has the camera's
path, that path has the reconstruction's shape (a similarity fit; catches another drive or frames in another order)
— the scale it finds is reported as a warning when it is not 1 (the import's metric scale is off, so are the boxes).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from .. import errors, files
from .. import job as job_mod
from ..geometry import boxes, cameras, similarity
from . import kitti, nuscenes, openlabel, plain, tracks

FORMATS = ("nuscenes", "kitti", "openlabel", "plain")
#: ``read``'s format argument when the content decides.
AUTO = "auto"
#: The path's shape of a recording against the reconstruction's: RMS residual of camera centres over the path's
#: length above this refuses the file (frames of another drive, or in another order).
PATH_MISMATCH = 0.1
#: The reconstruction's scale against the recording's off by more than this is a warning.
SCALE_WARNING = 0.05


def detect(path: str) -> str:
    """The format of ``path`` by content; InputError naming the file when it is none of ``FORMATS``."""
    if os.path.isdir(path) or os.path.basename(path) in {f"{t}.json" for t in nuscenes.TABLES}:
        folder = path if os.path.isdir(path) else os.path.dirname(path)
        if nuscenes.is_tables_folder(folder):
            return "nuscenes"
        if os.path.isdir(path):
            raise errors.InputError(path, "(folder)", "not a folder of nuScenes tables (no scene.json and "
                                                      "sample_annotation.json)")
    files.check_regular(path)
    with files.open_regular(path) as f:
        head = f.read(4096)
    text = head.decode("utf-8", "replace").lstrip("\ufeff").lstrip()
    if text.startswith("{"):
        d = files.read_json(path)
        if isinstance(d, dict) and "openlabel" in d:
            return "openlabel"
        if isinstance(d, dict) and d.get("schema") == plain.SCHEMA:
            return "plain"
    else:
        first = text.splitlines()[0].split() if text else []
        if len(first) in (len(kitti.FIELDS), len(kitti.FIELDS) + 1) and first[0].isdigit():
            return "kitti"
    raise errors.InputError(path, "(file)", f"objects of an unknown format; the formats read: {', '.join(FORMATS)}",
                            hint="a nuScenes tables folder, a KITTI tracking label_02/NNNN.txt, an OpenLABEL JSON "
                                 f"or a {plain.SCHEMA} JSON (docs/design.md §15)")


def read(path: str, fmt: str = AUTO, scene: str = "", camera: str = "") -> tracks.Recording:
    """The tracks of ``path`` in format ``fmt`` (``AUTO``: ``detect``); ``scene`` chooses a nuScenes scene,
    ``camera`` the camera (nuScenes channel, KITTI image folder, OpenLABEL coordinate system)."""
    path = os.path.abspath(path)
    if fmt == AUTO:
        fmt = detect(path)
    if fmt == "nuscenes":
        return nuscenes.read(path, scene, camera)
    if fmt == "kitti":
        return kitti.read(path, camera)
    if fmt == "openlabel":
        return openlabel.read(path, camera=camera)
    if fmt == "plain":
        return plain.read(path)
    raise errors.InputError(path, "format", f"unknown objects format {fmt!r}; one of {[AUTO, *FORMATS]}")


@dataclass
class Mapped:
    """``recorded_objects``' result: ``objects`` (``core.job.RecordedObject``) and ``warnings`` (sentences)."""
    objects: list
    warnings: list = field(default_factory=list)


def check_path(recording: tracks.Recording, world_to_camera: np.ndarray) -> list:
    """The recording's camera path against the reconstruction's (both (F, 4, 4)): InputError when its shape differs
    (``PATH_MISMATCH``); the warnings about the scale."""
    if recording.world_to_camera is None or len(world_to_camera) < 2:
        return []
    centres = cameras.camera_centers(recording.world_to_camera)
    length = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).sum())
    if length < 1e-3:
        return []
    try:
        fit = similarity.fit_similarity_to_cameras(recording.world_to_camera, world_to_camera)
    except ValueError as e:  # opposite directions: frames reversed
        raise errors.InputError(recording.path, "(frames)", f"the recording's camera path does not match the "
                                                           f"reconstruction's: {e}",
                                hint="the objects must be of the same drive, its frames the predictions' in order") \
            from None
    if fit.rms / fit.scale > PATH_MISMATCH * length:
        raise errors.InputError(recording.path, "(frames)",
                                f"the recording's camera path does not match the reconstruction's (RMS "
                                f"{fit.rms / fit.scale:.2f} m over a {length:.1f} m path)",
                                hint="the objects must be of the same drive, its frames the predictions' in order")
    if abs(fit.scale - 1) > SCALE_WARNING:
        return [f"the reconstruction's path is {fit.scale:.3g}× the recording's: the import's metric scale is off "
                f"by {100 * (fit.scale - 1):+.0f} %, and the objects' boxes with it (choose a metric scale)"]
    return []


def recorded_objects(recording: tracks.Recording, world_to_camera: np.ndarray, frame_start: int) -> Mapped:
    """The recording's tracks as ``RecordedObject``s in the world of ``world_to_camera`` (F, 4, 4): the
    reconstruction's cameras in metres, one per predictions frame, shown at scene frames ``frame_start + i``.
    InputError (naming the recording) when the frames do not match (module docstring)."""
    W = np.asarray(world_to_camera, np.float64)
    n = len(W)
    if recording.num_frames is not None and recording.num_frames != n:
        raise errors.InputError(recording.path, "(frames)", f"the recording has {recording.num_frames} frames, the "
                                                            f"reconstruction {n}",
                                hint="the objects must be of the same drive, its frames the predictions' in order")
    for t in recording.tracks:
        beyond = sorted(f for f in t.boxes if f >= n)
        if beyond:
            raise errors.InputError(recording.path, f"track {t.id!r}", f"is in frame {beyond[0]}, outside the "
                                                                      f"reconstruction's {n} frames (0–{n - 1})",
                                    hint="the objects must be of the same drive, its frames the predictions' in order")
    warnings = check_path(recording, W)
    c2w = cameras.rigid_inverse(W)
    out = []
    for t in recording.tracks:
        frame_boxes = {}
        for f, B in sorted(t.boxes.items()):
            M = c2w[f] @ B
            M[:3, :3] = boxes.nearest_rotation(M[:3, :3])
            frame_boxes[int(frame_start + f)] = M
        out.append(job_mod.RecordedObject(t.id, np.asarray(t.size, np.float64), frame_boxes, t.category, t.ignore))
    return Mapped(out, warnings)
