"""Camera rigs in Blender (docs/design.md §9, §17): *Add Camera Rig* on a camera path, and the rig a scene holds read
back as a ``core.rig.Rig`` for the job.

In the scene a rig is an empty "SCPainter Rig" (kind ``rig``) parented to the camera path it follows, standing at the
ego pose (ego axes: x forward, y left, z up): its local matrix is ``F · camera_to_ego(follow)⁻¹`` (F =
``cameras.OPENCV_TO_BLENDER_CAMERA``, the camera path's Blender axes to OpenCV's), so at every frame

    ego_to_world = camera_to_world(path) · camera_to_ego(follow)⁻¹

with the path camera taken as the rig camera ``follow`` (``keys.RIG_FOLLOW``: CAM_FRONT for the presets; it is
``core.rig.ego_path``'s rule, the parent relation doing it per frame). Under it, one Blender camera per rig camera
(kind ``rig_camera``, named after its sensor, ``keys.SENSOR``), local matrix ``camera_to_ego · F``, its lens, sensor
and shifts from K (``cameras.blender_camera_from_K``) for the camera's own resolution, stored on it
(``keys.RESOLUTION``, ``keys.PIXEL_ASPECT``: Blender renders one resolution per scene); and, when the rig has one, a
LiDAR empty (kind ``rig_lidar``, local matrix ``lidar_to_ego``, its model in ``keys.LIDAR_MODEL``).

Everything stays editable: the user moves and turns the cameras, changes their lens, sensor, shift or stored
resolution, moves the LiDAR, and ``read_rig`` reads what is there: ``camera_to_ego`` = the camera's local matrix
(``matrix_parent_inverse · matrix_basis``, so keyframes count, constraints do not) · F, K from the camera data at its
stored resolution (``cameras.K_from_blender_camera``). Blender keeps those values in float32 (a lens of 28 mm to
~2e-6 mm: 1e-4 px of fx); the float64 values a sensor was added with (``keys.INTRINSICS``, ``keys.MOUNT``) are what
is read while the scene's still round to them (``KEPT_K_PX``, ``KEPT_POSE``), so an unedited preset exports exactly
the preset (nuScenes' calibration, to the last digit) and any real edit exports the edit.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from ..core import rig as rig_mod
from ..core.geometry import cameras
from ..core.errors import InputError
from . import keys, kinds, props
from . import recording_rig as recording_rig_mod

RIG_NAME = "SCPainter Rig"
#: The preset *Add Camera Rig* offers beside ``core.rig.PRESETS`` when the scene's recording stored its own rig.
RECORDING = "recording"
#: The camera a rig follows when it has it (the presets' front camera); else its first camera.
FOLLOW = "CAM_FRONT"
#: The scale *Add Camera Rig* proposes: a quarter of nuScenes' 1600 × 900 (400 × 225), so a first render is quick.
DEFAULT_SCALE = 0.25
#: A rig camera's kept K (as added) is read while the camera data gives it back to within this many pixels per
#: 1000 px of image size (float32 lens and shifts round to ~1e-4 px); a larger difference is an edit.
KEPT_K_PX = 1e-3
#: A kept mounting pose is read while the scene's local matrix equals it to within this (rotation entries; metres).
KEPT_POSE = 1e-5
F = cameras.OPENCV_TO_BLENDER_CAMERA


def _matrix(M) -> Matrix:
    return Matrix(np.asarray(M, np.float64).tolist())


def _array(M) -> np.ndarray:
    return np.array(M, dtype=np.float64).reshape(4, 4)


def recording_rig(scene) -> rig_mod.Rig | None:
    """The rig the scene's multi-camera recording stored on its points object (``recording_rig.recording_rig``), or
    None (a single-camera import). InputError naming the object and key for a stored rig that is not one."""
    return recording_rig_mod.recording_rig(scene)


def preset_items(scene) -> list:
    """(identifier, label, description) of each rig *Add Camera Rig* offers: ``core.rig.PRESETS``, and "recording"
    when the scene's recording stored a rig (``recording_rig``)."""
    labels = {"nuscenes": "nuScenes"}
    items = [(name, labels.get(name, name.capitalize()), description)
             for name, (description, _maker) in rig_mod.PRESETS.items()]
    try:
        stored = recording_rig(scene) if scene is not None else None
    except InputError:  # a stored rig edited into nonsense: not offered (choosing it by name says what is wrong)
        stored = None
    if stored is not None:
        items.append((RECORDING, "Recording", "the cameras (and LiDAR) of the imported multi-camera recording"))
    return items


