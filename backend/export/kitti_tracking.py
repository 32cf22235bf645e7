"""KITTI tracking format (the KITTI tracking benchmark's devkit ``readme.txt``): the job's frames as one sequence,
``0000``, its objects with their track ids across frames.

    image_02/0000/NNNNNN.png  the frames' images, NNNNNN sequential from 000000 in the job's frame order
    label_02/0000.txt         one line per object and frame, sorted by frame:
                              frame track_id type truncated occluded alpha left top right bottom h w l x y z ry
    calib/0000.txt            the sequence's calibration: P0..P3, R_rect, Tr_velo_cam, Tr_imu_velo (the tracking
                              devkit's keys, the last three without a colon; ``kitti.calib_text``)
    pose/0000.txt             one row per frame: the 12 numbers (row-major 3x4) of the frame's label frame to world
    velodyne/0000/NNNNNN.bin  only for a camera of a rig job with a LiDAR: each frame's sweep (``kitti``'s rows and
                              velodyne frame); ``Tr_velo_cam`` is the first frame's velodyne frame to its label
                              frame, which holds for every frame: the LiDAR and the camera are fixed to one rig, so
                              frame i's returns in its velodyne frame (the first frame's axes relative to the
                              sensor) map by it into L_i
    frames.json               KITTI frame -> scene frame, timestamp, the frame's quality (``kitti.FRAMES``)

Each line is ``kitti``'s object label (the same columns, conventions and 4-decimal 3D values, the same rules for
which objects are labelled; ignore regions are ``DontCare`` lines) preceded by the frame index and the track id:
the labels' ``track_id`` (stable across frames: an inserted car's instance id, a recorded object's place after
them); ``DontCare`` lines have track id −1, as in KITTI's own files.

**One calibration for the sequence, so the first frame's tilt.** The tracking devkit has one ``calib`` per
sequence; its ``P2`` = K [R | 0] carries the tilt of the first frame's camera (``kitti.level_rotation``: R turns
that frame's level frame into its camera frame). The labels of frame i are in the frame *L_i*: camera i turned by
that same R (X_camera_i = R · X_L_i), so ``P2`` projects every frame's labels exactly onto its image. L_i is level
(y = world down, boxes upright with yaw only) whenever camera i has the first frame's pitch and roll — a camera
path that keeps its tilt, as every rendered path of a level drive does; a camera that pitches during the sequence
makes the later frames' boxes tilt by the difference (``tilt_change_deg`` in ``frames.json`` says how much).

``pose/0000.txt``: row i is L_i-to-world, the 3x4 [R | t] (row-major, %.12e) with X_world = R · X_L_i + t, world
the job's (z up, metres): the frame's camera_to_world turned by R (KITTI odometry's poses file layout, here in
our world rather than relative to the first camera).
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from scpainter_blender.core import outputs

from . import common, kitti

IMAGES, LABELS, CALIB, POSES = "image_02", "label_02", "calib", "pose"
#: The one sequence this export writes.
SEQUENCE = "0000"
#: Whether ``write`` reads the frames' instance layers (``command.FORMATS``).
NEEDS_INSTANCE = False


def label_frame_to_world(camera_to_world, level_to_camera) -> np.ndarray:
    """(4, 4) the label frame L (X_camera = ``level_to_camera`` · X_L) to world, of a camera_to_world (4, 4)."""
    return kitti.level_to_world(camera_to_world, level_to_camera)


def tilt_change_deg(world_to_camera, level_to_camera) -> float:
    """How far (degrees) the label frame's y axis lies from world down for a camera ``world_to_camera`` whose
    labels use ``level_to_camera``: 0 when the camera has the tilt the calibration carries."""
    down_in_camera = np.asarray(world_to_camera, np.float64)[:3, :3] @ [0.0, 0.0, -1.0]
    y_in_camera = np.asarray(level_to_camera, np.float64)[:, 1]
    return math.degrees(math.acos(float(np.clip(down_in_camera @ y_in_camera, -1.0, 1.0))))


def _matrix_row(m) -> str:
    return " ".join(f"{v:.12e}" for v in np.asarray(m, np.float64)[:3, :4].ravel())


def write(folder: str, frames: list, progress=None) -> dict:
    """The sequence into ``folder`` (existing, empty) from ``frames`` (``common.ExportFrame``, in order);
    ``progress(i)`` after each frame. Returns {"frames", "objects", "ignore_regions"} (label lines, DontCare
    lines)."""
    lidar = frames[0].sweep is not None
    for sub in (os.path.join(IMAGES, SEQUENCE), LABELS, CALIB, POSES) + \
            ((os.path.join(kitti.VELODYNE, SEQUENCE),) if lidar else ()):
        outputs.make_folder(os.path.join(folder, sub))
    first = frames[0].labels["camera"]
    R = kitti.level_rotation(first["world_to_camera"])
    velo = axes = None
    if lidar:   # the rig's LiDAR is fixed to its camera: the first frame's Tr_velo_cam holds for every frame
        level = label_frame_to_world(first["camera_to_world"], R)
        axes = kitti.velodyne_to_sensor(frames[0].sweep.lidar_to_world, level)
        velo = kitti.velo_to_level(frames[0].sweep.lidar_to_world, level, axes)
    lines, poses, index, objects, regions = [], [], [], 0, 0
    for i, fr in enumerate(frames):
        lab = fr.labels
        common.copy_image(fr.image, os.path.join(folder, IMAGES, SEQUENCE, common.index_name(i, ".png")))
        if lidar:
            kitti.write_velodyne(os.path.join(folder, kitti.VELODYNE, SEQUENCE, common.index_name(i, ".bin")),
                                 kitti.velodyne_rows(fr.sweep, axes))
        for track, columns in kitti.frame_lines(lab, R):
            lines.append(f"{i} {track} {columns}")
            regions += track == -1
            objects += track != -1
        poses.append(_matrix_row(label_frame_to_world(lab["camera"]["camera_to_world"], R)))
        index.append({"index": i, "frame": lab["frame"], "timestamp_s": lab["timestamp_s"],
                      "tilt_change_deg": round(tilt_change_deg(lab["camera"]["world_to_camera"], R), 6),
                      **common.frame_quality(lab)})
        if progress:
            progress(i)
    for sub, text in ((LABELS, "".join(line + "\n" for line in lines)),
                      (CALIB, kitti.calib_text(first["K"], R, kitti.TRACKING_KEYS, velo)),
                      (POSES, "".join(row + "\n" for row in poses))):
        with outputs.atomic_write(os.path.join(folder, sub, SEQUENCE + ".txt"), "w") as f:
            f.write(text)
    with outputs.atomic_write(os.path.join(folder, kitti.FRAMES), "w") as f:
        json.dump({"sequence": SEQUENCE, "frames": index}, f, indent=1)
    return {"frames": len(frames), "objects": int(objects), "ignore_regions": int(regions)}
