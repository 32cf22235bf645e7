"""A small synthetic drive for the recording readers' tests: level OpenCV cameras driving along +y (Z-up world,
metres) and two tracked objects (a still car, a walking pedestrian in the first two frames), written in each format
the readers take. Each test reads a file back and maps it through the same cameras: the boxes must come back."""

import json
import os

import numpy as np

from scpainter_blender.core.geometry import boxes, cameras

#: OpenCV camera axes in a Z-up world, looking along +y: x right, y down (−z), z forward (+y).
LEVEL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def yaw(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose(R, t):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def drive(num_frames=3):
    """{"camera_to_world": (F, 4, 4), "world_to_camera", "objects": [{"id", "class", "size", "boxes"}]} (world)."""
    c2w = np.stack([pose(yaw(0.02 * i) @ LEVEL, [0.1 * i, 2.0 * i, 1.6]) for i in range(num_frames)])
    car = {"id": "car-a", "class": "car", "size": np.array([1.8, 4.4, 1.5]),
           "boxes": {i: pose(yaw(0.1), [3.0, 10.0, 0.75]) for i in range(num_frames)}}
    walker = {"id": "ped-b", "class": "pedestrian", "size": np.array([0.6, 0.7, 1.8]),
              "boxes": {i: pose(yaw(1.2), [-2.0, 5.0 + i, 0.9]) for i in range(min(2, num_frames))}}
    return {"camera_to_world": c2w, "world_to_camera": cameras.rigid_inverse(c2w), "objects": [car, walker]}


def assert_same(objects, truth, frame_start=0, atol=1e-6, ids=None):
    """RecordedObjects ``objects`` hold ``truth``'s boxes (world) at scene frames ``frame_start + i``; ``ids``: the
    file's track id of each truth object, when not its own."""
    ids = ids or [t["id"] for t in truth]
    by_id = {o.id: o for o in objects}
    assert sorted(by_id) == sorted(ids)
    for t, tid in zip(truth, ids):
        o = by_id[tid]
        assert o.category == t["class"]
        np.testing.assert_allclose(o.size, t["size"], atol=atol)
        assert sorted(o.boxes) == [frame_start + f for f in sorted(t["boxes"])]
        for f, B in t["boxes"].items():
            np.testing.assert_allclose(o.boxes[frame_start + f], B, atol=atol)


# -- writers ---------------------------------------------------------------------------------------------------------

KITTI_TYPES = {"car": "Car", "pedestrian": "Pedestrian"}
#: image_02 sits this far from rectified camera 0 (metres, camera axes): KITTI's colour camera offset.
T2 = np.array([0.06, -0.001, 0.002])
K = np.array([[700.0, 0.0, 600.0], [0.0, 700.0, 180.0], [0.0, 0.0, 1.0]])


def kitti_line(frame, track, kitti_type, box_to_cam2, size):
    """A KITTI tracking line for a box in image_02's camera (upright in that camera)."""
    w, l, h = size
    R = box_to_cam2[:3, :3] @ boxes.OBJECT_TO_BOX
    bottom = box_to_cam2[:3, 3] + np.array([0.0, h / 2, 0.0]) - T2   # camera 2 -> rectified camera 0
    ry = boxes.rotation_y(R)
    return (f"{frame} {track} {kitti_type} 0 0 -10 100 100 200 200 {h:.9f} {w:.9f} {l:.9f} "
            f"{bottom[0]:.9f} {bottom[1]:.9f} {bottom[2]:.9f} {ry:.12f}")


def write_kitti(root, d, extra_lines=()):
    """``root/label_02/0000.txt`` and ``root/calib/0000.txt`` of drive ``d``; returns the label path."""
    os.makedirs(os.path.join(root, "label_02"), exist_ok=True)
    os.makedirs(os.path.join(root, "calib"), exist_ok=True)
    lines = []
    for f in range(len(d["world_to_camera"])):
        for k, o in enumerate(d["objects"]):
            if f in o["boxes"]:
                lines.append(kitti_line(f, k, KITTI_TYPES[o["class"]], d["world_to_camera"][f] @ o["boxes"][f],
                                        o["size"]))
        lines.append(f"{f} -1 DontCare -1 -1 -10 0 0 10 10 -1 -1 -1 -1000 -1000 -1000 -10")
    P0 = np.hstack([K, np.zeros((3, 1))])
    P2 = np.hstack([K, (K @ T2)[:, None]])
    calib = [f"P0: {' '.join(map(str, P0.ravel()))}", f"P1: {' '.join(map(str, P0.ravel()))}",
             f"P2: {' '.join(map(str, P2.ravel()))}", f"P3: {' '.join(map(str, P0.ravel()))}",
             "R_rect 1 0 0 0 1 0 0 0 1", "Tr_velo_cam 1 0 0 0 0 1 0 0 0 0 1 0"]
    with open(os.path.join(root, "calib", "0000.txt"), "w") as fh:
        fh.write("\n".join(calib) + "\n")
    path = os.path.join(root, "label_02", "0000.txt")
    with open(path, "w") as fh:
        fh.write("\n".join(lines + list(extra_lines)) + "\n")
    return path


NUSCENES_NAMES = {"car": "vehicle.car", "pedestrian": "human.pedestrian.adult"}
#: CAM_FRONT in the ego frame (x forward, y left, z up): OpenCV axes z -> x, x -> −y, y -> −z.
CAMERA_TO_EGO = pose(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), [1.7, 0.0, 1.5])


