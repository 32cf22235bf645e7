"""KITTI object format (the KITTI object benchmark's devkit ``readme.txt``; written as its ``writeLabels.m`` does):

    image_2/NNNNNN.png    the frame's image, NNNNNN sequential from 000000 in the job's frame order
    label_2/NNNNNN.txt    one line per object that shows (visible pixels, not removed):
                          type truncated occluded alpha left top right bottom h w l x y z rotation_y
    calib/NNNNNN.txt      P0..P3, R0_rect, Tr_velo_to_cam, Tr_imu_to_velo ("key: values", %.12e)
    frames.json           KITTI index -> scene frame and timestamp (``FRAMES``)

Conventions (the devkit's): camera x right, y down, z forward, metres. ``type``: the class, first letter
upper-cased (``Car``). ``truncated`` 0..1 and ``occluded`` 0..3 are the labels' ``truncation``/``occlusion``.
The 2D box is the labels' ``bbox_amodal`` (the projected 3D box, clipped) in 0-based pixel coordinates (pixel
centres at integers: ours − 0.5, ``common.opencv_K``), clipped to [0, W−1] x [0, H−1] as KITTI's own boxes are.
``dimensions`` are height, width, length; ``location`` is the box's **bottom** centre in camera coordinates (the
centre moved half the height along the object's down axis: the devkit builds the box upwards from it, y corners
0 .. −h); ``rotation_y`` is the labels' ``box_camera.yaw`` (the length axis along (cos ry, 0, −sin ry)).
``alpha``, the observation angle, is ``rotation_y − atan2(x, z)`` of the object's location, wrapped to [−π, π)
— the relation OpenPCDet writes KITTI results with (``pcdet/datasets/kitti/kitti_dataset.py``,
``generate_prediction_dicts``: ``alpha = -arctan2(-y_lidar, x_lidar) + ry``, where x_lidar = z and y_lidar = −x)
and mmdetection3d's ``yaw2alpha`` (``alpha = rot_y − atan2(center_x, center_z)``). ``P0``..``P3`` are all
K [I | 0] (one camera: no stereo baseline), ``R0_rect`` the identity; there is no lidar or IMU, so
``Tr_velo_to_cam`` and ``Tr_imu_to_velo`` are the identity [I | 0], written only because readers expect the keys.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from . import common

IMAGES, LABELS, CALIB, FRAMES = "image_2", "label_2", "calib", "frames.json"
#: Whether ``write`` reads the frames' instance layers (``command.FORMATS``).
NEEDS_INSTANCE = False


def alpha(rotation_y: float, x: float, z: float) -> float:
    """KITTI's observation angle of an object at camera coordinates (x, ·, z) with ``rotation_y`` (see the module's
    docstring for the sources), in [−π, π)."""
    a = rotation_y - math.atan2(x, z)
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def bottom_centre(box_camera: dict) -> np.ndarray:
    """The centre of a box's bottom face in camera coordinates: the centre minus half the height along the object's
    up axis (``box_camera.quaternion``, object frame x forward, y left, z up)."""
    from scpainter_blender.core.geometry import cameras

    R = cameras.quaternion_to_rotation(np.asarray(box_camera["quaternion"], np.float64)).reshape(3, 3)
    return np.asarray(box_camera["center"], np.float64) - R[:, 2] * box_camera["size"][2] / 2.0


def label_line(obj: dict, width: int, height: int) -> str:
    """One object's line of ``label_2`` (``obj``: an object of ``core.labels``)."""
    cam = obj["box_camera"]
    x, y, z = bottom_centre(cam)
    ry = float(cam["yaw"])
    l, w, h = cam["size"]
    box = obj["bbox_amodal"] or obj["bbox_visible"]
    x0, y0, x1, y1 = (np.asarray(box, np.float64) - common.OPENCV_SHIFT).clip(0.0, [width - 1, height - 1] * 2)
    return (f"{common.class_name(obj['class'])} {obj['truncation']:.2f} {int(obj['occlusion'])} "
            f"{alpha(ry, x, z):.2f} {x0:.2f} {y0:.2f} {x1:.2f} {y1:.2f} {h:.2f} {w:.2f} {l:.2f} "
            f"{x:.2f} {y:.2f} {z:.2f} {ry:.2f}")


def calib_text(K) -> str:
    """A ``calib`` file for a camera with our intrinsics ``K`` (3, 3): the devkit's keys, %.12e values."""
    P = np.hstack([common.opencv_K(K), np.zeros((3, 1))])
    eye34 = np.hstack([np.eye(3), np.zeros((3, 1))])

    def row(key, m):
        return f"{key}: " + " ".join(f"{v:.12e}" for v in np.asarray(m, np.float64).ravel())

    rows = [row(f"P{i}", P) for i in range(4)]
    rows += [row("R0_rect", np.eye(3)), row("Tr_velo_to_cam", eye34), row("Tr_imu_to_velo", eye34)]
    return "\n".join(rows) + "\n"


def write(folder: str, frames: list, progress=None) -> dict:
    """The dataset into ``folder`` (existing, empty) from ``frames`` (``common.ExportFrame``, in order);
    ``progress(i)`` after each frame. Returns {"frames", "objects"} (objects: label lines)."""
    for sub in (IMAGES, LABELS, CALIB):
        os.makedirs(os.path.join(folder, sub))
    index, objects = [], 0
    for i, fr in enumerate(frames):
        lab = fr.labels
        W, H = lab["image_size"]
        common.copy_image(fr.image, os.path.join(folder, IMAGES, common.index_name(i, ".png")))
        lines = [label_line(o, W, H) for o in lab["objects"] if common.exported(o, hidden=True)]
        objects += len(lines)
        with open(os.path.join(folder, LABELS, common.index_name(i, ".txt")), "w", encoding="utf-8") as f:
            f.write("".join(line + "\n" for line in lines))
        with open(os.path.join(folder, CALIB, common.index_name(i, ".txt")), "w", encoding="utf-8") as f:
            f.write(calib_text(lab["camera"]["K"]))
        index.append({"index": common.index_name(i, ""), "frame": lab["frame"], "timestamp_s": lab["timestamp_s"],
                      **common.frame_quality(lab)})
        if progress:
            progress(i)
    with open(os.path.join(folder, FRAMES), "w", encoding="utf-8") as f:
        json.dump({"frames": index}, f, indent=1)
    return {"frames": len(frames), "objects": objects}
