"""Box proposals in Blender (scene/proposals.py, the operators of operators/placement.py): after the street's import
its parked cars are proposed as boxes (the core's proposals: tests/core/variation/test_proposals.py checks them
against the street's truth); accept, relabel, ignore and reject each do what the review promises, and a second
*Propose Boxes* does not propose what was accepted."""

import os
import sys

import bpy
import numpy as np

from scpainter_blender.core.variation import proposals as core_proposals, variants


def _mod(addon, name):
    return sys.modules[f"{addon}.scpainter_blender.scene.{name}"]


def test_import_proposes_and_each_review_action(addon, empty_scene, street):
    kinds, keys = _mod(addon, "kinds"), _mod(addon, "keys")
    scene_proposals = _mod(addon, "proposals")
    assert bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, scale_mode="TRAJECTORY",
                                         trajectory_path=os.path.join(street.root, "metric.npz")) == {"FINISHED"}
    assert kinds.is_kind(bpy.context.active_object, kinds.POINTS)      # the import's selection is kept
    made = kinds.objects_of_kind(empty_scene, kinds.PROPOSAL)
    # the core's proposals of the job the scene exports, one box each: the unit cube of a display-size-0.5 empty
    job, job_path = _mod(addon, "drive_lane").drive_job(bpy.context)
    expected = core_proposals.propose(variants.scene_points(job, job_path), job)
    assert sorted(o[keys.TRACK_ID] for o in made) == [p.id for p in expected] == \
        ["proposal_01", "proposal_02", "proposal_03"]
    for p in expected:
        (obj,) = [o for o in made if o[keys.TRACK_ID] == p.id]
        T, size = scene_proposals.box_of(obj)
        assert np.allclose(T, p.box_to_world, atol=1e-4) and np.allclose(size, p.size, atol=1e-4)
        assert obj[keys.CLASS] == p.category and obj.users_collection[0].name == scene_proposals.COLLECTION

    def named(track_id):
        return next(o for o in empty_scene.objects if o.get(keys.TRACK_ID) == track_id)

    assert bpy.ops.scpainter.relabel_proposal(name=named("proposal_02").name, category="van") == {"FINISHED"}
    assert bpy.ops.scpainter.review_proposal(name=named("proposal_02").name, action="accept") == {"FINISHED"}
    assert bpy.ops.scpainter.review_proposal(name=named("proposal_03").name, action="ignore") == {"FINISHED"}
    assert bpy.ops.scpainter.review_proposal(name=named("proposal_01").name, action="reject") == {"FINISHED"}
    recorded = {o[keys.TRACK_ID]: o for o in kinds.objects_of_kind(empty_scene, kinds.RECORDED_OBJECT)}
    assert sorted(recorded) == ["proposal_02", "proposal_03"] and kinds.objects_of_kind(empty_scene, kinds.PROPOSAL) == []
    assert (recorded["proposal_02"][keys.CLASS], recorded["proposal_02"][keys.IGNORE]) == ("van", False)
    assert (recorded["proposal_03"][keys.CLASS], recorded["proposal_03"][keys.IGNORE]) == ("car", True)
    assert all(o.users_collection[0].name == "SCPainter Recorded Objects" and o.empty_display_size == 0.5
               for o in recorded.values())
    # proposed again: the rejected car comes back, the two recorded ones do not
    assert bpy.ops.scpainter.propose_boxes() == {"FINISHED"}
    assert [o[keys.TRACK_ID] for o in kinds.objects_of_kind(empty_scene, kinds.PROPOSAL)] == ["proposal_01"]
    assert bpy.ops.scpainter.relabel_proposal(name=named("proposal_01").name, category="bus") == {"FINISHED"}
    assert named("proposal_01")[keys.CLASS] == "bus"