def _quat(R):
    return cameras.rotation_to_quaternion(R).tolist()


#: Extra camera channels ``write_nuscenes`` can add: channel -> camera_to_ego (CAM_BACK: looking backwards).
EXTRA_CAMERAS = {"CAM_BACK": pose(np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), [0.0, 0.0, 1.6])}


def write_nuscenes(folder, d, extra_category=None, extra_cameras=()):
    """The devkit's tables of drive ``d`` as one scene (plus another scene's sample, a LIDAR_TOP keyframe and a
    CAM_FRONT sweep that must be left out; ``extra_cameras``: channels of ``EXTRA_CAMERAS`` with a keyframe image
    per sample, 7 ms after CAM_FRONT's, at 800 x 450); returns the folder."""
    os.makedirs(folder, exist_ok=True)
    n = len(d["world_to_camera"])
    t = {name: [] for name in ("scene", "sample", "sample_data", "calibrated_sensor", "sensor", "ego_pose",
                               "sample_annotation", "instance", "category", "log")}
    t["sensor"] = [{"token": "s-cam", "channel": "CAM_FRONT", "modality": "camera"},
                   {"token": "s-lidar", "channel": "LIDAR_TOP", "modality": "lidar"}]
    t["calibrated_sensor"] = [
        {"token": "cs-cam", "sensor_token": "s-cam", "translation": CAMERA_TO_EGO[:3, 3].tolist(),
         "rotation": _quat(CAMERA_TO_EGO[:3, :3]), "camera_intrinsic": K.tolist()},
        {"token": "cs-lidar", "sensor_token": "s-lidar", "translation": [0, 0, 1.8], "rotation": [1, 0, 0, 0],
         "camera_intrinsic": []}]
    names = dict(NUSCENES_NAMES)
    t["category"] = [{"token": f"cat-{c}", "name": name, "description": ""} for c, name in names.items()]
    if extra_category:
        t["category"].append({"token": "cat-extra", "name": extra_category, "description": ""})
    samples = [f"sample-{i}" for i in range(n)]
    t["scene"] = [{"token": "scene-1", "log_token": "log-1", "nbr_samples": n, "first_sample_token": samples[0],
                   "last_sample_token": samples[-1], "name": "scene-0001", "description": ""},
                  {"token": "scene-2", "log_token": "log-1", "nbr_samples": 1, "first_sample_token": "other",
                   "last_sample_token": "other", "name": "scene-0002", "description": ""}]
    t["sample"] = [{"token": s, "timestamp": 1_000_000 + 500_000 * i, "scene_token": "scene-1",
                    "prev": samples[i - 1] if i else "", "next": samples[i + 1] if i + 1 < n else ""}
                   for i, s in enumerate(samples)]
    t["sample"].append({"token": "other", "timestamp": 9, "scene_token": "scene-2", "prev": "", "next": ""})
    for i in range(n):
        ego = d["camera_to_world"][i] @ cameras.rigid_inverse(CAMERA_TO_EGO)
        t["ego_pose"].append({"token": f"ego-{i}", "translation": ego[:3, 3].tolist(), "rotation": _quat(ego[:3, :3]),
                              "timestamp": 0})
        for token, cs, key in ((f"sd-cam-{i}", "cs-cam", True), (f"sd-lidar-{i}", "cs-lidar", True),
                               (f"sd-sweep-{i}", "cs-cam", False)):
            t["sample_data"].append({"token": token, "sample_token": samples[i], "ego_pose_token": f"ego-{i}",
                                     "calibrated_sensor_token": cs, "timestamp": 1_000_000 + 500_000 * i + 5 * key,
                                     "fileformat": "jpg",
                                     "is_key_frame": key, "height": 900, "width": 1600,
                                     "filename": f"samples/CAM_FRONT/{token}.jpg", "prev": "", "next": ""})
    for k, ch in enumerate(extra_cameras):
        T = EXTRA_CAMERAS[ch]
        t["sensor"].append({"token": f"s-{ch}", "channel": ch, "modality": "camera"})
        t["calibrated_sensor"].append({"token": f"cs-{ch}", "sensor_token": f"s-{ch}",
                                       "translation": T[:3, 3].tolist(), "rotation": _quat(T[:3, :3]),
                                       "camera_intrinsic": K.tolist()})
        for i in range(n):
            t["sample_data"].append({"token": f"sd-{ch}-{i}", "sample_token": samples[i], "ego_pose_token": f"ego-{i}",
                                     "calibrated_sensor_token": f"cs-{ch}", "timestamp": 1_000_000 + 500_000 * i + 7_000,
                                     "fileformat": "jpg", "is_key_frame": True, "height": 450, "width": 800,
                                     "filename": f"samples/{ch}/{i}.jpg", "prev": "", "next": ""})
    for k, o in enumerate(d["objects"]):
        t["instance"].append({"token": o["id"], "category_token": f"cat-{o['class']}",
                              "nbr_annotations": len(o["boxes"])})
        for f, B in o["boxes"].items():
            t["sample_annotation"].append({
                "token": f"ann-{k}-{f}", "sample_token": samples[f], "instance_token": o["id"],
                "translation": B[:3, 3].tolist(), "size": list(map(float, o["size"])),
                "rotation": _quat(B[:3, :3] @ boxes.OBJECT_TO_BOX), "num_lidar_pts": 3, "num_radar_pts": 0,
                "attribute_tokens": [], "visibility_token": "4", "prev": "", "next": ""})
    for name, rows in t.items():
        with open(os.path.join(folder, f"{name}.json"), "w") as fh:
            json.dump(rows, fh)
    return folder


