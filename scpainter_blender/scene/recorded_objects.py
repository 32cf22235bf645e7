"""Recorded objects in Blender: the drive's own tracked boxes (``core.job.RecordedObject``) as editable cube empties,
and back (docs/design.md §15).

Each is a cube empty of display size ``DISPLAY_SIZE`` (0.5: its unit cube [−0.5, 0.5]³ is the box), ``matrix_world``
= box_to_world · diag(width, length, height, 1) (``placement.cube_matrix`` turns it back), of kind
``kinds.RECORDED_OBJECT``, with ``keys.TRACK_ID`` (str), ``keys.CLASS``, ``keys.IGNORE`` (bool) and
``keys.TRACK_FRAMES`` (the scene frames its track is in; an object without it, such as an accepted proposal, is in
every frame), in the collection ``COLLECTION``. An object whose box moves is keyed at each of its frames (location,
continuous quaternions, scale; linear in between); a still one is not keyed, so moving it by hand lasts. The artist
may move, scale, re-key, re-class (``scpainter_class``) or delete them: ``job_objects`` reads what the scene holds
at each output frame (keys, drivers and parents honoured) into the job's ``scene.recorded_objects``.
A removal box can be made from one (``removal_box``: its box at the current frame), for *Replace Car*.
"""

from __future__ import annotations

import os

import bpy
import numpy as np
from mathutils import Matrix

from ..core import job as job_mod
from ..core.geometry import cameras
from ..core.recording import reader
from . import camera as camera_mod
from . import compat, keys, kinds, placement, visibility
from . import points as points_mod
from .props import SceneError

COLLECTION = "SCPainter Recorded Objects"
DISPLAY_SIZE = 0.5
#: A box moving less than this (metres, or radians of its axes) between its frames is still: not keyed.
STILL = 1e-6


def cube_world(box_to_world, size) -> np.ndarray:
    """The cube empty's matrix_world (4, 4) of a box: box_to_world · diag(w, l, h, 1) (display size 0.5)."""
    return np.asarray(box_to_world, np.float64) @ np.diag([*np.asarray(size, np.float64), 1.0])


def collection(scene):
    """The scene's ``COLLECTION`` (made and linked under the scene's collection when missing)."""
    coll = bpy.data.collections.get(COLLECTION)
    if coll is None:
        coll = bpy.data.collections.new(COLLECTION)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def check_new(scene, objects: list) -> None:
    """SceneError when a track id of ``objects`` is already a recorded object of the scene (checked before anything
    is made: an import either adds all its objects or none)."""
    have = {o.get(keys.TRACK_ID) for o in kinds.recorded_objects(scene)}
    clash = [o.id for o in objects if o.id in have]
    if clash:
        raise SceneError("scene.objects", f"the scene already has recorded objects of tracks {clash[:5]}",
                         hint="delete them first (collection 'SCPainter Recorded Objects') to import them again")


def add_objects(context, objects: list) -> list:
    """Cube empties for ``objects`` (``RecordedObject``, boxes keyed by scene frame) in ``COLLECTION``; returns them."""
    scene = context.scene
    check_new(scene, objects)
    coll = collection(scene)
    made = []
    for o in objects:
        frames = sorted(o.boxes)
        M = np.stack([cube_world(o.boxes[f], o.size) for f in frames])
        obj = bpy.data.objects.new(f"{o.category} {o.id}"[:63], None)
        obj.empty_display_type = "CUBE"
        obj.empty_display_size = DISPLAY_SIZE
        kinds.mark(obj, kinds.RECORDED_OBJECT)
        obj[keys.TRACK_ID] = o.id
        obj[keys.CLASS] = o.category
        obj[keys.IGNORE] = bool(o.ignore)
        obj[keys.TRACK_FRAMES] = [int(f) for f in frames]
        obj.rotation_mode = "QUATERNION"
        obj.matrix_world = Matrix(M[0].tolist())
        if np.abs(M - M[0]).max() > STILL:
            T = np.stack([o.boxes[f] for f in frames])
            quat = cameras.continuous_quaternions(cameras.rotation_to_quaternion(T[:, :3, :3]))
            fc = compat.new_action_fcurves(obj, f"{obj.name} track")
            for i in range(3):
                compat.key_fcurve(fc, "location", i, frames, T[:, i, 3])
                compat.key_fcurve(fc, "scale", i, frames, np.full(len(frames), o.size[i]))
            for i in range(4):
                compat.key_fcurve(fc, "rotation_quaternion", i, frames, quat[:, i])
        coll.objects.link(obj)
        made.append(obj)
    return made


