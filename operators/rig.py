"""*Add Camera Rig* and *Remove Camera Rig* on a camera path (docs/design.md §9, §17)."""

from __future__ import annotations

import bpy

from ..scpainter_blender.scene import kinds
from ..scpainter_blender.scene import rig as rig_scene
from . import reports, selection


_ITEMS: list = []  # Blender keeps no reference to a dynamic enum's strings: they live here


def _preset_items(self, context):
    _ITEMS[:] = rig_scene.preset_items(context.scene if context else None)
    return _ITEMS


class SCPAINTER_OT_add_camera_rig(bpy.types.Operator):
    """Add a camera rig following the active camera path: one camera per sensor of the preset (and its LiDAR),
    mounted on the ego vehicle the path drives; its job renders every camera"""

    bl_idname = "scpainter.add_camera_rig"
    bl_label = "Add Camera Rig"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(name="Rig", items=_preset_items,
                                   description="The cameras (and LiDAR) to mount: a preset, or the recording's own")
    scale: bpy.props.FloatProperty(name="Scale", default=rig_scene.DEFAULT_SCALE, min=0.01, max=4.0,
                                   soft_min=0.1, soft_max=1.0,
                                   description="Every camera's resolution times this (nuScenes: 1.0 is 1600 x 900; "
                                               "0.25 renders quickly)")
    lidar: bpy.props.BoolProperty(name="LiDAR", default=True, description="Mount the rig's top LiDAR (the "
                                                                          "nuScenes 32-beam one for a preset)")

    @classmethod
    def poll(cls, context):
        if rig_scene.target_camera(context) is None:
            cls.poll_message_set("Make a camera path first (New Camera Path): a rig follows one")
            return False
        return True

    @reports.reported
    def execute(self, context):
        cam = rig_scene.target_camera(context)
        replaced = kinds.rig_of(cam) is not None
        rig = rig_scene.make_rig(context.scene, self.preset, lidar=self.lidar, scale=self.scale)
        empty = rig_scene.add_rig(cam, rig)
        selection.select_only(context, empty)
        W, H = rig.cameras[0].resolution
        self.report({"INFO"}, f"{'Replaced the rig of' if replaced else 'Added a rig to'} {cam.name!r}: "
                              f"{len(rig.cameras)} cameras ({W} x {H})"
                              f"{' and ' + rig.lidar.name if rig.lidar else ''}, {cam.name!r} is "
                              f"{rig_scene.follow_camera(rig)}")
        return {"FINISHED"}


class SCPAINTER_OT_remove_camera_rig(bpy.types.Operator):
    """Remove the camera rig of the active camera path: its jobs render that one camera again"""

    bl_idname = "scpainter.remove_camera_rig"
    bl_label = "Remove Camera Rig"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if kinds.rig_of(rig_scene.target_camera(context)) is None:
            cls.poll_message_set("The active camera path has no camera rig")
            return False
        return True

    @reports.reported
    def execute(self, context):
        cam = rig_scene.target_camera(context)
        rig_scene.remove_rig(kinds.rig_of(cam))
        self.report({"INFO"}, f"Removed the camera rig of {cam.name!r}")
        return {"FINISHED"}


classes = (SCPAINTER_OT_add_camera_rig, SCPAINTER_OT_remove_camera_rig)
