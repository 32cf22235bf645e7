"""Box proposals in Blender, for review: the objects of the reconstruction above the road that nothing labels
(``core/variation/proposals.py`` finds them), shown as boxes a person accepts, relabels, ignores or rejects, as the
asset review stages do (docs/design.md §15).

* A proposal is a cube empty of display size ``DISPLAY_SIZE`` = 0.5 (its unit cube is the box, ``placement.
  cube_matrix``; ``matrix_world`` = box_to_world · diag(width, length, height, 1)), kind ``kinds.PROPOSAL``, in the
  collection ``COLLECTION``, with ``keys.TRACK_ID`` (its id, ``proposal_NN``), ``keys.CLASS`` (the class its size
  suggests) and ``keys.PROPOSAL_SCORE``. ``propose`` replaces the scene's proposals with new ones (after an import,
  and from *Propose Boxes*).
* **Accept** makes it a recorded object (the contract of issue 41, the one ``scene/job_export.py`` writes into
  ``scene.recorded_objects``): kind ``kinds.RECORDED_OBJECT``, ``keys.TRACK_ID``, ``keys.CLASS``, ``keys.IGNORE``
  false, in the collection ``RECORDED_COLLECTION``; a static box (no keys: it stands at every frame). **Ignore**
  does the same with ``keys.IGNORE`` true (an ignore region in every export). **Relabel** sets its class (one of
  ``core.categories.NAMES``). **Reject** deletes it.

What covers an object already: the job the scene exports seen from its recorded camera (its recorded objects,
removal boxes, cars' boxes) and the scene's recorded-object boxes themselves.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from ..core import categories
from ..core import job as job_mod
from ..core.variation import proposals as proposals_mod, variants
from . import drive_lane, keys, kinds, placement
from .props import SceneError

DISPLAY_SIZE = 0.5
COLLECTION = "SCPainter Proposals"
#: The collection recorded objects live in (the contract of issue 41).
RECORDED_COLLECTION = "SCPainter Recorded Objects"


def _collection(context, name: str):
    coll = bpy.data.collections.get(name)
    if coll is None:
        coll = bpy.data.collections.new(name)
    if coll.name not in context.scene.collection.children:
        context.scene.collection.children.link(coll)
    return coll


def box_of(obj) -> tuple:
    """(rigid box_to_world (4, 4), size (3,) width, length, height metres) of a proposal or recorded-object empty
    (``placement.box_matrix``)."""
    return placement.box_matrix(obj)


def propose(context) -> list:
    """Replace the scene's proposals with those of its reconstruction along its recorded drive
    (``drive_lane.drive_job``, the road ``drive_lane.road_of`` keeps for the session); returns the new objects.
    SceneError without a recorded camera, a points object or a road under the drive."""
    job, job_path = drive_lane.drive_job(context)
    road = drive_lane.road_of(job, job_path)
    found = proposals_mod.clusters(variants.scene_points(job, job_path), None, road=road)
    scene_objects = kinds.objects_of_kind(context.scene, kinds.RECORDED_OBJECT)
    if scene_objects:   # the scene's own recorded objects as the job carries them: static boxes at every frame
        frames = [f.frame for f in job.frames]
        job.scene.recorded_objects = list(job.scene.recorded_objects) + [
            job_mod.RecordedObject(str(o.get(keys.TRACK_ID, o.name)), size, dict.fromkeys(frames, T))
            for o, (T, size) in zip(scene_objects, map(box_of, scene_objects))]
    clear(context)
    coll = _collection(context, COLLECTION)
    # select() skips the ids the job's recorded objects have: an accepted proposal_01 stays the only one
    return [_empty(coll, p) for p in proposals_mod.select(found, job)]


def _empty(coll, p: proposals_mod.Proposal):
    obj = bpy.data.objects.new(f"Proposal {p.id[len('proposal_'):]} ({p.category})", None)
    obj.empty_display_type = "CUBE"
    obj.empty_display_size = DISPLAY_SIZE
    obj.matrix_world = Matrix((np.asarray(p.box_to_world, np.float64) @ np.diag([*p.size, 1.0])).tolist())
    kinds.mark(obj, kinds.PROPOSAL)
    obj[keys.TRACK_ID] = p.id
    obj[keys.CLASS] = p.category
    obj[keys.PROPOSAL_SCORE] = float(p.score)
    coll.objects.link(obj)
    return obj


def clear(context) -> int:
    """Delete the scene's proposals (not the recorded objects accepted from them); their number."""
    gone = kinds.objects_of_kind(context.scene, kinds.PROPOSAL)
    for o in gone:
        bpy.data.objects.remove(o, do_unlink=True)
    return len(gone)


def _proposal(obj):
    if not kinds.is_kind(obj, kinds.PROPOSAL):
        raise SceneError(f"objects[{getattr(obj, 'name', None)!r}]", "is not a box proposal",
                         hint="select a box of the SCPainter Proposals collection (Propose Boxes makes them)")
    return obj


def accept(context, obj, ignore: bool = False):
    """The proposal ``obj`` becomes a recorded object (module docstring): labelled, or an ignore region when
    ``ignore``. Returns it."""
    _proposal(obj)
    kinds.mark(obj, kinds.RECORDED_OBJECT)
    obj[keys.IGNORE] = bool(ignore)
    if keys.PROPOSAL_SCORE in obj:
        del obj[keys.PROPOSAL_SCORE]
    coll = _collection(context, RECORDED_COLLECTION)
    for c in list(obj.users_collection):
        c.objects.unlink(obj)
    coll.objects.link(obj)
    obj.name = f"{'Ignored' if ignore else 'Recorded'} {obj[keys.TRACK_ID]} ({obj[keys.CLASS]})"
    return obj


def relabel(obj, category: str) -> None:
    """Set the proposal's class (one of ``core.categories.NAMES``)."""
    _proposal(obj)
    if category not in categories.NAMES:
        raise SceneError(f"objects[{obj.name!r}]", f"class {category!r} is not in the class table",
                         hint=f"one of {', '.join(categories.NAMES)}")
    obj[keys.CLASS] = category
    obj.name = f"Proposal {str(obj[keys.TRACK_ID])[len('proposal_'):]} ({category})"


def reject(obj) -> None:
    """Delete the proposal."""
    bpy.data.objects.remove(_proposal(obj), do_unlink=True)
