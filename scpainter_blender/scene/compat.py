"""The few Blender APIs that moved between 4.2 and 5.0, each behind one helper (docs/design.md §6).

* Keyframes: from 4.4 they live in action slots and channelbags, and ``Action.fcurves`` is gone in 5.0 (``fcurves``
  reads them, ``new_action_fcurves`` makes them; ``Object.keyframe_insert`` is the same in every version). The
  channelbag is reached through the RNA calls of 4.4+ (``Action.layers``, ``ActionLayer.strips``,
  ``ActionKeyframeStrip.channelbag``), not ``bpy_extras.anim_utils.action_ensure_channelbag_for_slot``, which 4.5
  LTS does not have (it came in 5.0).
* Node trees: before 5.0 a new material or world has none until ``use_nodes`` is set (deprecated in 5.0).
"""

from __future__ import annotations

import bpy

#: Actions with slots and channelbags (4.4+).
HAS_ACTION_SLOTS = bpy.app.version >= (4, 4, 0)

_INTERPOLATION = {"CONSTANT": 0, "LINEAR": 1, "BEZIER": 2}


def node_tree(id_data, clear: bool = False):
    """The node tree of a material or world, created the way this Blender version needs."""
    if id_data.node_tree is None:
        id_data.use_nodes = True
    if clear:
        id_data.node_tree.nodes.clear()
    return id_data.node_tree


def _channelbag(action, slot, ensure: bool):
    """The channelbag of ``slot`` in ``action`` (4.4+): the first one found in its layers' strips, or, with
    ``ensure``, made in its first keyframe strip (layer and strip made when missing, as Blender's own key insertion
    does); None when there is none and ``ensure`` is false."""
    if not ensure:
        for layer in action.layers:
            for strip in layer.strips:
                bag = strip.channelbag(slot)
                if bag is not None:
                    return bag
        return None
    layer = action.layers[0] if len(action.layers) else action.layers.new("Layer")
    strip = layer.strips[0] if len(layer.strips) else layer.strips.new(type="KEYFRAME")
    return strip.channelbag(slot, ensure=True)


def new_action_fcurves(id_data, action_name: str):
    """A fresh action assigned to ``id_data``; returns the collection to create its F-curves in."""
    ad = id_data.animation_data or id_data.animation_data_create()
    action = bpy.data.actions.new(action_name)
    ad.action = action
    if HAS_ACTION_SLOTS:
        slot = action.slots.new(id_type=id_data.id_type, name=id_data.name)
        ad.action_slot = slot
        return _channelbag(action, slot, ensure=True).fcurves
    return action.fcurves


def object_fcurves(id_data, action_name: str):
    """The collection of F-curves ``id_data``'s animation is keyed in: its action's (from 4.4 the channelbag of its
    assigned slot, made when missing), or a fresh action's (``new_action_fcurves``) when it has none. Unlike
    ``new_action_fcurves`` the curves it already has are kept."""
    ad = id_data.animation_data
    if ad is None or ad.action is None:
        return new_action_fcurves(id_data, action_name)
    if not HAS_ACTION_SLOTS:
        return ad.action.fcurves
    slot = ad.action_slot
    if slot is None:
        slot = ad.action.slots.new(id_type=id_data.id_type, name=id_data.name)
        ad.action_slot = slot
    return _channelbag(ad.action, slot, ensure=True).fcurves


def fcurves(id_data) -> list:
    """The F-curves of the action animating ``id_data`` (from 4.4 those of its action slot's channelbag); [] when it
    has no action (or no slot, or nothing keyed in it)."""
    ad = id_data.animation_data
    action = ad.action if ad is not None else None
    if action is None:
        return []
    if HAS_ACTION_SLOTS:
        if ad.action_slot is None:
            return []
        bag = _channelbag(action, ad.action_slot, ensure=False)
        return list(bag.fcurves) if bag is not None else []
    return list(action.fcurves)


def key_fcurve(fcurves, data_path: str, index: int, frames, values, interpolation: str = "LINEAR"):
    """One F-curve with a key at each frame, written in bulk with foreach_set (no per-key Python)."""
    import numpy as np

    frames = np.asarray(frames, dtype=np.float32)
    values = np.asarray(values, dtype=np.float32)
    fc = fcurves.new(data_path, index=index)
    kp = fc.keyframe_points
    kp.add(len(frames))
    kp.foreach_set("co", np.stack([frames, values], axis=1).ravel())
    kp.foreach_set("interpolation", np.full(len(frames), _INTERPOLATION[interpolation], dtype=np.int32))
    fc.update()
    return fc
