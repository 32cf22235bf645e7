"""``--proposals accept|ignore|off``: the objects of a job's reconstruction that nothing labels, added to the job in
memory before its labels are made (docs/design.md §15; ``core/variation/proposals.py`` finds them and adds them:
``with_proposals``).

``accept`` adds each proposal as a recorded object (a static box at every output frame, its class guessed from its
size), ``ignore`` as a recorded object with ``ignore: true`` (an ignore region in every export) and a ``warning``
event naming it (code ``proposals.UNLABELLED``), ``off`` nothing. The proposals are label-only: recorded objects are
``Job.LABEL_ONLY``, so the layers' key and the EXRs do not change with the mode, only the labels (their key covers
the whole job: a changed mode makes the labels again from the kept layers). Blender's render plan
(``runs/render_plan.py``) adds them the same way, so it agrees with the backend on which labels are up to date.

Cost: the points and the road (~1.3 s on the street, 1.2 M points) once per scene in a process
(``proposals.scene_clusters``); each job then only drops what its own boxes cover. A reconstruction with no road
under its drive (a tiny synthetic test scene, a clip not in metres) gets no proposals and a line in the log.
"""

from __future__ import annotations

from scpainter_blender.core import job_inputs
from scpainter_blender.core import job as job_mod
from scpainter_blender.core.variation import proposals as proposals_mod

from .. import events


def apply(job_path: str, job: job_mod.Job, mode: str, allow_outside: bool = False, data_roots=()) -> tuple:
    """(the job with its proposals added as ``mode`` says, the number of warning events said); ``off``, or a job
    without a scene or frames: (the job itself, 0). The job's inputs are checked first (``job_inputs.check_inputs``:
    its paths confined to its folder and ``data_roots`` unless ``allow_outside``), so a bad job fails as ``render``
    would, before its points are read."""
    if mode == "off" or job.scene is None or not job.frames:
        return job, 0
    job_inputs.check_inputs(job_path, job, allow_outside, data_roots)
    job, found, why = proposals_mod.with_proposals(job, job_path, mode)
    if why:
        events.log_here(f"proposals: none: {why}")
    for p in found:
        if mode == "ignore":
            events.warning(proposals_mod.unlabelled_message(p), proposals_mod.UNLABELLED, object=p.id)
        else:
            events.log_here(f"proposals: {proposals_mod.describe(p)}: added as a recorded object")
    return job, len(found) if mode == "ignore" else 0
