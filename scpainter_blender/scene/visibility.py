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

Collection instances (``rendered_placements``): an empty with ``instance_type`` 'COLLECTION' that renders draws every
object of its ``instance_collection`` that renders there, as Blender's dupli code does (``make_duplis_collection``):
the instanced collection's objects and those of its child collections, each once, unless the object is
``hide_render`` or a collection on its way down (the instanced one included) is disabled in renders; the view
layer's Exclude does not apply inside an instance, so a car whose source collection is excluded still renders
through its instances. The drawn object's world matrix is the instancer's ``matrix_world`` · translation(−the
collection's ``instance_offset``) · the object's own ``matrix_world``, composed for nested instances outermost first,
at most ``MAX_INSTANCE_DEPTH`` deep (Blender's ``MAX_DUPLI_RECUR``). Tested against the depsgraph's
``object_instances``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kinds
from .props import SceneError

#: How deep collection instances nest before Blender stops following them (``MAX_DUPLI_RECUR`` in BKE's duplis).
MAX_INSTANCE_DEPTH = 8


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


@dataclass(frozen=True)
class Placed:
    """One object as the render draws it: ``obj`` itself (``chain`` empty) or through the collection-instance empties
    ``chain`` (outermost first); ``name`` is unique among a job's drawings (``rendered_placements``)."""

    obj: object
    chain: tuple
    name: str

    def matrix_world(self) -> np.ndarray:
        """(4, 4) float64 object-to-world matrix of the drawn object at the scene's current (evaluated) frame."""
        m = np.eye(4)
        for empty in self.chain:
            offset = np.eye(4)
            offset[:3, 3] = -np.array(empty.instance_collection.instance_offset, dtype=np.float64)
            m = m @ np.array(empty.matrix_world, dtype=np.float64) @ offset
        return m @ np.array(self.obj.matrix_world, dtype=np.float64)


def instancing(obj) -> bool:
    """Whether ``obj`` draws a collection (an empty with ``instance_type`` 'COLLECTION' and a collection set)."""
    return obj.instance_type == "COLLECTION" and obj.instance_collection is not None


def instanced_objects(collection) -> list:
    """The objects a collection instance of ``collection`` draws (module docstring): those of ``collection`` and its
    child collections, each once, not ``hide_render``, reached through collections none of which is disabled in
    renders (``collection`` itself included); the view layer's Exclude does not apply."""
    out, seen = [], set()
    stack = [collection]
    while stack:
        c = stack.pop(0)
        if c.hide_render:
            continue
        for o in c.objects:
            if o not in seen and not o.hide_render:
                seen.add(o)
                out.append(o)
        stack.extend(c.children)
    return out


def rendered_placements(objects, view_layer) -> list:
    """Every drawing of ``objects`` that the render of ``view_layer`` makes, as ``Placed``: each of ``objects`` that
    renders itself (``rendered``, in their order; named by its name), then each drawn through a collection instance
    (instancers that render, in name order, nested instances followed ``MAX_INSTANCE_DEPTH`` deep; named by the
    instancers' names and its own joined by "/": "Cars.001/Pair/car_01"). A name drawn twice (one object reached
    twice through one instancer) gets " #2", " #3"."""
    wanted = set(objects)
    found = [(o, ()) for o in rendered(objects, view_layer)]
    top = sorted({o for c in included_collections(view_layer) for o in c.objects
                  if not o.hide_render and instancing(o)}, key=lambda o: o.name)

    def walk(chain):
        if len(chain) > MAX_INSTANCE_DEPTH:
            return
        for o in instanced_objects(chain[-1].instance_collection):
            if o == chain[-1]:  # an instancer inside the collection it draws does not draw itself (as Blender)
                continue
            if o in wanted:
                found.append((o, tuple(chain)))
            if instancing(o):
                walk(chain + [o])

    for empty in top:
        walk([empty])
    out, counts = [], {}
    for o, chain in found:
        name = "/".join([e.name for e in chain] + [o.name])
        counts[name] = counts.get(name, 0) + 1
        out.append(Placed(o, chain, name if counts[name] == 1 else f"{name} #{counts[name]}"))
    return out
