"""The rig of a multi-camera recording, as the import stored it: read back without bpy.

The import (scene/importer.py) stores the recording's rig (``core.geometry.rig_fit``: the sidecar's extrinsics or the
estimate) on the points object as the JSON text of ``core.rig.Rig.to_dict()`` under ``keys.RECORDING_RIG``; *Add
Camera Rig* offers it as the preset "recording". Objects are anything with ``get`` and ``name`` (Blender objects);
no bpy here.
"""

from __future__ import annotations

import json

from ..core import rig as rig_mod
from ..core.errors import InputError
from . import keys, kinds


def recording_rig(scene, points=None) -> rig_mod.Rig | None:
    """The rig stored with ``points`` (default: the scene's first points object that holds one), or None (a
    single-camera import). A stored rig that is not one (edited by hand) is an InputError naming the object and the
    key."""
    for obj in [points] if points is not None else kinds.point_clouds(scene):
        text = obj.get(keys.RECORDING_RIG) if obj is not None else None
        if not text:
            continue
        where = f"(object {obj.name!r})"
        try:
            d = json.loads(str(text))
        except ValueError as e:  # json's message says where
            raise InputError(where, keys.RECORDING_RIG, f"is not JSON: {e}",
                             hint="import the recording again (its sensors sidecar makes the rig)") from None
        return rig_mod.Rig.from_dict(d, where, keys.RECORDING_RIG)
    return None