def make_rig(scene, name: str, lidar: bool | None = True, scale: float = 1.0, field: str = "preset") -> rig_mod.Rig:
    """The rig called ``name``: a preset (``core.rig.preset``; with its LiDAR when ``lidar``, the preset's own choice
    for None), "recording" (the recording's own, ``recording_rig``; its LiDAR dropped when ``lidar`` is False, and
    nuScenes' top LiDAR mounted when ``lidar`` is True and it has none: its ego frame is nuScenes') or a rig file (a
    name ending in .json, ``core.rig.load``), cameras scaled by ``scale``. ArgumentError on ``field`` (the operator's
    property, the command line's option) for an unknown preset; SceneError for "recording" in a scene whose recording
    stored none; InputError for a bad rig file."""
    if name == RECORDING or name.lower().endswith(".json"):
        rig = rig_mod.load(name) if name != RECORDING else recording_rig(scene)
        if rig is None:
            raise props.SceneError("scene.objects", "the scene's recording stored no camera rig",
                                   hint="import a multi-camera recording, or choose a preset")
        if lidar is False:
            rig = rig_mod.Rig(rig.name, rig.cameras, None)
        elif lidar and rig.lidar is None:
            rig = rig_mod.Rig(rig.name, rig.cameras, rig_mod.preset("nuscenes", lidar=True).lidar)
        return rig if scale == 1.0 else rig.scaled(scale)
    return rig_mod.preset(name, lidar=lidar, scale=scale, field=field)


def follow_camera(rig: rig_mod.Rig) -> str:
    """The rig camera a camera path is: ``FOLLOW`` when the rig has it, else its first camera."""
    names = [c.name for c in rig.cameras]
    return FOLLOW if FOLLOW in names else names[0]


def path_sensor(path_camera, rig: rig_mod.Rig) -> str | None:
    """The sensor of ``rig`` a camera path was made from: the sensor (``keys.SENSOR``) of the recorded camera it
    follows (``keys.SOURCE_CAMERA``; a multi-camera recording has one recorded camera per sensor) or of the camera
    itself; None when that is no camera of ``rig``."""
    source = bpy.data.objects.get(str(path_camera.get(keys.SOURCE_CAMERA, "")))
    for obj in (source, path_camera):
        sensor = obj.get(keys.SENSOR) if obj is not None else None
        if sensor is not None and str(sensor) in [c.name for c in rig.cameras]:
            return str(sensor)
    return None


def add_rig(path_camera, rig: rig_mod.Rig, follow: str | None = None):
    """Add ``rig`` to the scene following camera object ``path_camera`` (a camera path: the path is rig camera
    ``follow``, default the sensor it was made from, ``path_sensor``, else ``follow_camera``); a rig that already
    follows it is removed first. Returns the rig empty. SceneError when ``path_camera`` is not a camera."""
    if path_camera is None or path_camera.type != "CAMERA":
        field = "scene.camera" if path_camera is None else f"objects[{path_camera.name!r}]"
        raise props.SceneError(field, "a camera rig follows a camera path: " +
                               ("there is no active camera" if path_camera is None else "this is not a camera"),
                               hint="make a camera path (New Camera Path) the active object or the scene camera")
    follow = follow or path_sensor(path_camera, rig) or follow_camera(rig)
    mount = rig.camera(follow).camera_to_ego
    remove_rig(kinds.rig_of(path_camera))
    collection = path_camera.users_collection[0] if path_camera.users_collection else bpy.context.scene.collection
    empty = _new(RIG_NAME, None, collection, path_camera, F @ cameras.rigid_inverse(mount))
    empty.empty_display_type, empty.empty_display_size = "ARROWS", 1.0
    kinds.mark(empty, kinds.RIG)
    empty[keys.RIG_NAME], empty[keys.RIG_FOLLOW] = rig.name, follow
    clip = (path_camera.data.clip_start, path_camera.data.clip_end)
    for i, cam in enumerate(rig.cameras):
        W, H = (int(v) for v in cam.resolution)
        bc = cameras.blender_camera_from_K(cam.K, W, H)
        data = bpy.data.cameras.new(cam.name)
        data.sensor_fit, data.sensor_width, data.sensor_height = bc.sensor_fit, bc.sensor_width, bc.sensor_height
        data.lens, data.shift_x, data.shift_y = bc.lens, bc.shift_x, bc.shift_y
        data.clip_start, data.clip_end = clip
        data.display_size = 0.3
        obj = _new(cam.name, data, collection, empty, np.asarray(cam.camera_to_ego, np.float64) @ F)
        kinds.mark(obj, kinds.RIG_CAMERA)
        obj[keys.SENSOR], obj[keys.SENSOR_INDEX] = cam.name, i
        obj[keys.RESOLUTION] = [W, H]
        obj[keys.PIXEL_ASPECT] = [bc.pixel_aspect_x, bc.pixel_aspect_y]
        obj[keys.INTRINSICS] = np.asarray(cam.K, np.float64).ravel().tolist()
        obj[keys.MOUNT] = np.asarray(cam.camera_to_ego, np.float64).ravel().tolist()
    if rig.lidar is not None:
        obj = _new(rig.lidar.name, None, collection, empty, rig.lidar.lidar_to_ego)
        obj.empty_display_type, obj.empty_display_size = "CIRCLE", 0.4
        kinds.mark(obj, kinds.RIG_LIDAR)
        obj[keys.SENSOR], obj[keys.SENSOR_INDEX] = rig.lidar.name, len(rig.cameras)
        obj[keys.LIDAR_MODEL] = rig.lidar.model
        obj[keys.MOUNT] = np.asarray(rig.lidar.lidar_to_ego, np.float64).ravel().tolist()
    return empty


