"""nuScenes (nuscenes-devkit 1.2.0's ``schema.md``; read by the devkit's ``NuScenes(version, dataroot)`` and by
mmdetection3d's ``tools/create_data.py nuscenes``, in the tests only): a dataroot ::

    <version>/{category,attribute,visibility,instance,sensor,calibrated_sensor,ego_pose,log,scene,sample,
               sample_data,sample_annotation,map}.json     the 13 tables (``nuscenes_tables``)
    <version>/splits.json            {split: [scene names]} (the devkit's custom splits: a dataset's split by drive)
    samples/<CHANNEL>/<scene>__<CHANNEL>__<µs>.png       keyframes: each camera's image, LIDAR_TOP's .pcd.bin
    sweeps/<CHANNEL>/...                                  the other frames
    maps/<token>.png                 one map raster per scene (the strip the ego drove on)

``--version`` (``VERSIONS``): ``v1.0-mini`` (default) or ``v1.0-trainval``, the names mmdetection3d's converter
accepts for annotated data (``v1.0-test`` has no annotations); ``create_data.py nuscenes --version v1.0-mini``
converts only that one (with ``v1.0`` it wants ``-trainval`` and ``-test`` both). Its split is by the devkit's
hard-coded scene names (``splits.mini_train`` / ``splits.train``), every other scene in val: every scene of ours is in
its val set and its train file is empty. ``splits.json`` carries ours (the devkit's custom split): a user's copy of
the converter takes its train and val scenes from ``nuscenes.utils.splits.get_scenes_of_custom_split("train", nusc)``
(README). Nothing here can change the converter, so no event says it. It also reads each sample's six camera
channels by name: other channels get a ``NOT_SIX_CAMERAS`` warning. A single job's scene is named after its folder
(``job_scene_name``), a dataset's ``scpainter-SSSS``; tokens are seeded by the name and ``job_identity``. Images stay PNG (``fileformat`` png):
JPEG would lose detail for no reader's sake (the devkit opens them with PIL, mmdetection3d with ``mmcv.imread``,
both by content). Keyframes every 1 / ``--keyframe-hz`` s (default 2 Hz, nuScenes'); a clip with one keyframe
gets a warning (velocities need two).

A **rig job** (``job.rig``) exports its cameras' output folders (``<output_dir>/<CAMERA>/``, each an ordinary one)
and its LiDAR's sweeps (``<output_dir>/<LIDAR>/sweep_NNNNNN.pcd.bin``, written by ``render``). A **single-camera
job** exports as the rig ``front``: its camera is ``CAM_FRONT`` mounted as nuScenes' (``core.rig``), the ego pose
= camera_to_world · camera_to_ego⁻¹, with no LIDAR_TOP: a ``warning`` (``NO_LIDAR``) says every box then has
``num_lidar_pts`` 0, which the devkit's ``filter_eval_boxes`` and mmdetection3d's ``valid_flag`` drop.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Callable

import numpy as np

from scpainter_blender.core import errors, files, outputs
from scpainter_blender.core import rig as rig_mod
from scpainter_blender.core.geometry import cameras
from scpainter_blender.core.output_layout import OutputLayout

from .. import events, png
from . import common
from .nuscenes_tables import CameraClip, Clip, Tables

FORMAT = "nuscenes"
#: Whether ``write`` reads the frames' instance layers (``command.FORMATS``).
NEEDS_INSTANCE = False
VERSIONS = ("v1.0-mini", "v1.0-trainval")
DEFAULT_VERSION = VERSIONS[0]
DEFAULT_KEYFRAME_HZ = 2.0
SPLITS = "splits.json"
#: Warning codes: a clip without a LiDAR; a clip with a single keyframe; a clip whose sensors are not nuScenes'
#: six cameras and LIDAR_TOP by name.
NO_LIDAR, ONE_KEYFRAME, NOT_SIX_CAMERAS = "no_lidar", "one_keyframe", "not_six_cameras"
#: What a scene's name may hold (it is in every file name of the scene) and its length.
NAME_CHARS, MAX_NAME = re.compile(r"[^A-Za-z0-9_-]"), 64


def check_options(version: str = DEFAULT_VERSION, keyframe_hz: float = DEFAULT_KEYFRAME_HZ) -> dict:
    """{"version", "keyframe_hz"} checked: ArgumentError naming ``--version`` or ``--keyframe-hz``."""
    if version not in VERSIONS:
        raise errors.ArgumentError("--version", f"expected one of {list(VERSIONS)}, got {version!r}",
                                   hint="the names mmdetection3d's nuScenes converter accepts for annotated data")
    try:
        hz = float(keyframe_hz)
    except (TypeError, ValueError):
        hz = float("nan")
    if not 0.0 < hz <= 1000.0:
        raise errors.ArgumentError("--keyframe-hz", f"expected a rate in Hz above 0, got {keyframe_hz!r}",
                                   hint="nuScenes' own keyframes are 2 Hz")
    return {"version": version, "keyframe_hz": hz}


def front_rig(K, resolution) -> rig_mod.Rig:
    """The rig ``front`` of a single-camera job: nuScenes' CAM_FRONT mount with the job's K and resolution."""
    mount = rig_mod.preset("front").camera("CAM_FRONT").camera_to_ego
    return rig_mod.Rig("front", [rig_mod.RigCamera("CAM_FRONT", tuple(resolution), np.asarray(K), mount)])


def clip_of_frames(frames: list, name: str, description: str = "", identity: str = "") -> Clip:
    """The clip of a single-camera job's ``frames`` (``common.ExportFrame``): CAM_FRONT of ``front_rig``, the ego
    pose from each frame's camera; ``identity``: the job's (``job_identity``)."""
    first = frames[0].labels
    rig = front_rig(first["camera"]["K"], first["image_size"])
    cam = rig.cameras[0]
    to_ego = cameras.rigid_inverse(cam.camera_to_ego)
    ego = np.stack([np.asarray(f.labels["camera"]["camera_to_world"], np.float64) @ to_ego for f in frames])
    return Clip(name, description or "a single-camera job as CAM_FRONT", rig.name,
                [f.labels["frame"] for f in frames], [float(f.labels["timestamp_s"]) for f in frames], ego,
                [CameraClip(cam.name, cam.camera_to_ego, [f.labels for f in frames], [f.image for f in frames])],
                identity=identity)


def folder_clip(root: str, rig: rig_mod.Rig, frames: list, ego_to_world, name: str, description: str = "",
                identity: str = "") -> tuple:
    """(clip, images) of a rig job's output folder ``root``: each camera's labels and images from
    ``<root>/<CAMERA>/`` (``command.read_frame``; images: the generated frames where a finished generation is there,
    else the condition previews — ``images`` says which, per camera), the LiDAR's sweeps from
    ``<root>/<LIDAR>/`` (``OutputLayout.lidar_sweep``). ``frames``: the scene frame numbers; ``ego_to_world`` (N, 4, 4)."""
    from . import command

    cams, images = [], []
    out = OutputLayout(root)
    for cam in rig.cameras:
        layout = out.camera(cam.name)
        source, _ = command.frames_image_source(layout, frames)
        read = [command.read_frame(layout, f, source, False) for f in frames]
        cams.append(CameraClip(cam.name, cam.camera_to_ego, [r.labels for r in read], [r.image for r in read]))
        images.append(source)
    sweeps = [out.lidar_sweep(f, rig.lidar.name) for f in frames] if rig.lidar else []
    times = [float(lab["timestamp_s"]) for lab in cams[0].labels]
    return Clip(name, description or f"rig {rig.name}", rig.name, list(frames), times,
                np.asarray(ego_to_world, np.float64), cams, rig.lidar, sweeps, identity), images


def scene_name(sequence: int) -> str:
    """The scene (and log) name of a dataset's ``sequence``-th job: ``scpainter-NNNN``."""
    return f"scpainter-{int(sequence):04d}"


