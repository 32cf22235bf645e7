"""bpy operators: thin wrappers that read the context, call scpainter_blender, and report."""

from . import import_vggt

classes = (*import_vggt.classes,)
