"""File > Import > SCPainter Gaussian Asset (.ply): an Amodal3R / 3DGS car as an object to place."""

from __future__ import annotations

import bpy
from bpy_extras.io_utils import ImportHelper

from ..scpainter_blender.scene import gaussians


class SCPAINTER_OT_import_gaussians(bpy.types.Operator, ImportHelper):
    """Import a 3D Gaussian Splatting PLY (Amodal3R, TRELLIS or INRIA layout) as a car asset at the 3D cursor"""

    bl_idname = "scpainter.import_gaussians"
    bl_label = "Import Gaussian Asset"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".ply"
    filter_glob: bpy.props.StringProperty(default="*.ply", options={"HIDDEN"})
    axes: bpy.props.EnumProperty(
        name="Axes", default="AUTO",
        items=[("AUTO", "Auto", "TRELLIS/Amodal3R axes for unit-cube SH-0 files, else as stored"),
               ("TRELLIS", "TRELLIS / Amodal3R", "Undo their (x, -z, y) file axes"),
               ("NONE", "As Stored", "Use the file's axes as Z-up")])
    target_length: bpy.props.FloatProperty(
        name="Length", default=0.0, min=0.0, unit="LENGTH",
        description="Scale to this length along the longest horizontal axis (0: 4.5 m for unit-cube assets, "
                    "file units otherwise)")
    ellipsoids: bpy.props.BoolProperty(name="Ellipsoids", default=False,
                                       description="Preview as oriented ellipsoids (slower) instead of sprites")

    def execute(self, context):
        try:
            r = gaussians.import_gaussians(context, self.filepath, self.axes, self.target_length or None,
                                           self.ellipsoids)
        except ValueError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        for o in context.view_layer.objects.selected:
            o.select_set(False)
        context.view_layer.objects.active = r.object
        r.object.select_set(True)
        dropped = f", dropped {r.dropped}" if r.dropped else ""
        self.report({"INFO"}, f"Imported {r.count:,} Gaussians as {r.object.name!r} ({r.axes} axes{dropped}) "
                              f"in {r.timings['total']:.2f} s")
        return {"FINISHED"}


class SCPAINTER_FH_gaussians(bpy.types.FileHandler):
    """Drag a Gaussian-splat .ply into the 3D viewport to import it."""

    bl_idname = "SCPAINTER_FH_gaussians"
    bl_label = "SCPainter Gaussian asset"
    bl_import_operator = "scpainter.import_gaussians"
    bl_file_extensions = ".ply"

    @classmethod
    def poll_drop(cls, context):
        return context.area is not None and context.area.type == "VIEW_3D"


def menu_import(self, context):
    self.layout.operator(SCPAINTER_OT_import_gaussians.bl_idname, text="SCPainter Gaussian Asset (.ply)")


classes = (SCPAINTER_OT_import_gaussians, SCPAINTER_FH_gaussians)