def job_scene_name(job_path: str) -> str:
    """The scene (and log) name of a single job's export: which job it is, its folder's name (a vary run's variant:
    ``v0007``), with the file's stem when that is not ``job`` (``drive-night``); characters other than letters,
    digits, ``_`` and ``-`` become ``_`` (the name is in every file name), at most ``MAX_NAME`` of them."""
    folder = os.path.basename(os.path.dirname(os.path.abspath(job_path)))
    stem = os.path.splitext(os.path.basename(job_path))[0]
    name = "-".join(p for p in (folder, "" if stem == "job" else stem) if p)
    return NAME_CHARS.sub("_", name)[:MAX_NAME] or "scpainter"


def job_description(job_path: str) -> str:
    """A scene's ``description``: the job as ``<folder>/<file>``, never its absolute path (a dataset is shared)."""
    return "job " + "/".join(os.path.abspath(job_path).split(os.sep)[-2:])


def job_identity(job_path: str) -> str:
    """A job's identity, the seed of its tokens (``Clip.identity``): 32 hex digits of the SHA-256 of its resolved
    path and its file's content: stable over exports of the same job, different for two jobs (a vary run's
    variants differ in content, copies of one job in path)."""
    real = os.path.realpath(job_path)
    with files.open_regular(real) as f:
        content = hashlib.sha256(f.read()).hexdigest()
    return hashlib.sha256(f"{real}\n{content}".encode("utf-8")).hexdigest()[:32]


