"""Replace Reconstruction: a new predictions file (another confidence, another crop, a better run of VGGT) in place
of the scene's points object and recorded camera, keeping what the artist built on them.

Importing again beside the old reconstruction leaves two clouds (the job refuses two that render:
scene/visibility.py); this swaps them instead. Kept: the camera paths, the assets, the removal boxes (their
modifiers move to the new points object, in order, with their on/off switches), the scene's frame range (the camera
paths are keyed over it) and the scene camera (unless it was the old recorded camera: then the new one). The new
objects go into the old points object's collection and take the old objects' names, so everything naming them
(``scpainter_points_object`` on a box, ``scpainter_source_camera`` on a camera path) still does. The recording is
placed on the same scene frames as the old one (its recorded camera's ``scpainter_frame_start``). A multi-camera
recording's other recorded cameras (``keys.SENSOR``, in the points' collection) go too, each new camera of the same
sensor taking the old one's name.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import bpy

from ..core.import_options import ImportOptions
from . import importer, keys, kinds, node_groups, placement, visibility
from . import points as points_mod
from .props import SceneError


@dataclass
class ReplaceResult:
    imported: importer.ImportResult
    replaced: str                                # the old points object's name, now the new one's
    camera: str | None                           # the old recorded camera's name, now the new one's (None: none)
    boxes: list = field(default_factory=list)    # names of the removal boxes carried over
    warnings: list = field(default_factory=list)


def old_points(context, chosen=None):
    """The points object to replace: ``chosen`` (e.g. the active object) when it is one, else the one the view
    layer renders, else the scene's only one. SceneError when there is none or it is ambiguous."""
    if kinds.is_kind(chosen, kinds.POINTS):
        return chosen
    clouds = kinds.point_clouds(context.scene)
    if not clouds:
        raise SceneError("scene.objects", "there is no reconstruction to replace",
                         hint="import one with Import VGGT Reconstruction")
    try:
        shown = visibility.points_object(context.scene, context.view_layer)
    except SceneError:  # two render: the artist says which by making it the active object
        shown = None
    if shown is None and len(clouds) > 1:
        raise SceneError(", ".join(f"objects[{o.name!r}]" for o in clouds), "which reconstruction to replace is "
                         "not clear", hint="select the points object to replace (make it the active object)")
    return shown or clouds[0]


def replace_reconstruction(context, filepath: str, opts: ImportOptions | None = None, chosen=None) -> ReplaceResult:
    """Import ``filepath`` (``importer.import_vggt`` with ``opts``) in place of ``old_points(context, chosen)`` and
    its recorded camera (module docstring). The file is read and checked before anything changes: a refused file
    leaves the scene as it was."""
    scene = context.scene
    old = old_points(context, chosen)
    old_cam = kinds.recorded_camera_of(scene, old)
    # a multi-camera recording's other sensors' cameras (sharing the points' collection): replaced too, each by the
    # new camera of its sensor (which takes its name), or removed
    sensor_cams = kinds.sensor_cameras_of(scene, old)
    old_sensors = {name: o for name, o in sensor_cams.items() if o != old_cam}
    old_frames = points_mod.num_scene_frames(old)
    start = int(old_cam[keys.FRAME_START]) if old_cam is not None and keys.FRAME_START in old_cam \
        else scene.frame_start
    opts = dataclasses.replace(opts or ImportOptions(), frame_start=start, set_scene_camera=False)
    frame_range = (scene.frame_start, scene.frame_end)
    follow = scene.camera is None or scene.camera == old_cam  # the old recorded camera was the one looked through
    collection = old.users_collection[0] if old.users_collection else None
    result = importer.import_vggt(context, filepath, opts, collection=collection)
    scene.frame_start, scene.frame_end = frame_range  # the import set the new recording's; the paths use these
    boxes = []
    for mod in placement.removal_modifiers(old):
        box = node_groups.get_input(mod, "Box")
        if box is None:  # a deleted box: nothing to carry
            continue
        new_mod = placement.attach_removal_box(result.points, box)
        new_mod.show_viewport, new_mod.show_render = mod.show_viewport, mod.show_render
        boxes.append(box.name)
    if follow:
        scene.camera = result.camera
    warnings = list(result.warnings)
    # scene frames, not VGGT frames: a multi-camera recording has one VGGT frame per sensor at each scene frame
    new_frames = points_mod.num_scene_frames(result.points)
    if old_frames and old_frames != new_frames:
        warnings.append(f"the new recording has {new_frames} scene frames, the old one {old_frames}: the frame "
                        f"range stays {frame_range[0]}–{frame_range[1]} (the camera paths are keyed over it); make "
                        "new camera paths to follow the new recording")
    old_set, new_set = sorted(sensor_cams), sorted(str(c[keys.SENSOR]) for c in result.cameras if keys.SENSOR in c)
    if old_set != new_set:
        lacks = [n for n in old_set if n not in new_set]
        warnings.append(f"the new recording's sensors are {', '.join(new_set) or 'one camera'}, the old one's "
                        f"{', '.join(old_set) or 'one camera'}"
                        + (f": the cameras of {', '.join(lacks)} are removed; check the camera paths made from them"
                           if lacks else ""))
    names = (old.name, old_cam.name if old_cam is not None else None)
    sensor_names = {sensor: o.name for sensor, o in old_sensors.items()}
    _remove(old)
    if old_cam is not None:
        _remove(old_cam)
    for o in old_sensors.values():
        _remove(o)
    result.points.name = names[0]  # free now: everything naming the old objects names the new ones
    if names[1] is not None:
        result.camera.name = names[1]
    for cam in result.cameras[1:]:
        if cam.get(keys.SENSOR) in sensor_names:
            cam.name = sensor_names[cam[keys.SENSOR]]
    for name in boxes:  # attach_removal_box wrote the new object's name before it took the old one's
        bpy.data.objects[name][keys.POINTS_OBJECT] = result.points.name
    context.view_layer.update()  # the view layer drops the deleted objects (its selection would still list them)
    return ReplaceResult(result, names[0], names[1], boxes, warnings)


def _remove(obj) -> None:
    """Delete ``obj`` and its data when nothing else uses it (a camera path has its own copy of the camera data)."""
    data = obj.data
    bpy.data.objects.remove(obj, do_unlink=True)
    if isinstance(data, bpy.types.Mesh) and data.users == 0:
        bpy.data.meshes.remove(data)
    elif isinstance(data, bpy.types.Camera) and data.users == 0:
        bpy.data.cameras.remove(data)