def map_recording(recording, groups: dict, offsets, frame_start: int, camera: str, world_to_camera) -> reader.Mapped:
    """The recording's boxes mapped into the world (``reader.recorded_objects``) through the recorded camera they are
    seen from: the one path of the import's ``objects`` (scene/importer.py) and of *Import Recorded Objects*
    (``import_file``), so both put them on the same scene frames through the same camera.

    ``groups`` {sensor: (n,) VGGT frames} as the import makes its recorded cameras (``points.camera_frames``: the
    reference sensor first; {"": all} for one camera), ``offsets`` (S,) each VGGT frame's scene frame offset
    (``points.scene_frame_offsets``), ``frame_start`` the scene frame of offset 0, ``camera`` the recording's camera
    (``reader.read``'s): the sensor of that name when the recording has one, else the reference. Recording frame i
    is that sensor's i-th frame, keyed at its scene frame ``frame_start + offsets[groups[sensor][i]]`` (a sensor
    that missed a reference frame skips that scene frame); ``world_to_camera(sensor, vggt_frames, scene_frames) ->
    (n, 4, 4)`` gives its camera at its frames (metres, OpenCV)."""
    name = camera if camera in groups else next(iter(groups))
    idx = np.asarray(groups[name], np.int64)
    frames = int(frame_start) + np.asarray(offsets, np.int64)[idx]
    mapped = reader.recorded_objects(recording, world_to_camera(name, idx, frames), 0)   # keyed by recording frame
    for o in mapped.objects:
        o.boxes = {int(frames[f]): B for f, B in o.boxes.items()}
    return mapped


def import_file(context, path: str, fmt: str = reader.AUTO, scene_name: str = "", camera: str = "",
                points=None) -> tuple:
    """(objects made, warnings): the recorded objects of ``path`` (``core.recording``) added to a scene that holds
    the reconstruction ``points`` (default: the one the view layer renders) and its recorded cameras, mapped as the
    import maps them (``map_recording``: a multi-camera recording's boxes through the camera of sensor ``camera``,
    else the reference sensor's, at that sensor's scene frames). Read and checked before anything is made."""
    scene = context.scene
    points = points or visibility.points_object(scene, context.view_layer) or kinds.point_cloud(scene)
    cam = kinds.recorded_camera_of(scene, points)
    if points is None or cam is None or keys.NUM_FRAMES not in points or keys.FRAME_START not in cam:
        raise SceneError("scene.objects", "recorded objects need the imported reconstruction and its recorded camera",
                         hint="import the predictions first (Import VGGT Reconstruction)")
    groups = points_mod.camera_frames(points)
    if groups is None:
        raise SceneError(f"objects[{points.name!r}]", f"this multi-camera recording has no {keys.FRAME_SENSORS} "
                                                      "(imported before it was stored): which camera took which "
                                                      "frame is not known", hint="import the predictions again")
    offsets = points_mod.scene_frame_offsets(points)
    cams = kinds.sensor_cameras_of(scene, points) or {"": cam}
    # the scene frame of offset 0: the import's frame_start (each recorded camera keeps its first frame's)
    first = groups.get(cam.get(keys.SENSOR, ""), next(iter(groups.values())))
    frame_start = int(cam[keys.FRAME_START]) - int(offsets[first[0]])

    def world_to_camera(sensor, idx, frames):
        if sensor not in cams:
            raise SceneError("scene.objects", f"the recorded camera of sensor {sensor} is gone",
                             hint="import the predictions again (Replace Reconstruction), or choose another camera")
        return camera_mod.world_to_camera_per_frame(scene, cams[sensor], frames)

    recording = reader.read(os.path.abspath(bpy.path.abspath(path)), fmt, scene_name, camera)
    mapped = map_recording(recording, groups, offsets, frame_start, camera, world_to_camera)
    return add_objects(context, mapped.objects), mapped.warnings


def job_objects(scene, frames: list) -> list:
    """The job's ``scene.recorded_objects`` at output ``frames`` (the scene is set to each in turn; the current frame
    is restored): per recorded object its box at each of its frames among them (``placement.box_matrix``), its size
    at the first; an object in none of them is left out. SceneError when two share a track id."""
    objs = kinds.recorded_objects(scene)
    ids = [str(o.get(keys.TRACK_ID, o.name)) for o in objs]
    for i, tid in enumerate(ids):
        if tid in ids[:i]:
            raise SceneError(f"objects[{objs[i].name!r}]", f"track id {tid!r} is also {objs[ids.index(tid)].name!r}'s",
                             hint="give each recorded object its own scpainter_track_id")
    found = {o.name: {} for o in objs}
    sizes = {}
    current = scene.frame_current
    try:
        for f in frames:
            wanted = [o for o in objs if keys.TRACK_FRAMES not in o or f in set(o[keys.TRACK_FRAMES])]
            if not wanted:
                continue
            scene.frame_set(f)
            for o in wanted:
                T, size = placement.box_matrix(o)
                found[o.name][f] = T
                sizes.setdefault(o.name, size)
    finally:
        scene.frame_set(current)
    return [job_mod.RecordedObject(tid, sizes[o.name], found[o.name], str(o.get(keys.CLASS, job_mod.DEFAULT_CLASS)),
                                   bool(o.get(keys.IGNORE, False)))
            for o, tid in zip(objs, ids) if found[o.name]]


def removal_box(context, obj, points_obj):
    """A removal box around recorded object ``obj``'s box at the current frame (``placement.add_removal_box``):
    where an inserted car replaces it (*Replace Car*). The box is still: for a moving object, key it or make one
    per frame."""
    T, size = placement.box_matrix(obj)
    return placement.add_removal_box(context, points_obj, box_to_world=T, size=(size[1], size[0], size[2]),
                                     name=f"Removal {obj.name}")


def of_selection(context) -> list:
    """The selected recorded objects (the active one first)."""
    sel = [o for o in context.selected_objects if kinds.is_kind(o, kinds.RECORDED_OBJECT)]
    active = context.active_object
    return sorted(sel, key=lambda o: o != active)

