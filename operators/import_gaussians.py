"""File > Import > SCPainter Car Asset: a Gaussian-splat or mesh car as an object to place."""

from __future__ import annotations

import bpy
from bpy_extras.io_utils import ImportHelper

from ..scpainter_blender.core.splats import formats
from ..scpainter_blender.runs import preferences
from ..scpainter_blender.scene import gaussians, kinds
from . import reports, selection

AXES_ITEMS = [("TRELLIS", "TRELLIS / Amodal3R", "Undo their (x, -z, y) file axes"),
              ("NONE", "As Stored", "Use the file's axes as Z-up")]


#: The import's tooltip: the Gaussian formats named from their records (core/splats/formats.py).
DESCRIPTION = ("Import a car asset at the 3D cursor: Gaussian splats ("
               + "; ".join(f.name + (", converted by the backend" if f.needs_backend else "") for f in formats.FORMATS)
               + ") or a mesh (GLB, glTF, OBJ, STL, mesh PLY; turned into surface Gaussians by the backend)")


class SCPAINTER_OT_import_gaussians(bpy.types.Operator, ImportHelper):
    """Import a car asset at the 3D cursor (the tooltip, ``DESCRIPTION``, names the formats)"""

    bl_idname = "scpainter.import_gaussians"
    bl_label = "Import Car Asset"
    bl_description = DESCRIPTION
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".ply"
    filter_glob: bpy.props.StringProperty(default=gaussians.FILE_FILTER, options={"HIDDEN"})
    axes: bpy.props.EnumProperty(
        name="Axes", default="AUTO",
        items=[("AUTO", "Auto", "TRELLIS/Amodal3R axes for files in their layout and unit cube, else as stored")]
        + AXES_ITEMS)
    target_length: bpy.props.FloatProperty(
        name="Length", default=0.0, min=0.0, unit="LENGTH",
        description="Scale to this length along the longest horizontal axis (0: 4.5 m for unit-cube assets, "
                    "file units otherwise)")
    ellipsoids: bpy.props.BoolProperty(name="Ellipsoids", default=False,
                                       description="Preview as oriented ellipsoids (slower) instead of sprites")
    mesh_count: bpy.props.IntProperty(
        name="Mesh Gaussians", default=gaussians.DEFAULT_MESH_COUNT, min=100, soft_max=2_000_000,
        description="Meshes only: how many flat Gaussians to sample on the surface (more: a closer silhouette)")

    @reports.reported
    def execute(self, context):
        prefs = preferences.get(context)
        r = gaussians.import_gaussians(context, self.filepath, self.axes, self.target_length or None,
                                       self.ellipsoids, mesh_count=self.mesh_count,
                                       backend_python=preferences.python(prefs))
        selection.select_only(context, r.object)
        self.report({"INFO"}, r.report())
        for w in r.warnings:
            self.report({"WARNING"}, w)
        return {"FINISHED"}


class SCPAINTER_OT_set_asset_axes(bpy.types.Operator):
    """Re-read the active asset with other file axes (when Auto chose wrong: a car lying on its side)"""

    bl_idname = "scpainter.set_asset_axes"
    bl_label = "Set Asset Axes"
    bl_options = {"REGISTER", "UNDO"}

    axes: bpy.props.EnumProperty(name="Axes", items=AXES_ITEMS)

    @classmethod
    def poll(cls, context):
        return kinds.is_kind(context.active_object, kinds.GAUSSIAN_ASSET)

    @reports.reported
    def execute(self, context):
        gaussians.set_axes(context.active_object, self.axes)
        return {"FINISHED"}


class SCPAINTER_FH_gaussians(bpy.types.FileHandler):
    """Drag a car asset (splats or a mesh) into the 3D viewport to import it."""

    bl_idname = "SCPAINTER_FH_gaussians"
    bl_label = "SCPainter car asset"
    bl_import_operator = "scpainter.import_gaussians"
    bl_file_extensions = ";".join(gaussians.ASSET_EXTENSIONS)

    @classmethod
    def poll_drop(cls, context):
        return context.area is not None and context.area.type == "VIEW_3D"


def menu_import(self, context):
    self.layout.operator(SCPAINTER_OT_import_gaussians.bl_idname, text="SCPainter Car Asset (.ply, .splat, .sog, mesh)")


classes = (SCPAINTER_OT_import_gaussians, SCPAINTER_OT_set_asset_axes, SCPAINTER_FH_gaussians)
