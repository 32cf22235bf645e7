"""Scene-level settings of the add-on (registered on bpy.types.Scene), and where a scene's runs write.

A scene's output folder (``output_dir``: ``Scene.scpainter_output_dir``, or ``//scpainter/<scene name>/``) holds one
job output folder per camera (``camera_output_dir``: ``<scene output folder>/<camera name, cleaned>/``), so a
second camera path never overwrites the first's conditions, video or labels (``core.output_layout.SceneFolder``).
A camera's folder is named by ``bpy.path.clean_name`` of its object name; two cameras of the scene whose names clean
to the same folder (``Cam.1`` and ``Cam_1``; on a case-insensitive disk ``cam`` and ``Cam``), or a name the scene
folder uses itself (``SceneFolder.RESERVED``), are refused naming the object: rename one.
"""

from __future__ import annotations

import os

import bpy

from ..core import errors
from ..core import job as job_mod
from ..core.output_layout import SceneFolder
from . import keys

DEFAULT_OUTPUT = "//scpainter/{scene}/"
#: The ``path`` of a SceneError in a .blend that was never saved.
UNSAVED = "(unsaved .blend)"


class SceneError(errors.InputError):
    """A scene that cannot be used as it is (no camera, an output folder relative to an unsaved .blend, no road
    points under an asset): bad input, like a bad file. ``path`` is the .blend (``UNSAVED`` before it is saved),
    ``field`` the datablock or property at fault (``scene.camera``, ``scene.scpainter_output_dir``,
    ``objects['Car']``)."""

    def __init__(self, field, message, hint=None):
        super().__init__(bpy.data.filepath or UNSAVED, field, message, hint)


def output_dir(scene) -> str:
    """The scene's output folder, absolute: its setting, or //scpainter/<scene name>/ beside the .blend.
    SceneError when it is relative to a .blend that is not saved."""
    raw = scene.scpainter_output_dir or DEFAULT_OUTPUT.format(scene=bpy.path.clean_name(scene.name))
    if raw.startswith("//") and not bpy.data.filepath:
        raise SceneError("scene.scpainter_output_dir", f"the output folder {raw!r} is relative to the .blend, which "
                         "is not saved yet", hint="save the .blend or set an absolute output folder in the "
                                                  "SCPainter panel")
    return os.path.abspath(bpy.path.abspath(raw))


def camera_folder_name(camera) -> str:
    """The name of ``camera``'s output folder inside the scene's: its object name made file-system safe
    (``bpy.path.clean_name``: "Camera path 2 m left" -> "Camera_path_2_m_left")."""
    return bpy.path.clean_name(camera.name)


def camera_output_dir(scene, camera=None) -> str:
    """The output folder of ``camera``'s runs (default: the scene camera), absolute: ``<output_dir(scene)>/<its
    folder name>``. SceneError when the scene folder cannot be had (``output_dir``), when there is no camera, or
    when the folder name is taken (module docstring)."""
    root = output_dir(scene)  # first: an unsaved .blend is said before a missing camera
    camera = camera or scene.camera
    if camera is None or camera.type != "CAMERA":
        field = "scene.camera" if camera is None else f"objects[{camera.name!r}]"
        raise SceneError(field, "the scene has no active camera" if camera is None else "is not a camera",
                         hint="add one (or a camera path) and make it the scene camera")
    name = camera_folder_name(camera)
    if name.casefold() in SceneFolder.RESERVED:  # casefolded: on a case-blind disk "Assets" is "assets"
        raise SceneError(f"objects[{camera.name!r}]", f"its output folder would be {name!r}, a name the scene's "
                         "output folder uses itself", hint="rename the camera")
    twin = next((o for o in scene.objects if o.type == "CAMERA" and o != camera
                 and camera_folder_name(o).casefold() == name.casefold()), None)
    if twin is not None:  # the two would write into one folder: the second would overwrite the first
        raise SceneError(f"objects[{camera.name!r}]", f"its output folder {name!r} would also be the output "
                         f"folder of camera {twin.name!r}", hint="rename one of the two cameras")
    return SceneFolder(root).camera(name)


