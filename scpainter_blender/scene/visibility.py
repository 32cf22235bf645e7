"""What Blender's render includes, the one rule the job export follows (docs/design.md §9), so a job never renders
an object Blender's own render leaves out.

An object *renders* when it is not ``hide_render`` (Disable in Renders) and at least one of the collections it is
linked into is *included* in the view layer: reached from the view layer's top layer collection through layer
collections none of which is excluded (the checkbox, ``LayerCollection.exclude``, which takes the collections
below with it) and whose collections are not disabled in renders (``Collection.hide_render``, also inherited by the
collections below). A collection linked in two places is included when one of its places is. This is how Cycles
and EEVEE decide; ``LayerCollection.hide_viewport`` and ``Object.hide_viewport`` only change the viewport.

Used for the points object (``points_object``: the one reconstruction the job renders) and the Gaussian assets.
Removal boxes do not go through it: a box is an empty, which never renders, and Blender applies its Geometry
Nodes modifier on the points object whatever the box's own visibility, even from an excluded collection (measured
with bpy 5.0.1), so the boxes that apply are the ones the exported points object's modifiers name
(``placement.applied_removal_boxes``).
"""

from __future__ import annotations

from . import kinds
from .props import SceneError


def included_collections(view_layer) -> set:
    """The collections whose objects ``view_layer`` renders (module docstring): the scene collection and every
    collection below it reached through layer collections neither excluded nor disabled in renders."""
    out = set()
    stack = [view_layer.layer_collection]
    while stack:
        lc = stack.pop()
        if lc.exclude or lc.collection.hide_render:  # both take every collection below with them
            continue
        out.add(lc.collection)
        stack.extend(lc.children)
    return out


def renders(obj, view_layer, included: set | None = None) -> bool:
    """Whether Blender's render of ``view_layer`` includes ``obj``: not ``hide_render``, and linked into a collection
    the view layer includes (``included``: ``included_collections(view_layer)``, passed when asking for many)."""
    if obj.hide_render:
        return False
    included = included_collections(view_layer) if included is None else included
    return any(c in included for c in obj.users_collection)


def rendered(objects, view_layer) -> list:
    """Those of ``objects`` that ``view_layer`` renders, in their order."""
    included = included_collections(view_layer)
    return [o for o in objects if renders(o, view_layer, included)]


def points_object(scene, view_layer):
    """The reconstruction a job renders: the one points object ``view_layer`` renders; None when there is none (no
    reconstruction, or every one hidden from renders). SceneError naming them when more than one renders: the
    job holds one, and taking either would silently drop the other."""
    shown = rendered(kinds.point_clouds(scene), view_layer)
    if len(shown) > 1:
        names = ", ".join(repr(o.name) for o in shown)
        raise SceneError(", ".join(f"objects[{o.name!r}]" for o in shown),
                         f"{len(shown)} reconstructions render ({names}); a job renders one",
                         hint="hide the old one from renders (Object Properties > Visibility > Renders, or exclude its "
                              "collection), or use Replace Reconstruction, which swaps it for the new file")
    return shown[0] if shown else None
