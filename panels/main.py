"""The "SCPainter" tab in the 3D viewport's sidebar."""

from __future__ import annotations

import textwrap

import bpy

from ..scpainter_blender.runs import camera_run
from ..scpainter_blender.scene import asset_box, job_export, keys, kinds, node_groups, points, props
from ..scpainter_blender.scene import rig as rig_scene


class SCPAINTER_PT_main(bpy.types.Panel):
    bl_label = "SCPainter"
    bl_idname = "SCPAINTER_PT_main"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "SCPainter"

    def draw(self, context):
        layout = self.layout
        col = layout.column(align=True)
        col.operator("scpainter.import_vggt", icon="IMPORT")
        col.operator("scpainter.replace_reconstruction", icon="FILE_REFRESH")
        col.operator("scpainter.import_gaussians", icon="IMPORT")
        box = layout.box()
        box.label(text="New Camera Path", icon="CAMERA_DATA")
        row = box.row(align=True)
        for shift in (3.0, 2.0, -2.0, -3.0):  # the paper's lateral shifts; + is left
            label = f"{abs(shift):g} m {'L' if shift > 0 else 'R'}"
            row.operator("scpainter.new_camera_path", text=label).shift = shift
        box.operator("scpainter.new_camera_path", text="Custom Shift...").shift = 1.0
        self.draw_rig(context, layout.box())
        self.draw_assets(context, layout.box())
        box = layout.box()
        box.label(text="Job", icon="FILE")
        box.prop(context.scene, "scpainter_output_dir", text="")
        if context.scene.camera is not None:  # runs write into the camera's own folder inside it
            box.label(text=f"Camera folder: {props.camera_folder_name(context.scene.camera)}/",
                      icon="OUTLINER_OB_CAMERA")
        self.draw_job_warnings(context, box)
        box.operator("scpainter.export_job", icon="EXPORT")
        self.draw_backend(context, box)
        obj = context.active_object
        if not kinds.is_kind(obj, kinds.POINTS, kinds.RECORDED_CAMERA):
            return
        box = layout.box()
        box.label(text=obj.name, icon="POINTCLOUD_DATA" if kinds.is_kind(obj, kinds.POINTS) else "CAMERA_DATA")
        box.label(text=f"Scale: {obj.get(keys.SCALE_METHOD, '?')}, "
                       f"residual {obj.get(keys.SCALE_RESIDUAL_M, 0.0):.3g} m")
        mod = points.points_modifier(obj)
        if mod is not None:
            for name in ("Point Radius", "Current Frame Only", "Frame Window"):
                box.prop(mod, f'["{node_groups.socket_identifier(mod.node_group, name)}"]', text=name)


    @staticmethod
    def draw_rig(context, box):
        """The camera rig of the active camera path (``rig_scene.target_camera``): its cameras (resolution, lens)
        and LiDAR, Remove; or Add Camera Rig with its presets."""
        cam = rig_scene.target_camera(context)
        rig_obj = kinds.rig_of(cam)
        box.label(text="Camera Rig" + (f" of {cam.name}" if cam is not None else ""), icon="OUTLINER_OB_CAMERA")
        if rig_obj is None:
            box.operator_menu_enum("scpainter.add_camera_rig", "preset", text="Add Camera Rig", icon="ADD")
            return
        box.label(text=f"{rig_obj.get(keys.RIG_NAME, 'custom')}: the path is {rig_scene.follow_of(rig_obj)}")
        col = box.column(align=True)
        for c in kinds.rig_sensors(rig_obj, kinds.RIG_CAMERA):
            row = col.row(align=True)
            row.label(text=str(c.get(keys.SENSOR, c.name)), icon="CAMERA_DATA")
            row.prop(c, f'["{keys.RESOLUTION}"]', text="")
            row.prop(c.data, "lens", text="")
        for ld in kinds.rig_sensors(rig_obj, kinds.RIG_LIDAR):
            col.label(text=f"{ld.get(keys.SENSOR, ld.name)}: {ld.get(keys.LIDAR_MODEL, '?')}", icon="LIGHT_POINT")
        row = box.row(align=True)
        row.operator_menu_enum("scpainter.add_camera_rig", "preset", text="Replace", icon="FILE_REFRESH")
        row.operator("scpainter.remove_camera_rig", text="Remove", icon="X")

    @staticmethod
    def draw_job_warnings(context, box):
        """What a job of the scene would get wrong (frames outside the recording) or refuse (two reconstructions
        render), said before anything runs: ``job_export.job_notes``."""
        col = None
        for level, text in job_export.job_notes(context):
            col = col or box.column(align=True)
            for i, line in enumerate(textwrap.wrap(text, 44)):
                col.label(text=line, icon=("CANCEL" if level == "ERROR" else "ERROR") if i == 0 else "BLANK1")

    @staticmethod
    def draw_backend(context, box):
        if camera_run.ACTIVE:
            box.progress(factor=camera_run.progress_fraction(), type="BAR",
                         text=f"{camera_run.progress_text()} (Esc stops)")
        # without a checkpoint Generate makes the inpainting baseline: the button and a note say so
        text, note = camera_run.generate_ui(context)
        row = box.row(align=True)
        row.operator("scpainter.render_conditions", icon="RENDER_STILL")
        row.operator("scpainter.generate", text=text, icon="RENDER_ANIMATION")
        # every camera path, each into its own folder (the buttons grey out, saying why, without one)
        row = box.row(align=True)
        row.operator("scpainter.render_all_camera_paths", text="Render All Paths", icon="RENDER_STILL")
        row.operator("scpainter.generate_all_camera_paths", text=text.replace("Generate", "Generate All Paths"),
                     icon="RENDER_ANIMATION")
        if note:
            col = box.column(align=True)
            for i, line in enumerate(note):
                col.label(text=line, icon="INFO" if i == 0 else "BLANK1")
            col.prop(context.scene, "scpainter_baseline_inpaint", text="Inpainting")
        box.operator_menu_enum("scpainter.export_labels", "format", text="Export Labels", icon="EXPORT")
        box.operator("scpainter.open_output", icon="FILE_FOLDER")
        box.operator("scpainter.make_variations", icon="MOD_ARRAY")

    @staticmethod
    def draw_assets(context, box):
        box.label(text="Car Assets", icon="AUTO")
        col = box.column(align=True)
        col.operator("scpainter.fit_asset")
        col.operator("scpainter.snap_to_ground")
        col.operator("scpainter.add_removal_box")
        col.operator("scpainter.removal_box_from_recorded")
        col.operator("scpainter.replace_car")
        col.operator("scpainter.check_assets")
        col.operator("scpainter.drive_along_lane", icon="AUTO")
        active = context.active_object
        if kinds.is_kind(active, kinds.GAUSSIAN_ASSET):
            row = box.row(align=True)  # how the file's axes were read, and the way to correct it
            row.label(text=f"Axes: {active.get(keys.AXES, '?')}", icon="ORIENTATION_GLOBAL")
            for axes, text in (("TRELLIS", "TRELLIS"), ("NONE", "As Stored")):
                row.operator("scpainter.set_asset_axes", text=text,
                             depress=active.get(keys.AXES) == axes).axes = axes
            if active.get(keys.AXES_REASON):
                box.label(text=active[keys.AXES_REASON])
        owner = kinds.owning_asset(active)  # the asset, or the one whose box (or front arrow) is active
        if owner is not None:  # its label: class and 3D box (the box empty is edited in the viewport)
            if asset_box.CLASS_PROPERTY in owner:
                box.prop(owner, f'["{asset_box.CLASS_PROPERTY}"]', text="Class")
            else:  # imported before classes: the default until the property is added
                box.label(text=f"Class: {asset_box.category(owner)}")
            row = box.row(align=True)
            row.label(text="Box" if kinds.asset_box(owner) is not None else "No box", icon="MESH_CUBE")
            row.operator("scpainter.estimate_asset_box", text="Estimate")
            row.operator("scpainter.flip_asset_front", text="Flip Front")
        icons = {"accepted": "CHECKMARK", "rejected": "X", "unchecked": "QUESTION"}
        box.operator("scpainter.propose_boxes", icon="MESH_CUBE")
        if kinds.is_kind(active, kinds.PROPOSAL):  # its class: the relabel menu acts on the active proposal
            box.operator_menu_enum("scpainter.relabel_proposal", "category", text=f"Class: {active.get(keys.CLASS)}")
        for obj in kinds.objects_of_kind(context.scene, kinds.PROPOSAL):  # each proposal: accept, ignore, reject
            row = box.row(align=True)
            row.label(text=obj.name, icon="QUESTION")
            for action, icon in (("accept", "CHECKMARK"), ("ignore", "HIDE_ON"), ("reject", "X")):
                op = row.operator("scpainter.review_proposal", text="", icon=icon)
                op.name, op.action = obj.name, action
        for obj in kinds.gaussian_assets(context.scene):  # stage 2: a person accepts or rejects each asset
            row = box.row(align=True)
            stage1 = obj.get(keys.STAGE1, "")
            row.label(text=f"{obj.name}{'  (size flagged)' if stage1 == 'flagged' else ''}",
                      icon=icons.get(obj.get(keys.REVIEW, "unchecked"), "QUESTION"))
            for status, icon in (("accepted", "CHECKMARK"), ("rejected", "X")):
                op = row.operator("scpainter.review_asset", text="", icon=icon)
                op.name, op.status = obj.name, status


classes = (SCPAINTER_PT_main,)
