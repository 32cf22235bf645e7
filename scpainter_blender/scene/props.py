"""Scene-level settings of the add-on (registered on bpy.types.Scene)."""

from __future__ import annotations

import os

import bpy

DEFAULT_OUTPUT = "//scpainter/{scene}/"


def output_dir(scene) -> str:
    """The scene's output folder, absolute: its setting, or //scpainter/<scene name>/ beside the .blend."""
    raw = scene.scpainter_output_dir or DEFAULT_OUTPUT.format(scene=bpy.path.clean_name(scene.name))
    if raw.startswith("//") and not bpy.data.filepath:
        raise ValueError(f"the output folder {raw!r} is relative to the .blend, which is not saved yet: save it "
                         "or set an absolute output folder in the SCPainter panel")
    return os.path.abspath(bpy.path.abspath(raw))


def register():
    bpy.types.Scene.scpainter_output_dir = bpy.props.StringProperty(
        name="Output Folder", subtype="DIR_PATH", default="",
        description="Where jobs, condition layers and videos go (empty: //scpainter/<scene name>/)")


def unregister():
    del bpy.types.Scene.scpainter_output_dir
