"""SCPainter for Blender: insert realistic cars into recorded drives and re-render them from new camera paths.

register() and unregister() only (docs/design.md §2); everything else lives in scpainter_blender, operators and panels.
"""

import bpy

from . import operators, panels
from .scpainter_blender import cli
from .scpainter_blender.runs import preferences, warm_session
from .scpainter_blender.scene import paths, props

_classes = (*preferences.classes, *operators.classes, *panels.classes)


def register():
    for cls in _classes:
        bpy.utils.register_class(cls)
    props.register()
    paths.register()  # file paths kept relative to the .blend when it is saved
    for draw in operators.menu_import:
        bpy.types.TOPBAR_MT_file_import.append(draw)
    cli.register()


def unregister():
    warm_session.end()  # the session's backend process goes with the add-on (design §12)
    cli.unregister()
    for draw in operators.menu_import:
        bpy.types.TOPBAR_MT_file_import.remove(draw)
    paths.unregister()
    props.unregister()
    for cls in reversed(_classes):
        bpy.utils.unregister_class(cls)
