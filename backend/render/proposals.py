"""``--proposals accept|ignore|off``: the objects of a job's reconstruction that nothing labels, added to the job in
memory before its labels are made (docs/design.md §15; ``core/variation/proposals.py`` finds them).

``accept`` adds each proposal as a recorded object (a static box at every output frame, its class guessed from its
size), ``ignore`` as a recorded object with ``ignore: true`` (an ignore region in every export) and a ``warning``
event naming it (code ``UNLABELLED``), ``off`` nothing. The proposals are label-only: recorded objects are
``Job.LABEL_ONLY``, so the layers' key and the EXRs do not change with the mode, only the labels (their key covers
the whole job: a changed mode makes the labels again from the kept layers).

Cost and cache: the points as the renderer loads them (``variants.scene_points``) and the road (~1.3 s on the
street, 1.2 M points) are computed once per scene in a process: the clusters (``proposals.clusters``) are kept under
the predictions file's identity (real path, size, mtime: ``core.frame_keys.stamp``) and the job's scene settings
(``Job.layers_dict()["scene"]``: transform, confidence, removal boxes, cleaning); each job then only drops the
clusters its own boxes cover and numbers the rest. The last ``KEPT`` scenes are kept (a warm backend, a batch, a
merged export of many variants of one drive). A job whose reconstruction shows no road under its drive (a tiny
synthetic test scene, a clip not in metres) gets no proposals and a line in the log: nothing to propose there.
"""

from __future__ import annotations

import collections
import json
import os
from dataclasses import replace

from scpainter_blender.core import frame_keys, job_inputs
from scpainter_blender.core import job as job_mod
from scpainter_blender.core.variation import proposals as proposals_mod
from scpainter_blender.core.variation import variants

from .. import events

#: The ``warning`` event's code for a proposal added as an ignore region.
UNLABELLED = "unlabelled_object"
#: Scenes whose clusters a process keeps (the last used).
KEPT = 4

_kept: collections.OrderedDict = collections.OrderedDict()


def _scene_key(job_path: str, job: job_mod.Job) -> str:
    """What a scene's clusters depend on: the predictions file and the settings its cloud is made from, and the
    first camera path's centres (the road grows from them)."""
    pred = os.path.realpath(job_mod.resolve(job_path, job.scene.predictions))
    scene = {k: v for k, v in job.layers_dict()["scene"].items() if k != "predictions"}
    centres = variants.reference_path(job).centres[[0, -1]].round(3).tolist()
    return json.dumps({"points": [pred, *frame_keys.stamp(pred)], "scene": scene, "path": centres,
                       "version": proposals_mod.VERSION}, sort_keys=True)


def clusters(job_path: str, job: job_mod.Job) -> list:
    """The scene's ``proposals.Cluster`` list, computed once per scene (module docstring); [] when it holds no road
    under the drive (logged)."""
    key = _scene_key(job_path, job)
    if key in _kept:
        _kept.move_to_end(key)
        return _kept[key]
    points = variants.scene_points(job, job_path)
    try:
        found = proposals_mod.clusters(points, variants.reference_path(job).centres)
    except ValueError as e:   # the Road's: no level ground under the drive
        events.log_here(f"proposals: none: {e}")
        found = []
    _kept[key] = found
    while len(_kept) > KEPT:
        _kept.popitem(last=False)
    return found


def apply(job_path: str, job: job_mod.Job, mode: str, allow_outside: bool = False, data_roots=()) -> tuple:
    """(the job with its proposals added as ``mode`` says (module docstring), the number of warning events said);
    ``off``, or a job without a scene or frames: (the job itself, 0). The job's inputs are checked first (``job_inputs.check_inputs``: its paths confined to
    its folder and ``data_roots`` unless ``allow_outside``), so a bad job fails as ``render`` would."""
    if mode not in proposals_mod.MODES:
        raise ValueError(f"proposals mode {mode!r} is not one of {proposals_mod.MODES}")  # the parser's choices
    if mode == "off" or job.scene is None or not job.frames:
        return job, 0
    job_inputs.check_inputs(job_path, job, allow_outside, data_roots)
    found = proposals_mod.select(clusters(job_path, job), job)
    if not found:
        return job, 0
    ignore = mode == "ignore"
    added = [p.recorded_object([e.frame for e in job.frames], ignore) for p in found]
    for p in found:
        if ignore:
            events.warning(proposals_mod.describe(p) + ": nothing labels it, so it is an ignore region in every "
                           "export (accept it in Blender, or pass --proposals accept to label it)", UNLABELLED,
                           object=p.id)
        else:
            events.log_here(f"proposals: {proposals_mod.describe(p)}: added as a recorded object")
    job = replace(job, scene=replace(job.scene, recorded_objects=list(job.scene.recorded_objects) + added))
    return job, len(found) if ignore else 0