def job_clip(job, root: str, name: str, description: str = "", identity: str = "") -> tuple:
    """(clip, images, why) of a rendered job whose output folder is ``root``: a rig job's ``folder_clip``, a
    single-camera job's ``clip_of_frames`` (``identity``: the job's, ``job_identity``); images "generated" when
    every camera has a finished generation, else "conditions" and why (``command.image_source``)."""
    from . import command

    frames = [e.frame for e in job.frames]
    if getattr(job, "rig", None) is not None:
        ego = np.stack([np.asarray(e.ego_to_world, np.float64) for e in job.frames])
        clip, images = folder_clip(root, job.rig, frames, ego, name, description, identity)
        lacking = [c.name for c, source in zip(clip.cameras, images) if source == "conditions"]
        return (clip, "conditions", f"no finished generation of {', '.join(lacking)}") if lacking else \
            (clip, "generated", "")
    layout = OutputLayout(root)
    images, why = command.image_source(layout, job)
    read = [command.read_frame(layout, f, images, False) for f in frames]
    return clip_of_frames(read, name, description, identity), images, why


def warn(clip: Clip, keyframe_hz: float) -> None:
    """The warning events of a clip: no LiDAR (every box num_lidar_pts 0), a single keyframe, channels other than
    nuScenes' six cameras (``rig.NUSCENES_CAMERAS``) and LIDAR_TOP, said with the channels missing and unknown."""
    channels = [c.name for c in clip.cameras]
    missing = [c for c in rig_mod.NUSCENES_CAMERAS if c not in channels]
    unknown = [c for c in channels if c not in rig_mod.NUSCENES_CAMERAS]
    if clip.lidar is not None and clip.lidar.name != rig_mod.NUSCENES_LIDAR:
        unknown.append(clip.lidar.name)
    if missing or unknown:
        said = "; ".join(p for p in (f"missing {', '.join(missing)}" if missing else "",
                                     f"not nuScenes' {', '.join(unknown)}" if unknown else "") if p)
        events.warning(f"{clip.name}: not nuScenes' six cameras and {rig_mod.NUSCENES_LIDAR} ({said}): the devkit "
                       "loads it, but mmdetection3d's nuScenes converter reads every sample's six camera channels "
                       f"and {rig_mod.NUSCENES_LIDAR} by name and stops with a KeyError (use the rig preset "
                       "nuscenes, or rename the channels)", NOT_SIX_CAMERAS, missing=missing, unknown=unknown)
    if clip.lidar is None:
        events.warning(f"{clip.name}: no LIDAR_TOP (a single-camera job, or a rig without a LiDAR): every box has "
                       "num_lidar_pts 0, so the devkit's filter_eval_boxes and mmdetection3d's valid_flag drop them "
                       "all (render a rig with a LiDAR for training data)", NO_LIDAR)
    from .nuscenes_tables import keyframes

    if len(keyframes(clip.times_s, keyframe_hz)) < 2:
        events.warning(f"{clip.name}: {len(clip.frames)} frames over {clip.times_s[-1]:.2f} s give one keyframe at "
                       f"{keyframe_hz:g} Hz: no velocities (raise --keyframe-hz or export a longer clip)",
                       ONE_KEYFRAME)


