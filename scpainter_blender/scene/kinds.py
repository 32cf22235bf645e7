"""The kinds of scene object SCPainter makes, and how to find them: the one place their names are spelled.

Each object SCPainter creates carries its kind as the custom property ``scpainter_kind`` (``PROPERTY``). The values
are saved in .blend files: never rename them.

* ``POINTS``: the VGGT point cloud (scene/importer.py, scene/points.py);
* ``RECORDED_CAMERA``: the camera keyed with the recorded drive (scene/importer.py, scene/camera.py);
* ``CAMERA_PATH``: a camera following the recorded one shifted sideways (scene/camera.py);
* ``GAUSSIAN_ASSET``: a Gaussian car asset (scene/gaussians.py);
* ``REMOVAL_BOX``: a cube empty whose points are removed from the points object (scene/placement.py);
* ``ASSET_BOX``: a Gaussian asset's upright 3D box, a cube empty parented to the asset (scene/asset_box.py);
* ``ASSET_FRONT``: the arrow that marks the front (+y) of an asset box, parented to the box (scene/asset_box.py);
* ``RECORDED_OBJECT``: an object of the recording (a tracked car), a cube empty whose unit cube is its box; the job's
  ``scene.recorded_objects`` (scene/job_export.py; an accepted proposal becomes one: scene/proposals.py);
* ``PROPOSAL``: a box proposal for review, a cube empty like a recorded object (scene/proposals.py);
* ``RIG``: a camera rig, an empty parented to the camera path it follows, at the ego pose (scene/rig.py);
* ``RIG_CAMERA``: one camera of a rig, a camera parented to the rig empty (scene/rig.py);
* ``RIG_LIDAR``: a rig's LiDAR, an empty parented to the rig empty (scene/rig.py).

Objects are anything with ``get`` (Blender objects, ``None`` allowed where noted); no bpy needed here.
"""

from __future__ import annotations

from . import keys

PROPERTY = "scpainter_kind"

POINTS = "points"
RECORDED_CAMERA = "recorded_camera"
CAMERA_PATH = "camera_path"
GAUSSIAN_ASSET = "gaussian_asset"
REMOVAL_BOX = "removal_box"
ASSET_BOX = "asset_box"
ASSET_FRONT = "asset_front"
RECORDED_OBJECT = "recorded_object"
PROPOSAL = "proposal"
RIG = "rig"
RIG_CAMERA = "rig_camera"
RIG_LIDAR = "rig_lidar"
ALL = (POINTS, RECORDED_CAMERA, CAMERA_PATH, GAUSSIAN_ASSET, REMOVAL_BOX, ASSET_BOX, ASSET_FRONT, RECORDED_OBJECT,
       PROPOSAL, RIG, RIG_CAMERA, RIG_LIDAR)


def mark(obj, kind: str) -> None:
    """Tag ``obj`` as one of ``ALL``; ValueError for any other name (a typo would make an object no finder sees)."""
    if kind not in ALL:
        raise ValueError(f"unknown scene object kind {kind!r}; one of {ALL}")
    obj[PROPERTY] = kind


def kind_of(obj) -> str | None:
    """The kind ``obj`` was marked with; None for None or an object SCPainter did not make."""
    return None if obj is None else obj.get(PROPERTY)


def is_kind(obj, *kinds: str) -> bool:
    """Whether ``obj`` (None allowed: False) is of one of ``kinds``."""
    return kind_of(obj) in kinds


def objects_of_kind(scene, kind: str) -> list:
    """The scene's objects of ``kind``, in ``scene.objects`` order."""
    return [o for o in scene.objects if is_kind(o, kind)]


def first_of_kind(scene, kind: str):
    """The scene's first object of ``kind``, or None."""
    return next((o for o in scene.objects if is_kind(o, kind)), None)


def point_cloud(scene):
    """The scene's (first) points object, or None: for tools that need any reconstruction. The one a job renders
    is ``visibility.points_object``'s (a re-imported scene may hold an old, hidden one first)."""
    return first_of_kind(scene, POINTS)


