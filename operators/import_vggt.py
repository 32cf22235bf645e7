"""File > Import > SCPainter VGGT (.npz): the reconstruction as coloured points plus the recorded camera; Replace
Reconstruction: a new file in place of the scene's (scene/replace.py). Both take the import options as properties
made from ``core.import_options``."""

from __future__ import annotations

import bpy
from bpy_extras.io_utils import ImportHelper

from ..scpainter_blender.core import import_options
from ..scpainter_blender.scene import importer, kinds, proposals, replace
from ..scpainter_blender.scene.props import SceneError
from . import reports, selection


def _import_option_properties(cls):
    """The import options (``core.import_options.OPTIONS``: defaults, choices, bounds, descriptions) as the class's
    properties, added to its annotations before it is registered."""
    annotations = dict(cls.__dict__.get("__annotations__", {}))
    for name, (kind, keywords) in import_options.blender_properties().items():
        annotations[name] = getattr(bpy.props, kind)(**keywords)
    cls.__annotations__ = annotations
    return cls


@_import_option_properties
class SCPAINTER_OT_import_vggt(bpy.types.Operator, ImportHelper):
    """Import a VGGT predictions.npz as coloured points and the recorded camera, at metric scale"""

    bl_idname = "scpainter.import_vggt"
    bl_label = "Import VGGT Reconstruction"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".npz"
    filter_glob: bpy.props.StringProperty(default="*.npz", options={"HIDDEN"})
    propose_boxes: bpy.props.BoolProperty(
        name="Propose Boxes", default=True,
        description="After the import, propose a box for each object above the road (a parked car) for review "
                    "in the SCPainter tab: accept, relabel, ignore or reject each (about a second)")

    def draw(self, context):
        _draw_options(self)
        self.layout.prop(self, "propose_boxes")

    @reports.reported
    def execute(self, context):
        result = importer.import_vggt(context, self.filepath, _options(self, context))  # InputError: reported
        _report_import(self, context, result)
        if self.propose_boxes:
            try:
                made = proposals.propose(context)
            except SceneError as e:   # no road under the drive (a clip not in metres, a tiny test scene)
                self.report({"INFO"}, f"no box proposals: {e}")
            else:
                if made:
                    self.report({"WARNING"}, f"{len(made)} objects above the road are not labelled: review the "
                                             "box proposals in the SCPainter tab (accept, relabel, ignore, reject)")
        if result.kept_camera is not None:
            self.report({"INFO"}, f"{result.camera.name!r} was added; the camera path {result.kept_camera.name!r} "
                                  "stays the scene camera (make the recorded camera active to look through it)")
        return {"FINISHED"}


@_import_option_properties
class SCPAINTER_OT_replace_reconstruction(bpy.types.Operator, ImportHelper):
    """Import a new VGGT predictions.npz in place of the reconstruction (its points and recorded camera), keeping the
    camera paths, car assets, removal boxes and frame range"""

    bl_idname = "scpainter.replace_reconstruction"
    bl_label = "Replace Reconstruction"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".npz"
    filter_glob: bpy.props.StringProperty(default="*.npz", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        if kinds.point_cloud(context.scene) is None:
            cls.poll_message_set("There is no reconstruction to replace: use Import VGGT Reconstruction")
            return False
        return True

    def draw(self, context):
        _draw_options(self)

    @reports.reported
    def execute(self, context):
        done = replace.replace_reconstruction(context, self.filepath, _options(self, context),
                                              chosen=context.active_object)
        result = done.imported
        _report_import(self, context, result, warnings=done.warnings)
        boxes = f"removal boxes carried over: {', '.join(map(repr, done.boxes))}" if done.boxes else "no removal boxes"
        self.report({"INFO"}, f"{done.replaced!r} replaced (recorded camera: {done.camera or 'none before'!r}); "
                              f"{boxes}; camera paths, assets and the frame range kept")
        return {"FINISHED"}


def _draw_options(op):
    col = op.layout.column()
    col.use_property_split = True
    for name, option in import_options.OPTIONS.items():  # a scale value only with its scale mode
        if option.scale_mode in (None, op.scale_mode):
            col.prop(op, name)


def _options(op, context) -> import_options.ImportOptions:
    """The operator's import options (its properties, made from ``import_options.OPTIONS``)."""
    values = {name: getattr(op, name) for name in import_options.OPTIONS}
    # the property is float32 (0.05 reads 0.0500000007): back to the decimal typed (6 digits survive float32)
    values["depth_edge_ratio"] = float(f"{op.depth_edge_ratio:.6g}")
    return import_options.ImportOptions(**values, frame_start=context.scene.frame_start)


def _report_import(op, context, result, warnings=None):
    """The import's warnings, what the file's reading found, and a summary line; the points selected."""
    for w in result.warnings if warnings is None else warnings:
        op.report({"WARNING"}, w)
    for line in result.load_report.info:
        op.report({"INFO"}, line)
    if result.rig_fit is not None:   # a multi-camera recording: its rig and the spread per sensor
        for line in result.rig_fit.notes + [f.sentence() for f in result.rig_fit.sensors.values()]:
            op.report({"INFO"}, line)
        op.report({"INFO"}, f"{len(result.cameras)} recorded cameras; the rig 'recording' is stored with the points "
                            f"(Add Camera Rig offers it)")
    selection.select_only(context, result.points)
    _show_attribute_colours(context)
    fit = result.fit
    edges = "depth-edge test off" if result.depth_edge_ratio is None else \
        f"{result.depth_edge_points:,} on depth edges left out (ratio {result.depth_edge_ratio:g})"
    op.report({"INFO"}, f"Imported {result.num_points:,} points ({edges}) and {result.camera.name!r} in "
                        f"{result.timings['total']:.2f} s; scale {fit.scale:.4g} m/unit ({fit.method}, "
                        f"residual {fit.residual_m:.3g} m)")


def _show_attribute_colours(context):
    """Solid viewports show the point colours (a no-op in background mode, where there is no screen)."""
    screen = getattr(context, "screen", None)
    for area in screen.areas if screen else ():
        if area.type == "VIEW_3D":
            shading = area.spaces.active.shading
            if shading.type == "SOLID":
                shading.color_type = "VERTEX"  # shown as "Attribute" in the UI


class SCPAINTER_FH_vggt(bpy.types.FileHandler):
    """Drag a predictions .npz into the 3D viewport to import it."""

    bl_idname = "SCPAINTER_FH_vggt"
    bl_label = "SCPainter VGGT"
    bl_import_operator = "scpainter.import_vggt"
    bl_file_extensions = ".npz"

    @classmethod
    def poll_drop(cls, context):
        return context.area is not None and context.area.type == "VIEW_3D"


def menu_import(self, context):
    self.layout.operator(SCPAINTER_OT_import_vggt.bl_idname, text="SCPainter VGGT Reconstruction (.npz)")


classes = (SCPAINTER_OT_import_vggt, SCPAINTER_OT_replace_reconstruction, SCPAINTER_FH_vggt)