def named_camera(scene, name: str | None, blend: str, option: str = "--camera"):
    """The camera object of ``scene`` a command line names (``option`` = ``name``; None: the scene camera).
    ``ArgumentError`` naming the option, the .blend and the scene's cameras when it is not one of them."""
    if name is None:
        return scene.camera
    obj = scene.objects.get(name)
    if obj is not None and obj.type == "CAMERA":
        return obj
    cameras = sorted(o.name for o in scene.objects if o.type == "CAMERA")
    what = f"is a {obj.type.lower()}, not a camera" if obj is not None else "is no object of the scene"
    raise errors.ArgumentError(option, f"{name!r} {what} in {blend}; its cameras: "
                                       f"{', '.join(map(repr, cameras)) or 'none'}",
                               hint=f"give one of the scene's camera names (e.g. a camera path's), or leave {option} "
                                    "out for the scene camera")


#: Object properties renamed to the ``a_to_b`` rule (issue 15): the name a .blend saved before holds.
RENAMED_PROPERTIES = keys.RENAMED


def matrix_property(obj, name: str):
    """A 4x4 matrix stored on ``obj`` as 16 row-major floats, read under its current name or, in a .blend saved
    before the rename, its old one (``RENAMED_PROPERTIES``). SceneError naming the object and the current name
    when neither is set (the property was deleted: import the file again)."""
    import numpy as np

    for key in (name, RENAMED_PROPERTIES.get(name)):
        if key is not None and key in obj:
            return np.array(obj[key], dtype=np.float64).reshape(4, 4)
    raise SceneError(f"objects[{obj.name!r}][{name!r}]", "missing: the matrix the import stored on the object",
                     hint="import the file again")


#: ``Scene.scpainter_baseline_inpaint``'s identifiers -> ``generate.inpaint`` ("DEFAULT": not chosen, not exported).
INPAINT_ITEMS = {"DEFAULT": None, "TELEA": "telea", "NAVIER_STOKES": "navier-stokes"}


def baseline_inpaint(scene) -> str | None:
    """The scene's ``generate.inpaint`` for the job: "telea", "navier-stokes", or None (the backend's default)."""
    return INPAINT_ITEMS[scene.scpainter_baseline_inpaint]


def registered() -> bool:
    """Whether ``register`` ran in this Blender (the add-on enabled, or ``cli.execute`` outside it)."""
    return hasattr(bpy.types.Scene, "scpainter_output_dir")


def register():
    bpy.types.Scene.scpainter_output_dir = bpy.props.StringProperty(
        name="Output Folder", subtype="DIR_PATH", default="",
        description="Where jobs, condition layers and videos go, one folder per camera inside it "
                    "(empty: //scpainter/<scene name>/)")
    default = job_mod.INPAINT_NAMES[job_mod.BASELINE_DEFAULTS["inpaint"]]
    bpy.types.Scene.scpainter_baseline_inpaint = bpy.props.EnumProperty(
        name="Baseline Inpainting", default="DEFAULT",
        description="How the baseline (Generate without a checkpoint: no model) fills the holes of each condition "
                    "image; the job's generate.inpaint",
        items=[("DEFAULT", f"Default ({default})", f"The backend's default, OpenCV {default}; not written to the job"),
               ("TELEA", "Telea", "OpenCV Telea: fast marching from the hole's border (Telea 2004)"),
               ("NAVIER_STOKES", "Navier-Stokes", "OpenCV Navier-Stokes: isophotes carried into the hole "
                                                  "(Bertalmio et al. 2001)")])


def unregister():
    del bpy.types.Scene.scpainter_baseline_inpaint
    del bpy.types.Scene.scpainter_output_dir