def point_clouds(scene) -> list:
    """The scene's points objects (rendered or not), in ``scene.objects`` order."""
    return objects_of_kind(scene, POINTS)


def recorded_camera(scene, prefer=()):
    """The scene's recorded camera: the first of ``prefer`` (e.g. the active object, the scene camera) that is one,
    else the first in the scene; None without one."""
    found = next((o for o in prefer if is_kind(o, RECORDED_CAMERA)), None)
    return found if found is not None else first_of_kind(scene, RECORDED_CAMERA)


def recorded_camera_of(scene, points):
    """The recorded camera imported with ``points`` (the import links both into one collection): the scene's
    recorded camera sharing a collection with it, else the scene's only recorded camera; None otherwise (or for
    ``points`` None)."""
    cams = objects_of_kind(scene, RECORDED_CAMERA)
    if points is None:
        return None
    own = set(points.users_collection)
    return next((c for c in cams if own.intersection(c.users_collection)), cams[0] if len(cams) == 1 else None)


def sensor_cameras_of(scene, points) -> dict:
    """{sensor: recorded camera} of a multi-camera recording imported with ``points``: the recorded cameras sharing
    a collection with it that carry ``keys.SENSOR`` (empty for a single-camera import or ``points`` None)."""
    own = set(points.users_collection) if points is not None else set()
    return {c[keys.SENSOR]: c for c in objects_of_kind(scene, RECORDED_CAMERA)
            if keys.SENSOR in c and own.intersection(c.users_collection)}


def camera_paths(scene) -> list:
    """The scene's camera paths (``scpainter.new_camera_path``'s cameras), in name order: what *Render/Generate
    All Camera Paths* runs, one after another."""
    return sorted((o for o in objects_of_kind(scene, CAMERA_PATH) if o.type == "CAMERA"), key=lambda o: o.name)


def gaussian_assets(scene) -> list:
    """The scene's Gaussian car assets (accepted, rejected or unchecked)."""
    return objects_of_kind(scene, GAUSSIAN_ASSET)


def removal_boxes(scene) -> list:
    """The scene's removal boxes."""
    return objects_of_kind(scene, REMOVAL_BOX)


def recorded_objects(scene) -> list:
    """The scene's recorded objects (tracked boxes of the recording), in ``scene.objects`` order."""
    return objects_of_kind(scene, RECORDED_OBJECT)


def child_of_kind(obj, kind: str):
    """The first of ``obj``'s direct children (``obj.children``) of ``kind``, or None (also for ``obj`` None)."""
    return None if obj is None else next((c for c in obj.children if is_kind(c, kind)), None)


def asset_box(asset):
    """The box of a Gaussian asset (its child of kind ``ASSET_BOX``), or None: none estimated yet, or deleted."""
    return child_of_kind(asset, ASSET_BOX)


def asset_front(box):
    """The front arrow of an asset box (its child of kind ``ASSET_FRONT``), or None."""
    return child_of_kind(box, ASSET_FRONT)


def owning_asset(obj):
    """The Gaussian asset ``obj`` belongs to: itself, or the asset above its box or front arrow (through
    ``parent``); None for anything else."""
    while obj is not None and is_kind(obj, ASSET_BOX, ASSET_FRONT):
        obj = obj.parent
    return obj if is_kind(obj, GAUSSIAN_ASSET) else None


def rig_of(camera):
    """The camera rig that follows ``camera`` (its child of kind ``RIG``), or None (also for ``camera`` None)."""
    return child_of_kind(camera, RIG)


def rig_sensors(rig, kind: str) -> list:
    """A rig's direct children of ``kind`` (``RIG_CAMERA`` or ``RIG_LIDAR``) in the rig's order: by their stored
    place (``scpainter_sensor_index``), then by name; [] for ``rig`` None."""
    if rig is None:
        return []
    return sorted((c for c in rig.children if is_kind(c, kind)),
                  key=lambda c: (int(c.get(keys.SENSOR_INDEX, 1 << 30)), c.name))

