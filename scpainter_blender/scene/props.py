"""Scene-level settings of the add-on (registered on bpy.types.Scene)."""

from __future__ import annotations

import os

import bpy

from ..core import errors
from ..core import job as job_mod

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


#: Object properties renamed to the ``a_to_b`` rule (issue 15): the name a .blend saved before holds.
RENAMED_PROPERTIES = {"scpainter_vggt_to_world": "scpainter_world_from_vggt",
                      "scpainter_file_to_data": "scpainter_data_from_file"}


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
        description="Where jobs, condition layers and videos go (empty: //scpainter/<scene name>/)")
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
