"""bpy operators: thin wrappers that read the context, call scpainter_blender, and report."""

from . import asset_box, backend_run, camera_path, import_gaussians, import_vggt, job, placement, variations
from . import drive_lane, recorded_objects, rig

classes = (*import_vggt.classes, *import_gaussians.classes, *camera_path.classes, *job.classes,
           *placement.classes, *asset_box.classes, *backend_run.classes, *variations.classes)
classes += drive_lane.classes + recorded_objects.classes + rig.classes
menu_import = (import_vggt.menu_import, import_gaussians.menu_import, recorded_objects.menu_import)
