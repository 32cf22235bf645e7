"""bpy operators: thin wrappers that read the context, call scpainter_blender, and report."""

from . import import_gaussians, import_vggt

classes = (*import_vggt.classes, *import_gaussians.classes)
menu_import = (import_vggt.menu_import, import_gaussians.menu_import)