class Writer:
    """A dataroot being written into ``folder`` (existing, empty): ``add`` each clip (its files copied at once),
    then ``finish`` (the tables, maps and splits)."""

    def __init__(self, folder: str, version: str = DEFAULT_VERSION, keyframe_hz: float = DEFAULT_KEYFRAME_HZ) \
            -> None:
        opts = check_options(version, keyframe_hz)
        self.folder, self.version, self.keyframe_hz = folder, opts["version"], opts["keyframe_hz"]
        self.tables = Tables(self.keyframe_hz)
        self.splits: dict = {}
        self._copied = 0

    def add(self, clip: Clip, split: str = "train", progress: Callable[[int], None] | None = None) -> dict:
        """The clip's records and files; ``progress(i)`` after each frame's files. Returns its counts."""
        warn(clip, self.keyframe_hz)
        counts = self.tables.add(clip)
        self.splits.setdefault(split, []).append(clip.name)
        new = sorted(self.tables.files[self._copied:], key=lambda f: f[2])
        self._copied = len(self.tables.files)
        for k, (src, rel, i) in enumerate(new):
            dst = os.path.join(self.folder, *rel.split("/"))
            outputs.make_folder(os.path.dirname(dst))
            common.copy_image(src, dst)
            if progress and (k + 1 == len(new) or new[k + 1][2] != i):
                progress(i)
        return counts

    def finish(self) -> None:
        tables = os.path.join(self.folder, self.version)
        outputs.make_folder(tables)
        for name, rows in self.tables.records.items():
            with outputs.atomic_write(os.path.join(tables, f"{name}.json"), "w") as f:
                json.dump(rows, f, indent=0, allow_nan=False)
        with outputs.atomic_write(os.path.join(tables, SPLITS), "w") as f:
            json.dump(self.splits, f, indent=1)
        outputs.make_folder(os.path.join(self.folder, "maps"))
        for rel, raster in self.tables.maps:
            png.write_png(os.path.join(self.folder, *rel.split("/")), raster)


def write_clips(folder: str, clips: list, progress: Callable[[int], None] | None = None,
                version: str = DEFAULT_VERSION, keyframe_hz: float = DEFAULT_KEYFRAME_HZ) -> dict:
    """A dataroot of ``clips`` (all in split train) into ``folder`` (existing, empty). Returns {"frames",
    "objects", "ignore_regions", "samples", "inserted", "version", "keyframe_hz"}."""
    w = Writer(folder, version, keyframe_hz)
    total = {"frames": 0, "samples": 0, "objects": 0, "inserted": 0, "ignore_regions": 0}
    done = 0
    for clip in clips:
        counts = w.add(clip, progress=(lambda i, d=done: progress(d + i)) if progress else None)
        done += len(clip.frames)
        total = {k: total[k] + counts[k] for k in total}
    w.finish()
    return {**total, "version": w.version, "keyframe_hz": w.keyframe_hz}


def write(folder: str, frames: list, progress: Callable[[int], None] | None = None,
          version: str = DEFAULT_VERSION, keyframe_hz: float = DEFAULT_KEYFRAME_HZ) -> dict:
    """A single-camera job's ``frames`` (``common.ExportFrame``, in order) as a dataroot (``clip_of_frames``:
    CAM_FRONT, no LiDAR, with its warning) into ``folder`` (existing, empty)."""
    return write_clips(folder, [clip_of_frames(frames, "scpainter-0000")], progress, version, keyframe_hz)
