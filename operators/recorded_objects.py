"""Recorded objects: File > Import > SCPainter Recorded Objects (a drive's tracked 3D boxes added to the imported
reconstruction, scene/recorded_objects.py) and a removal box from a recorded object (for *Replace Car*)."""

from __future__ import annotations

import bpy
from bpy_extras.io_utils import ImportHelper

from ..scpainter_blender.core import import_options
from ..scpainter_blender.scene import kinds, recorded_objects, visibility
from . import reports, selection


def _option(name):
    """The import option ``name`` (``core.import_options.OPTIONS``) as a bpy property."""
    kind, keywords = import_options.blender_properties()[name]
    return getattr(bpy.props, kind)(**keywords)


class SCPAINTER_OT_import_recorded_objects(bpy.types.Operator, ImportHelper):
    """Import a drive's tracked 3D boxes (nuScenes tables, KITTI tracking label_02, OpenLABEL or scpainter.objects/1
    JSON) as recorded objects of the imported reconstruction, mapped through its recorded camera"""

    bl_idname = "scpainter.import_recorded_objects"
    bl_label = "Import Recorded Objects"
    bl_options = {"REGISTER", "UNDO"}

    filter_glob: bpy.props.StringProperty(default="*.json;*.txt", options={"HIDDEN"})
    objects_format: _option("objects_format")
    objects_scene: _option("objects_scene")
    objects_camera: _option("objects_camera")

    @classmethod
    def poll(cls, context):
        if kinds.point_cloud(context.scene) is None:
            cls.poll_message_set("Import a VGGT reconstruction first: the objects are placed through its camera")
            return False
        return True

    @reports.reported
    def execute(self, context):
        made, warnings = recorded_objects.import_file(context, self.filepath, self.objects_format,
                                                      self.objects_scene, self.objects_camera)
        for w in warnings:
            self.report({"WARNING"}, w)
        if made:
            selection.select_only(context, made[0])
        moving = sum(1 for o in made if o.animation_data is not None)
        self.report({"INFO"}, f"Imported {len(made)} recorded objects ({moving} moving) into "
                              f"{recorded_objects.COLLECTION!r}")
        return {"FINISHED"}


class SCPAINTER_OT_removal_box_from_recorded(bpy.types.Operator):
    """Add a removal box around each selected recorded object (its box at the current frame): the recorded car's
    points are removed, and an asset can replace it (Replace Car)"""

    bl_idname = "scpainter.removal_box_from_recorded"
    bl_label = "Removal Box from Recorded Object"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not recorded_objects.of_selection(context) or kinds.point_cloud(context.scene) is None:
            cls.poll_message_set("Select recorded objects of an imported reconstruction")
            return False
        return True

    @reports.reported
    def execute(self, context):
        pts = visibility.points_object(context.scene, context.view_layer) or kinds.point_cloud(context.scene)
        made = [recorded_objects.removal_box(context, o, pts) for o in recorded_objects.of_selection(context)]
        selection.select_only(context, made[0])
        self.report({"INFO"}, f"{len(made)} removal boxes: {', '.join(b.name for b in made)}")
        return {"FINISHED"}


def menu_import(self, context):
    self.layout.operator(SCPAINTER_OT_import_recorded_objects.bl_idname, text="SCPainter Recorded Objects")


classes = (SCPAINTER_OT_import_recorded_objects, SCPAINTER_OT_removal_box_from_recorded)
