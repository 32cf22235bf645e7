"""File > Import > SCPainter VGGT (.npz): the reconstruction as coloured points plus the recorded camera."""

from __future__ import annotations

import bpy
from bpy_extras.io_utils import ImportHelper

from ..scpainter_blender.scene import importer
from . import reports, selection


class SCPAINTER_OT_import_vggt(bpy.types.Operator, ImportHelper):
    """Import a VGGT predictions.npz as coloured points and the recorded camera, at metric scale"""

    bl_idname = "scpainter.import_vggt"
    bl_label = "Import VGGT Reconstruction"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".npz"
    filter_glob: bpy.props.StringProperty(default="*.npz", options={"HIDDEN"})
    confidence_percentile: bpy.props.FloatProperty(
        name="Confidence Percentile", default=50.0, min=0.0, max=100.0, subtype="PERCENTAGE",
        description="Drop the points below this percentile of the clip's confidence (VGGT demo semantics)")
    point_source: bpy.props.EnumProperty(
        name="Points From", default="depth",
        items=[("depth", "Depth", "Unproject the depth maps with each frame's camera (VGGT's recommended branch)"),
               ("world_points", "Point Map", "VGGT's world_points head")])
    scale_mode: bpy.props.EnumProperty(
        name="Metric Scale", default="FACTOR",
        items=[("FACTOR", "Factor", "Metres per VGGT unit"),
               ("TRAJECTORY", "Metric Trajectory", "Fit the camera path to a metric one (Umeyama)"),
               ("CAMERA_HEIGHT", "Camera Height", "Known camera height over the road: RANSAC ground plane in the "
                                                     "lower image rows, scale = height / camera-to-plane distance")])
    scale_factor: bpy.props.FloatProperty(name="Scale Factor", default=1.0, min=1e-6, soft_max=1000.0,
                                          description="Metres per VGGT unit")
    trajectory_path: bpy.props.StringProperty(name="Trajectory", subtype="FILE_PATH",
                                              description="Metric camera path (.npz world_to_camera, xyz or TUM text)")
    camera_height: bpy.props.FloatProperty(name="Camera Height", default=1.6, min=0.01, unit="LENGTH",
                                           description="Height of the camera over the road, metres (the road "
                                                       "must show in the lower part of the images)")
    point_radius: bpy.props.FloatProperty(name="Point Radius", default=0.03, min=0.0, unit="LENGTH")
    current_frame_only: bpy.props.BoolProperty(name="Current Frame Only", default=False,
                                               description="Show only the points of the current frame (± window)")
    frame_window: bpy.props.IntProperty(name="Frame Window", default=0, min=0)
    extrinsic_convention: bpy.props.EnumProperty(
        name="Extrinsic Convention", default="auto",
        items=[("auto", "Auto (Check)", "VGGT's world-to-camera, checked against the file's world_points: a file "
                                        "holding camera-to-world poses is refused with a message"),
               ("world_to_camera", "World to Camera", "The extrinsic maps world to camera (VGGT's own output); "
                                                      "not checked"),
               ("camera_to_world", "Camera to World", "The extrinsic holds camera poses (camera to world), as some "
                                                      "tools around VGGT save them; inverted, not checked")])
    crop: bpy.props.StringProperty(
        name="Crop", default="auto",
        description="Borders to leave out, in pixels: 'auto' (the white padding of VGGT's pad preprocessing), "
                    "'none', or 'left top right bottom'. The camera's principal point and resolution follow")
    depth_edge_ratio: bpy.props.FloatProperty(
        name="Depth Edge Ratio", default=importer.DEPTH_EDGE_RATIO or 0.0, min=0.0, max=100.0, soft_max=0.5,
        precision=3, step=1,
        description="Drop pixels whose depth jumps by more than this fraction of their own depth to one of their 8 "
                    "neighbours: VGGT's \"flying pixels\", smeared across depth edges, which show as streaks from a "
                    "shifted camera. 0 turns it off. The exported job renders with the same setting")

    def draw(self, context):
        col = self.layout.column()
        col.use_property_split = True
        for name in ("confidence_percentile", "depth_edge_ratio", "point_source", "scale_mode"):
            col.prop(self, name)
        col.prop(self, {"FACTOR": "scale_factor", "TRAJECTORY": "trajectory_path",
                        "CAMERA_HEIGHT": "camera_height"}[self.scale_mode])
        for name in ("extrinsic_convention", "crop", "point_radius", "current_frame_only", "frame_window"):
            col.prop(self, name)

    @reports.reported
    def execute(self, context):
        opts = importer.ImportOptions(
            confidence_percentile=self.confidence_percentile, point_source=self.point_source,
            scale_mode=self.scale_mode, scale_factor=self.scale_factor, trajectory_path=self.trajectory_path,
            camera_height=self.camera_height,
            point_radius=self.point_radius, current_frame_only=self.current_frame_only,
            frame_window=self.frame_window, frame_start=context.scene.frame_start,
            extrinsic_convention=self.extrinsic_convention, crop=self.crop,
            # the property is float32 (0.05 reads 0.0500000007): back to the decimal typed (6 digits survive float32)
            depth_edge_ratio=float(f"{self.depth_edge_ratio:.6g}"))
        result = importer.import_vggt(context, self.filepath, opts)  # InputError: reported by @reports.reported
        for w in result.warnings:
            self.report({"WARNING"}, w)
        for line in result.load_report.info:
            self.report({"INFO"}, line)
        selection.select_only(context, result.points)
        _show_attribute_colours(context)
        fit = result.fit
        edges = "depth-edge test off" if result.depth_edge_ratio is None else \
            f"{result.depth_edge_points:,} on depth edges left out (ratio {result.depth_edge_ratio:g})"
        self.report({"INFO"}, f"Imported {result.num_points:,} points ({edges}) and {result.camera.name!r} in "
                              f"{result.timings['total']:.2f} s; scale {fit.scale:.4g} m/unit ({fit.method}, "
                              f"residual {fit.residual_m:.3g} m)")
        return {"FINISHED"}


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


classes = (SCPAINTER_OT_import_vggt, SCPAINTER_FH_vggt)
