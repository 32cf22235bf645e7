"""File paths the add-on stores in a .blend, kept relative to it (Blender's ``//`` convention), so a project folder
that moves or is copied reads its own files, never the old folder's (docs/design.md §9).

The custom properties holding a path (``PATH_KEYS``: the file an object was imported from, the mesh or SOG it was
converted from) are written by ``stored``: ``//``-relative to the saved .blend when Blender's preference *File Paths >
Default > Relative Paths* is on (its default) and the file is reachable by a relative path (not on another drive),
else absolute (an unsaved .blend has nothing to be relative to). When the .blend is saved (``save_pre``) every such
value is rewritten for the file's new location: absolute ones become relative under the same rule (a scene imported
before its first save), relative ones are remapped when *Save As* moves the .blend, as Blender remaps its own
relative paths; a *Save Copy* puts the values back for the open file after writing the copy (``save_post``). Readers
go through ``resolve``: an absolute, normalised path.
"""

from __future__ import annotations

import os

import bpy
from bpy.app.handlers import persistent

from . import keys

#: The object custom properties that hold a file path.
PATH_KEYS = (keys.SOURCE, keys.MESH_SOURCE, keys.SPLAT_SOURCE)


def relative_paths_preferred() -> bool:
    """Blender's *Default > Relative Paths* preference (on unless the user turned it off)."""
    return bool(bpy.context.preferences.filepaths.use_relative_paths)


def resolve(value: str, blend_path: str | None = None) -> str:
    """The absolute, normalised path of a stored ``value`` (``//`` relative to ``blend_path``, default the open
    .blend's; any other value as it is)."""
    blend_path = bpy.data.filepath if blend_path is None else blend_path
    if value.startswith("//"):
        value = os.path.join(os.path.dirname(blend_path), value[2:])
    return os.path.normpath(os.path.abspath(value))


def stored(path: str, blend_path: str | None = None, relative: bool | None = None) -> str:
    """What to store for the file ``path`` in a .blend at ``blend_path`` (default the open one; "" unsaved):
    ``//``-relative when ``relative`` (default: ``relative_paths_preferred``) and the .blend is saved and a relative
    path reaches the file, else the absolute path."""
    path = resolve(path, blend_path)
    blend_path = bpy.data.filepath if blend_path is None else blend_path
    relative = relative_paths_preferred() if relative is None else relative
    if not (relative and blend_path):
        return path
    try:
        return "//" + os.path.relpath(path, os.path.dirname(os.path.abspath(blend_path))).replace(os.sep, "/")
    except ValueError:  # another drive (Windows): no relative path reaches it
        return path


def relative_to(path: str, folder: str) -> str:
    """``path`` relative to ``folder`` (how a job names its files: relative to the job file), or absolute when no
    relative path reaches it (another drive)."""
    try:
        return os.path.relpath(path, folder)
    except ValueError:
        return os.path.abspath(path)


def _path_values():
    """(object, key, value) for every path property of every object in the .blend."""
    for obj in bpy.data.objects:
        for key in PATH_KEYS:
            value = obj.get(key)
            if isinstance(value, str) and value:
                yield obj, key, value


def remap(new_blend_path: str, old_blend_path: str | None = None) -> dict:
    """Rewrite every path property for a .blend saved at ``new_blend_path`` (module docstring); returns
    {(object name, key): absolute path} as they were, for ``restore``."""
    relative = relative_paths_preferred()
    before = {}
    for obj, key, value in _path_values():
        absolute = resolve(value, old_blend_path)
        before[(obj.name, key)] = absolute
        obj[key] = stored(absolute, new_blend_path, relative or value.startswith("//"))
    return before


def restore(before: dict, blend_path: str) -> None:
    """Put back the values ``remap`` changed, stored for the .blend at ``blend_path``."""
    relative = relative_paths_preferred()
    for (name, key), absolute in before.items():
        obj = bpy.data.objects.get(name)
        if obj is not None and key in obj:
            obj[key] = stored(absolute, blend_path, relative)


_saving: dict = {}


@persistent
def save_pre(filepath: str = "", *_args) -> None:
    """Blender's ``save_pre`` handler: the path properties written for the file being saved (``filepath``)."""
    if filepath:
        _saving["before"] = remap(filepath)
        _saving["path"] = filepath


@persistent
def save_post(filepath: str = "", *_args) -> None:
    """Blender's ``save_post`` handler: after *Save Copy* (the open .blend is still the old one) the values go back
    to the open file's."""
    before = _saving.pop("before", None)
    _saving.pop("path", None)
    if before is not None and filepath and os.path.abspath(bpy.data.filepath) != os.path.abspath(filepath):
        restore(before, bpy.data.filepath)


def register() -> None:
    for handlers, fn in ((bpy.app.handlers.save_pre, save_pre), (bpy.app.handlers.save_post, save_post)):
        if fn not in handlers:
            handlers.append(fn)


def unregister() -> None:
    for handlers, fn in ((bpy.app.handlers.save_pre, save_pre), (bpy.app.handlers.save_post, save_post)):
        if fn in handlers:
            handlers.remove(fn)