def _new(name: str, data, collection, parent, local: np.ndarray):
    """A new object in ``collection``, child of ``parent`` with ``local`` as its matrix relative to it (no parent
    inverse: the parent's own matrix is the reference)."""
    obj = bpy.data.objects.new(name, data)
    collection.objects.link(obj)
    obj.parent = parent
    obj.matrix_parent_inverse = Matrix.Identity(4)
    obj.rotation_mode = "QUATERNION"  # Euler angles lose float32 precision near ±90° (the ego to camera turns)
    obj.matrix_basis = _matrix(local)
    return obj


def remove_rig(rig_obj) -> None:
    """Delete a rig: its empty, its sensors (and any other child) and its cameras' data. Nothing for None."""
    if rig_obj is None:
        return
    for obj in list(rig_obj.children_recursive) + [rig_obj]:
        data = obj.data if obj.type == "CAMERA" else None
        bpy.data.objects.remove(obj)
        if data is not None and data.users == 0:
            bpy.data.cameras.remove(data)


def path_camera_of(obj):
    """The camera path a rig belongs to, for ``obj`` the path itself, its rig, or one of the rig's sensors; None for
    anything else."""
    while obj is not None and kinds.is_kind(obj, kinds.RIG_CAMERA, kinds.RIG_LIDAR, kinds.RIG):
        obj = obj.parent
    return obj if obj is not None and obj.type == "CAMERA" and kinds.rig_of(obj) is not None else None


def target_camera(context):
    """The camera *Add / Remove Camera Rig* and the panel act on: the camera path whose rig (or rig sensor) is
    active, else the active object when it is a camera (not a rig's own), else the scene camera (or None)."""
    obj = context.active_object
    owner = path_camera_of(obj)
    if owner is not None:
        return owner
    if obj is not None and obj.type == "CAMERA" and not kinds.is_kind(obj, kinds.RIG_CAMERA):
        return obj
    return context.scene.camera


def local_matrix(obj) -> np.ndarray:
    """(4, 4) float64: ``obj``'s matrix relative to its parent as the scene is evaluated now (parent inverse ·
    basis: keyframes and drivers count, constraints do not), its scale taken out (a scaled empty or camera still
    stands where it stands, looking where it looks)."""
    M = _array(obj.matrix_parent_inverse) @ _array(obj.matrix_basis)
    M[:3, :3] /= np.linalg.norm(M[:3, :3], axis=0)
    return M


def ego_to_world(rig_obj) -> np.ndarray:
    """(4, 4) float64 ego_to_world of the rig empty as the scene is evaluated now (its matrix_world, scale taken
    out)."""
    M = _array(rig_obj.matrix_world)
    M[:3, :3] /= np.linalg.norm(M[:3, :3], axis=0)
    return M


def _kept(obj, key: str, now: np.ndarray, tolerance: float) -> np.ndarray:
    """The float64 value ``obj`` was added with (``key``) when ``now`` (what the scene holds) rounds to it, else
    ``now``: an edited sensor is read as edited."""
    if key not in obj:
        return now
    kept = np.array(obj[key], dtype=np.float64).reshape(now.shape)
    return kept if np.abs(kept - now).max() <= tolerance else now


