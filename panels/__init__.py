"""bpy panels: draw only."""

from . import main

classes = (*main.classes,)
