"""*Drive Along Lane*: key the active car driving along the recorded drive (scene/drive_lane.py)."""

from __future__ import annotations

import bpy

from ..scpainter_blender.scene import drive_lane, kinds
from . import reports


class SCPAINTER_OT_drive_along_lane(bpy.types.Operator):
    """Key the active car driving along the recorded drive in a lane at a speed, standing on the road at every
    frame (as the variations' moving cars)"""

    bl_idname = "scpainter.drive_along_lane"
    bl_label = "Drive Along Lane"
    bl_options = {"REGISTER", "UNDO"}

    lane_offset: bpy.props.FloatProperty(
        name="Lane Offset", default=0.0, min=-50.0, max=50.0, unit="LENGTH",
        description="Metres left of the recorded drive's direction (negative: right). From the panel it starts "
                    "where the car stands at the start frame")
    speed: bpy.props.FloatProperty(
        name="Speed", default=8.0, min=-70.0, max=70.0, unit="VELOCITY",
        description="Metres per second along the drive; 0 stands still in the lane, negative drives against the "
                    "drive's direction (oncoming)")
    start_frame: bpy.props.IntProperty(
        name="Start Frame", default=1,
        description="The frame the car starts from where it stands (from the panel: the scene's first frame); "
                    "before it the car holds its start pose")

    @classmethod
    def poll(cls, context):
        if not kinds.is_kind(context.active_object, kinds.GAUSSIAN_ASSET):
            cls.poll_message_set("Select a Gaussian car asset (File > Import > SCPainter Gaussian Asset)")
            return False
        return True

    @reports.reported_invoke
    def invoke(self, context, event):
        if not self.properties.is_property_set("start_frame"):
            self.start_frame = context.scene.frame_start
        if not self.properties.is_property_set("lane_offset"):  # keep the lane the artist put it in
            self.lane_offset = round(drive_lane.lane_where_it_stands(context, context.active_object,
                                                                     self.start_frame), 2)
        return self.execute(context)

    @reports.reported
    def execute(self, context):
        asset = context.active_object
        drive = drive_lane.drive_along_lane(context, asset, self.lane_offset, self.speed, self.start_frame)
        level, text = drive_lane.summary(asset, drive, self.lane_offset, self.speed)
        self.report({level}, text)
        return {"FINISHED"}


classes = (SCPAINTER_OT_drive_along_lane,)
