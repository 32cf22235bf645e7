"""A new camera path: the recorded drive shifted sideways relative to the direction of travel."""

from __future__ import annotations

import bpy

from ..scpainter_blender.scene import camera, kinds
from . import reports, selection


def recorded_camera(context):
    """The scene's recorded camera: the active object or scene camera if it is one, else the first found."""
    return kinds.recorded_camera(context.scene, prefer=(context.active_object, context.scene.camera))


class SCPAINTER_OT_new_camera_path(bpy.types.Operator):
    """Add a camera that follows the recorded drive shifted sideways (positive: left), keyed per frame"""

    bl_idname = "scpainter.new_camera_path"
    bl_label = "New Camera Path"
    bl_options = {"REGISTER", "UNDO"}

    shift: bpy.props.FloatProperty(name="Shift", default=2.0, unit="LENGTH", soft_min=-10.0, soft_max=10.0,
                                   description="Sideways offset from the recorded drive: positive left, negative right")

    @classmethod
    def poll(cls, context):
        if recorded_camera(context) is None:
            cls.poll_message_set("Import a VGGT reconstruction first: there is no recorded camera")
            return False
        return True

    @reports.reported
    def execute(self, context):
        obj = camera.create_camera_path(context, recorded_camera(context), self.shift)
        selection.select_only(context, obj)
        self.report({"INFO"}, f"{obj.name!r} is the active camera, keyed on frames "
                              f"{context.scene.frame_start}-{context.scene.frame_end}")
        return {"FINISHED"}


classes = (SCPAINTER_OT_new_camera_path,)
