"""The Blender side of the add-on's library: arrays -> Blender objects and back (bpy only, no torch)."""
