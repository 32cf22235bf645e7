"""Export the scene as job.json, the backend's input (docs/design.md §4.2)."""

from __future__ import annotations

import bpy

from ..scpainter_blender.core.output_layout import OutputLayout
from ..scpainter_blender.runs import preferences
from ..scpainter_blender.scene import job_export, props
from . import reports


class SCPAINTER_OT_export_job(bpy.types.Operator):
    """Write job.json for the frame range and the active camera into that camera's output folder"""

    bl_idname = "scpainter.export_job"
    bl_label = "Export Job"
    bl_options = {"REGISTER"}

    filepath: bpy.props.StringProperty(name="Job File", subtype="FILE_PATH", default="",
                                       description="Where to write job.json (empty: the scene camera's output folder)")

    @reports.reported
    def execute(self, context):
        path = bpy.path.abspath(self.filepath) if self.filepath else \
            OutputLayout(props.camera_output_dir(context.scene)).job
        prefs = preferences.get(context)
        job = job_export.export_job(context, path, checkpoint=bpy.path.abspath(prefs.checkpoint_dir)
                                    if prefs and prefs.checkpoint_dir else "")
        for w in job_export.warnings(context):  # written all the same: the artist may mean it
            self.report({"WARNING"}, w["message"])
        self.report({"INFO"}, f"Wrote {path}: {len(job.frames)} frames, {len(job.assets)} assets")
        return {"FINISHED"}


classes = (SCPAINTER_OT_export_job,)
