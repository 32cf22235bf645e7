"""KITTI object format (the KITTI object benchmark's devkit ``readme.txt``; written as its ``writeLabels.m`` does):

    image_2/NNNNNN.png    the frame's image, NNNNNN sequential from 000000 in the job's frame order
    label_2/NNNNNN.txt    one line per object exported as a label (in view, not removed, not ignored; hidden
                          ones included, marked occluded 2 or 3) and a DontCare line per ignore region:
                          type truncated occluded alpha left top right bottom h w l x y z rotation_y
    calib/NNNNNN.txt      P0..P3, R0_rect, Tr_velo_to_cam, Tr_imu_to_velo ("key: values", %.12e), in that order
                          (OpenPCDet's ``get_calib_from_file`` reads P2, P3, R0, Tr_velo_to_cam by line: 2..5)
    velodyne/NNNNNN.bin   only for a camera of a rig job with a LiDAR: the frame's sweep (see below)
    frames.json           KITTI index -> scene frame, timestamp, the frame's quality (``FRAMES``) and per label
                          line what the devkit's columns cannot hold (``line_extras``: track id, hole_fraction …)

**The level frame.** KITTI boxes have one angle, ``rotation_y`` about the camera's y axis, so they are upright only
in a camera frame whose y axis is gravity's. Labels are therefore given in the frame's *level camera*
(``level_rotation``): the camera's frame turned about its centre so that its y axis is world down (−z) and its z
axis the camera's heading (its optical axis laid flat), x = y × z to the right; the origin is the camera's centre.
Boxes (upright in the world) are upright there with yaw only, for any camera pitch and roll. **``P2`` carries the
tilt**: ``P2`` = K [R | 0], R the level-to-camera rotation and K our intrinsics in KITTI's pixel convention
(pixel centres at integers, the principal point ours − 0.5: ``common.opencv_K``), so ``P2 · [x y z 1]`` of a point
of the level frame is its pixel in the image; ``R0_rect`` is the identity. That is what KITTI loaders read:
OpenPCDet (``pcdet/utils/calibration_kitti.py``) projects labels with ``rect_to_img`` = P2 alone and uses R0 and
Tr_velo2cam only for LiDAR points; mmdetection3d keeps P2 as ``cam2img`` (KITTI mono3d projects boxes with it) and
R0_rect · Tr_velo_to_cam as ``lidar2cam``; the devkit's ``computeBox3D``/``projectToImage`` use P2. ``P0``..``P3``
are all that one P2 (one camera: no stereo baseline); a single camera has no lidar or IMU, so ``Tr_velo_to_cam`` and
``Tr_imu_to_velo`` are the identity [I | 0] (the "lidar" frame is the level frame), written because readers
expect the keys.

**A rig job's camera with the rig's LiDAR** (``common.ExportFrame.sweep``, docs/design.md §17) adds
``velodyne/NNNNNN.bin``: the frame's sweep as KITTI's rows of 4 little-endian float32 (x, y, z, reflectance =
intensity / 255) in the export's *velodyne frame*, and its ``calib`` carries ``Tr_velo_to_cam`` = that frame to
the level frame (``R0_rect`` stays I), so ``P2 · [Tr_velo_to_cam · X]`` is a return's pixel (OpenPCDet's
``lidar_to_rect`` then ``rect_to_img``; mmdetection3d's ``lidar2cam`` = R0_rect · Tr_velo_to_cam). The velodyne
frame is KITTI's axes (x forward, y left, z up) at the LiDAR: origin the sensor's, z the sensor's up, x **the
camera's heading** laid in the sensor's horizontal plane (``velodyne_to_sensor``), so for a camera looking forward
it is the sensor's own frame (x = its y, y = −its x), and for any other camera of the rig the returns the camera
sees lie at x > 0 as KITTI's loaders assume (OpenPCDet's KITTI point cloud range starts at x = 0; its
``boxes3d_kitti_camera_to_lidar`` turns a label's ``rotation_y`` into the lidar heading −(π/2 + ry), exact only
when the velodyne x is the level camera's z). A spinning LiDAR's sweep turned about its axis is the same sweep.

Columns (the devkit's; level frame: x right, y down, z forward, metres). ``type``: the class's KITTI type from the
fixed table (``core.categories``: ``Car``, ``Van``, ``Misc`` …). ``truncated`` 0..1 and ``occluded`` 0..3 are the
labels' ``truncation``/``occlusion``. The 2D box is the labels' ``bbox_amodal`` (the projected 3D box, clipped) in
0-based pixel coordinates (ours − 0.5), clipped to [0, W−1] x [0, H−1] as KITTI's own boxes are. ``dimensions``
are height, width, length; ``location`` is the box's **bottom** centre in the level frame (the centre moved half
the height along the object's down axis: the devkit builds the box upwards from it, y corners 0 .. −h);
``rotation_y`` turns the level frame's x axis onto the object's forward axis about y (the length axis along
(cos ry, 0, −sin ry)). ``alpha``, the observation angle, is ``rotation_y − atan2(x, z)`` of the location, wrapped
to [−π, π) — the relation OpenPCDet writes KITTI results with (``pcdet/datasets/kitti/kitti_dataset.py``,
``generate_prediction_dicts``: ``alpha = -arctan2(-y_lidar, x_lidar) + ry``, where x_lidar = z and y_lidar = −x)
and mmdetection3d's ``yaw2alpha`` (``alpha = rot_y − atan2(center_x, center_z)``). 3D values and angles are
written with 4 decimals (0.1 mm: KITTI's own files have 2; every reader parses floats), 2D boxes with 2.
An ignore region (``core.labels.ignore_region``) is a ``DontCare`` line with its 2D box and the devkit's
placeholders: ``DontCare -1 -1 -10 x0 y0 x1 y1 -1 -1 -1 -1000 -1000 -1000 -10``.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from scpainter_blender.core import errors, outputs
from scpainter_blender.core.geometry import cameras

from . import common

IMAGES, LABELS, CALIB, FRAMES = "image_2", "label_2", "calib", "frames.json"
#: The folder of a rig job's camera export's LiDAR sweeps (KITTI's ``velodyne/NNNNNN.bin``).
VELODYNE = "velodyne"
#: Values per row of a KITTI velodyne file: x, y, z, reflectance.
VELODYNE_COLUMNS = 4
#: Reflectance = a return's intensity (``backend.lidar.sweep``: 0..255) / this, KITTI's 0..1.
INTENSITY_SCALE = 255.0
#: Whether ``write`` reads the frames' instance layers (``command.FORMATS``).
NEEDS_INSTANCE = False


def alpha(rotation_y: float, x: float, z: float) -> float:
    """KITTI's observation angle of an object at camera coordinates (x, ·, z) with ``rotation_y`` (see the module's
    docstring for the sources), in [−π, π)."""
    a = rotation_y - math.atan2(x, z)
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def level_rotation(world_to_camera) -> np.ndarray:
    """(3, 3) rotation from the level camera frame (see the module's docstring) to the camera frame of a
    world_to_camera (4, 4; OpenCV axes, world z up): R with X_camera = R · X_level. A camera looking straight down
    or up takes its image's up direction (−y) as its heading."""
    R_wc = np.asarray(world_to_camera, np.float64)[:3, :3]
    c2w = R_wc.T
    down = np.array([0.0, 0.0, -1.0])
    heading = c2w[:, 2] * [1.0, 1.0, 0.0]
    if np.linalg.norm(heading) < 1e-9:
        heading = -c2w[:, 1] * [1.0, 1.0, 0.0]
    heading /= np.linalg.norm(heading)
    level_to_world = np.column_stack([np.cross(down, heading), down, heading])
    return R_wc @ level_to_world


def level_box(box_camera: dict, level_to_camera) -> tuple:
    """(bottom centre (3,), rotation_y) of a labels ``box_camera`` (object frame x forward, y left, z up) in the
    level frame whose rotation to the camera is ``level_to_camera`` (3, 3): the centre less half the height along
    the object's up axis, and the angle about y from the level x axis to the object's forward axis."""
    R = np.asarray(level_to_camera, np.float64).T @ cameras.quaternion_to_rotation(
        np.asarray(box_camera["quaternion"], np.float64)).reshape(3, 3)
    centre = np.asarray(level_to_camera, np.float64).T @ np.asarray(box_camera["center"], np.float64)
    forward = R[:, 0]
    return centre - R[:, 2] * box_camera["size"][2] / 2.0, math.atan2(-forward[2], forward[0])


def box2d(box: list, width: int, height: int) -> np.ndarray:
    """Our [x0, y0, x1, y1] as KITTI's 2D box: 0-based pixel coordinates, clipped to the image."""
    return (np.asarray(box, np.float64) - common.OPENCV_SHIFT).clip(0.0, [width - 1, height - 1] * 2)


def label_fields(obj: dict, kitti_type: str, width: int, height: int, level_to_camera) -> str:
    """The 15 columns of one object's label (``obj``: an object of ``core.labels``; ``kitti_type`` its class's
    KITTI type) in the level frame of ``level_to_camera``."""
    (x, y, z), ry = level_box(obj["box_camera"], level_to_camera)
    l, w, h = obj["box_camera"]["size"]
    x0, y0, x1, y1 = box2d(obj["bbox_amodal"] or obj["bbox_visible"], width, height)
    return (f"{kitti_type} {obj['truncation']:.2f} {int(obj['occlusion'])} "
            f"{alpha(ry, x, z):.4f} {x0:.2f} {y0:.2f} {x1:.2f} {y1:.2f} {h:.4f} {w:.4f} {l:.4f} "
            f"{x:.4f} {y:.4f} {z:.4f} {ry:.4f}")


def dontcare_fields(region: list, width: int, height: int) -> str:
    """The 15 columns of an ignore region's ``DontCare`` line (the devkit's placeholders, its 2D box)."""
    x0, y0, x1, y1 = box2d(region, width, height)
    return f"DontCare -1 -1 -10 {x0:.2f} {y0:.2f} {x1:.2f} {y1:.2f} -1 -1 -1 -1000 -1000 -1000 -10"


def line_extras(lab: dict) -> list:
    """What each line of ``frame_lines`` (same order) carries beside the devkit's columns, for ``frames.json``:
    a label's ``common.carried`` fields (track id, synthetic, hole_fraction, occlusion …), an ignore region's track
    id and why (``ignore`` or ``points_missing``)."""
    out = [common.carried(o) for o in lab["objects"] if common.exported(o, hidden=True)]
    out += [{"track_id": int(o["track_id"]), "dontcare": "ignore" if o["ignore"] else "points_missing"}
            for o, _ in common.ignore_regions(lab)]
    return out


def frame_lines(lab: dict, level_to_camera) -> list:
    """(track_id, columns) of each line of a frame's labels (``core.labels``): the objects exported as labels,
    then the ignore regions (track id −1)."""
    W, H = lab["image_size"]
    out = [(int(o["track_id"]), label_fields(o, common.category(lab, k).kitti, W, H, level_to_camera))
           for k, o in enumerate(lab["objects"]) if common.exported(o, hidden=True)]
    out += [(-1, dontcare_fields(region, W, H)) for _, region in common.ignore_regions(lab)]
    return out


#: The calibration's last three keys: the object devkit's, and the tracking devkit's (written without a colon in
#: its files: ``R_rect 9.99e-01 …``).
OBJECT_KEYS = ("R0_rect:", "Tr_velo_to_cam:", "Tr_imu_to_velo:")
TRACKING_KEYS = ("R_rect", "Tr_velo_cam", "Tr_imu_velo")


def calib_text(K, level_to_camera=None, keys: tuple = OBJECT_KEYS, velo_to_cam=None) -> str:
    """A ``calib`` file for a camera with our intrinsics ``K`` (3, 3) whose labels are in the level frame of
    ``level_to_camera`` (3, 3; None: the identity, a level camera): P0..P3 (all ``P2``), then the rectification
    (the identity), velo-to-camera (``velo_to_cam`` (3, 4), ``velo_to_level``; None: the identity, no LiDAR) and
    imu-to-velo (the identity) matrices under ``keys``; %.12e values."""
    R = np.eye(3) if level_to_camera is None else np.asarray(level_to_camera, np.float64)
    P = np.hstack([common.opencv_K(K) @ R, np.zeros((3, 1))])
    eye34 = np.hstack([np.eye(3), np.zeros((3, 1))])
    velo = eye34 if velo_to_cam is None else np.asarray(velo_to_cam, np.float64)[:3, :4]

    def row(key, m):
        return f"{key} " + " ".join(f"{v:.12e}" for v in np.asarray(m, np.float64).ravel())

    rows = [row(f"P{i}:", P) for i in range(4)]
    rows += [row(key, m) for key, m in zip(keys, (np.eye(3), velo, eye34))]
    return "\n".join(rows) + "\n"


def level_to_world(camera_to_world, level_to_camera) -> np.ndarray:
    """(4, 4) the level frame (X_camera = ``level_to_camera`` · X_level) to world, of a camera_to_world (4, 4)."""
    R = np.eye(4)
    R[:3, :3] = level_to_camera
    return np.asarray(camera_to_world, np.float64) @ R


def velodyne_to_sensor(lidar_to_world, level_to_world_) -> np.ndarray:
    """(3, 3) rotation from the export's velodyne frame (see the module's docstring) to the LiDAR's sensor frame
    (x right, y forward, z up) of ``lidar_to_world`` (4, 4), for a camera whose level frame is ``level_to_world_``
    (4, 4): its columns are the velodyne axes in the sensor frame, x the level camera's heading (its z axis) laid in
    the sensor's x-y plane, z the sensor's z, y = z × x. A heading along the sensor's z (no rig does that) takes the
    sensor's forward (within 1e-6 rad of it the turn is noise: every frame would get another)."""
    heading = np.asarray(lidar_to_world, np.float64)[:3, :3].T @ np.asarray(level_to_world_, np.float64)[:3, 2]
    x = np.array([heading[0], heading[1], 0.0])
    if np.linalg.norm(x) < 1e-6:
        x = np.array([0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    z = np.array([0.0, 0.0, 1.0])
    return np.column_stack([x, np.cross(z, x), z])


def velo_to_level(lidar_to_world, level_to_world_, velodyne_to_sensor_) -> np.ndarray:
    """(3, 4) KITTI's ``Tr_velo_to_cam``: the velodyne frame (``velodyne_to_sensor_`` (3, 3) turns it into the
    sensor frame of ``lidar_to_world`` (4, 4)) to the level frame of ``level_to_world_`` (4, 4)."""
    V = np.eye(4)
    V[:3, :3] = velodyne_to_sensor_
    return (cameras.rigid_inverse(np.asarray(level_to_world_, np.float64))
            @ np.asarray(lidar_to_world, np.float64) @ V)[:3]


def velodyne_rows(sweep: common.ExportSweep, velodyne_to_sensor_) -> np.ndarray:
    """(R, 4) little-endian float32: the sweep's returns (its ``.pcd.bin``, ``backend.lidar.sweep.read_pcd_bin``)
    as KITTI's velodyne rows: x, y, z in the velodyne frame (``velodyne_to_sensor_`` (3, 3)), reflectance =
    intensity / ``INTENSITY_SCALE``. A missing sweep is an ``InputError`` naming it (render the rig job again)."""
    from backend.lidar import sweep as sweep_mod

    if not os.path.isfile(sweep.path):
        raise errors.InputError(sweep.path, "(file)", "the LiDAR's sweep of this frame is missing",
                                hint="render the rig job again: python -m backend render JOB")
    rows = sweep_mod.read_pcd_bin(sweep.path)
    xyz = rows[:, :3].astype(np.float64) @ np.asarray(velodyne_to_sensor_, np.float64)   # X_v = V^T X_s, per row
    return np.column_stack([xyz, rows[:, 3].astype(np.float64) / INTENSITY_SCALE]).astype("<f4")


def write_velodyne(path: str, rows) -> None:
    """KITTI velodyne rows (R, 4) float32 to ``path`` (no header: the raw little-endian floats), atomically."""
    data = np.ascontiguousarray(rows, "<f4").tobytes()
    with outputs.atomic_write(path, "wb") as f:
        f.write(data)


def write(folder: str, frames: list, progress=None) -> dict:
    """The dataset into ``folder`` (existing, empty) from ``frames`` (``common.ExportFrame``, in order);
    ``progress(i)`` after each frame. Returns {"frames", "objects", "ignore_regions"} (label lines, DontCare
    lines)."""
    for sub in (IMAGES, LABELS, CALIB) + ((VELODYNE,) if any(fr.sweep for fr in frames) else ()):
        outputs.make_folder(os.path.join(folder, sub))
    index, objects, regions = [], 0, 0
    for i, fr in enumerate(frames):
        lab = fr.labels
        R = level_rotation(lab["camera"]["world_to_camera"])
        velo = None
        if fr.sweep is not None:   # a rig camera's export: its LiDAR's sweep and where it lies
            level = level_to_world(lab["camera"]["camera_to_world"], R)
            axes = velodyne_to_sensor(fr.sweep.lidar_to_world, level)
            velo = velo_to_level(fr.sweep.lidar_to_world, level, axes)
            write_velodyne(os.path.join(folder, VELODYNE, common.index_name(i, ".bin")), velodyne_rows(fr.sweep, axes))
        common.copy_image(fr.image, os.path.join(folder, IMAGES, common.index_name(i, ".png")))
        lines = frame_lines(lab, R)
        regions += sum(track == -1 for track, _ in lines)
        objects += sum(track != -1 for track, _ in lines)
        with outputs.atomic_write(os.path.join(folder, LABELS, common.index_name(i, ".txt")), "w") as f:
            f.write("".join(line + "\n" for _, line in lines))
        with outputs.atomic_write(os.path.join(folder, CALIB, common.index_name(i, ".txt")), "w") as f:
            f.write(calib_text(lab["camera"]["K"], R, velo_to_cam=velo))
        index.append({"index": common.index_name(i, ""), "frame": lab["frame"], "timestamp_s": lab["timestamp_s"],
                      **common.frame_quality(lab), "lines": line_extras(lab)})
        if progress:
            progress(i)
    with outputs.atomic_write(os.path.join(folder, FRAMES), "w") as f:
        json.dump({"frames": index}, f, indent=1)
    return {"frames": len(frames), "objects": objects, "ignore_regions": regions}