def camera_K(obj) -> np.ndarray:
    """Our K (3, 3) of rig camera ``obj`` at its stored resolution and pixel aspect, from its lens, sensor and shifts
    now (the K it was added with while they still give it, module docstring)."""
    d = obj.data
    W, H = resolution(obj)
    ax, ay = _pair(obj, keys.PIXEL_ASPECT, (1.0, 1.0), float)
    K = cameras.K_from_blender_camera(cameras.BlenderCamera(
        lens=d.lens, sensor_width=d.sensor_width, sensor_height=d.sensor_height, sensor_fit=d.sensor_fit,
        shift_x=d.shift_x, shift_y=d.shift_y, resolution_x=W, resolution_y=H, pixel_aspect_x=ax, pixel_aspect_y=ay))
    return _kept(obj, keys.INTRINSICS, K, KEPT_K_PX * max(W, H) / 1000.0)


def _pair(obj, key: str, default: tuple, kind) -> tuple:
    """Two numbers stored on ``obj`` under ``key`` (``default`` when absent); SceneError naming the object and the
    key for anything else (a value typed over by hand)."""
    value = obj.get(key, default)
    try:
        a, b = (kind(v) for v in value)
        if not (np.isfinite(a) and np.isfinite(b) and a > 0 and b > 0):
            raise ValueError
    except (TypeError, ValueError):
        shown = repr(getattr(value, "to_list", lambda: value)())[:100]
        raise props.SceneError(f"objects[{obj.name!r}][{key!r}]", f"expected two positive numbers, got {shown}",
                               hint="set them again (Object Properties > Custom Properties), or add the rig "
                                    "again") from None
    return a, b


def resolution(obj) -> tuple:
    """(width, height) px a rig camera renders at (``keys.RESOLUTION``); SceneError naming it when not two positive
    whole numbers."""
    W, H = _pair(obj, keys.RESOLUTION, (0, 0), float)
    if W != int(W) or H != int(H):
        raise props.SceneError(f"objects[{obj.name!r}][{keys.RESOLUTION!r}]", f"{W:g} x {H:g} is not a size in "
                               "whole pixels", hint="give a width and height in pixels")
    return int(W), int(H)


def _mount(obj, extra: np.ndarray | None = None) -> np.ndarray:
    """A sensor's mounting pose relative to the rig empty (``local_matrix`` · ``extra``; the kept one while equal)."""
    M = local_matrix(obj) if extra is None else local_matrix(obj) @ extra
    return _kept(obj, keys.MOUNT, M, KEPT_POSE)


def read_rig(rig_obj) -> rig_mod.Rig:
    """The ``core.rig.Rig`` the rig empty ``rig_obj`` holds as the scene is evaluated now: its cameras (kind
    ``rig_camera``, in their stored order) and its LiDAR (the first ``rig_lidar``), checked as a rig file is
    (``Rig.from_dict``: names unique, K usable at its resolution, mounts rigid, LiDAR model known). SceneError
    naming the rig object and the field otherwise."""
    cams = kinds.rig_sensors(rig_obj, kinds.RIG_CAMERA)
    if not cams:
        raise props.SceneError(f"objects[{rig_obj.name!r}]", "the camera rig has no camera",
                               hint="add the rig again (Add Camera Rig) or remove it (Remove Camera Rig)")
    d = {"name": str(rig_obj.get(keys.RIG_NAME, "custom")),
         "cameras": [{"name": str(c.get(keys.SENSOR, c.name)), "resolution": list(resolution(c)),
                      "K": camera_K(c).tolist(), "camera_to_ego": _mount(c, F).tolist()} for c in cams]}
    lidars = kinds.rig_sensors(rig_obj, kinds.RIG_LIDAR)
    if lidars:
        ld = lidars[0]
        d["lidar"] = {"name": str(ld.get(keys.SENSOR, ld.name)), "model": str(ld.get(keys.LIDAR_MODEL, "")),
                      "lidar_to_ego": _mount(ld).tolist()}
    objects = {"cameras": cams, "lidar": lidars[:1]}

    def error(path, field, message, hint=None):
        # "rig.cameras[2].K" -> the object that holds it: "objects['CAM_BACK'] (rig.cameras[2].K)"
        part = field.partition(".")[2].partition(".")[0]
        head = part.partition("[")[0]
        index = int(part.partition("[")[2].rstrip("]") or 0) if "[" in part else 0
        held = objects.get(head, [])
        obj = held[index] if index < len(held) else rig_obj
        return props.SceneError(f"objects[{obj.name!r}] ({field})", message, hint)

    return rig_mod.Rig.from_dict(d, bpy.data.filepath or props.UNSAVED, "rig", error)


def follow_of(rig_obj) -> str:
    """The sensor the camera path of ``rig_obj`` is (``keys.RIG_FOLLOW``)."""
    return str(rig_obj.get(keys.RIG_FOLLOW, FOLLOW))