def openlabel_document(d, static_car=True):
    """OpenLABEL of drive ``d`` as our export writes it: ``odom`` (root) and ``camera`` (child; per-frame
    ``camera_to_odom`` transforms), cuboids in ``odom``; the car's cuboid static when ``static_car``."""
    n = len(d["world_to_camera"])

    def val(B, size):
        w, x, y, z = cameras.rotation_to_quaternion(B[:3, :3] @ boxes.OBJECT_TO_BOX)
        return [*B[:3, 3].tolist(), x, y, z, w, float(size[1]), float(size[0]), float(size[2])]

    objects, frames = {}, {str(i): {"objects": {}, "frame_properties": {"transforms": {"camera_to_odom": {
        "src": "camera", "dst": "odom",
        "transform_src_to_dst": {"matrix4x4": d["camera_to_world"][i].ravel().tolist()}}}}} for i in range(n)}
    for k, o in enumerate(d["objects"]):
        uid = str(k)
        objects[uid] = {"name": o["id"], "type": o["class"],
                        "frame_intervals": [{"frame_start": min(o["boxes"]), "frame_end": max(o["boxes"])}]}
        if static_car and o["class"] == "car":
            objects[uid]["object_data"] = {"cuboid": [{"name": "box3d", "val": val(o["boxes"][0], o["size"]),
                                                       "coordinate_system": "odom"}]}
            continue
        for f, B in o["boxes"].items():
            frames[str(f)]["objects"][uid] = {"object_data": {"cuboid": [
                {"name": "box3d", "val": val(B, o["size"]), "coordinate_system": "odom"}]}}
    return {"openlabel": {
        "metadata": {"schema_version": "1.0.0"},
        "coordinate_systems": {"odom": {"type": "scene_cs", "parent": "", "children": ["camera"]},
                               "camera": {"type": "sensor_cs", "parent": "odom", "children": [],
                                          "pose_wrt_parent": {
                                              "matrix4x4": d["camera_to_world"][0].ravel().tolist()}}},
        "streams": {"camera": {"type": "camera"}},
        "frame_intervals": [{"frame_start": 0, "frame_end": n - 1}],
        "objects": objects, "frames": frames}}


def write_json(path, doc):
    with open(path, "w") as fh:
        json.dump(doc, fh)
    return str(path)
