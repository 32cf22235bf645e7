"""The selected assets' boxes (labels' 3D boxes, scene/asset_box.py): estimate again, flip the front."""

from __future__ import annotations

import bpy

from ..scpainter_blender.scene import asset_box
from . import reports


def _assets(context) -> list:
    """The assets the selection stands for (an asset, its box or its front arrow), the active object's first."""
    return asset_box.assets_among([context.active_object, *context.selected_objects])


class _BoxOperator:
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not _assets(context):
            cls.poll_message_set("Select a Gaussian car asset or its box")
            return False
        return True


class SCPAINTER_OT_estimate_asset_box(_BoxOperator, bpy.types.Operator):
    """Estimate the selected assets' 3D boxes from their Gaussians again (replaces an edited box)"""

    bl_idname = "scpainter.estimate_asset_box"
    bl_label = "Estimate Box"
    bl_options = {"REGISTER", "UNDO"}

    @reports.reported
    def execute(self, context):
        assets = _assets(context)
        made = [a.name for a in assets if asset_box.estimate(a) is not None]
        missing = [a.name for a in assets if a.name not in made]
        self.report({"WARNING"} if missing else {"INFO"}, f"Estimated the box of {', '.join(made) or 'none'}"
                    + (f"; too few Gaussians for a box: {', '.join(missing)}" if missing else ""))
        return {"FINISHED"}


class SCPAINTER_OT_flip_asset_front(_BoxOperator, bpy.types.Operator):
    """Turn the selected assets' boxes 180° about their up axis: the front (the arrow) becomes the back"""

    bl_idname = "scpainter.flip_asset_front"
    bl_label = "Flip Front"
    bl_options = {"REGISTER", "UNDO"}

    @reports.reported
    def execute(self, context):
        assets = _assets(context)
        flipped = [a.name for a in assets if asset_box.flip(a)]
        if not flipped:
            self.report({"ERROR"}, "the selected assets have no box: Estimate Box first")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Flipped the front of {', '.join(flipped)}")
        return {"FINISHED"}


classes = (SCPAINTER_OT_estimate_asset_box, SCPAINTER_OT_flip_asset_front)
