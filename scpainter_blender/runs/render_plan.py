"""Render Conditions with nothing to render: known in Blender, without starting the backend (docs/design.md §12).

The job a click would render is exported as ``camera_run.start`` exports it, and planned with the backend's own
rules (``core.frame_keys``: each frame's layers key from its camera and the assets it can see, the precision and the
assets' extents from the conditions folder's record). When every frame is finished under its keys, the run is
over before it starts: its results are loaded as a finished render's, and the frames' warnings are said again
as the backend says them on every run. Anything the record cannot answer (no record, an asset file changed, a
forced run) goes to the backend. A rig job is planned as the backend runs it, camera by camera (``Job.camera_jobs``,
each in its own ``<output folder>/<CAMERA>/``): it is over only when every camera's frames are; a rig with a LiDAR
goes to the backend (its sweeps' keys hold the caster's settings, which live there).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..core import backend_protocol as protocol
from ..core import errors, frame_keys
from ..core import job as job_mod
from ..core import labels as labels_mod
from ..core.output_layout import OutputLayout
from ..core.variation import proposals
from . import camera_run
from .client import Invocation


@dataclass
class Check:
    """What ``check`` found: the job it exported (``job_path``, ``out``: hand them to
    ``camera_run.start(exported=...)``) and, when every frame is finished, the run's ``done`` event and the frames'
    ``warning`` events (else None)."""
    job_path: str
    out: str
    done: dict | None = None
    warnings: list = field(default_factory=list)


def check(context, run: Invocation, camera) -> Check | None:
    """Export ``camera``'s job as ``camera_run.start`` would (InputError/SceneError when the scene cannot make one) and
    plan ``run`` (a ``render`` ``Invocation``) from its output folder's record: ``Check.done`` is set when every
    frame is finished. None for any other run or ``--force``: nothing exported."""
    if run.command != "render" or run.force:
        return None
    job_path, out = camera_run.export(context, camera=camera)
    job = job_mod.load(job_path)
    mode = run.proposals or proposals.DEFAULT_MODE
    try:  # the job as the backend labels it: its proposals added as the run's mode says (the backend's own rule;
        # a rig job gets one set, which its camera jobs share)
        job, found, _ = proposals.with_proposals(job, job_path, mode)
    except (OSError, errors.InputError):  # an input file is gone or unreadable: the backend names it
        return Check(job_path, out)
    if job.rig is not None and job.rig.lidar is not None:
        # its sweeps' keys (core.frame_keys.sweep_keys) hold the caster's settings, which only the backend has: it
        # decides (a second render casts nothing), never a LiDAR moved in Blender called up to date
        return Check(job_path, out)
    done_labels = []
    # a rig job is planned camera by camera, as the backend renders it: each camera job in its own folder
    # (<out>/<CAMERA>/); the run is over only when every camera's is
    for cam, cjob in job.camera_jobs():
        cout = out if cam is None else OutputLayout(out).camera(cam.name).root
        try:
            plan = frame_keys.plan_from_record(cout, job_path, cjob, run.point_radius or 0)
        except (OSError, errors.InputError):
            plan = None
        if plan is None or not plan.up_to_date:
            return Check(job_path, out)
        done_labels += [(cam, plan.done[e.frame]) for e in cjob.frames]
    # said again as the backend says them on every run: the ignored proposals, then each frame's (a rig camera's
    # naming the camera, as the backend tags them)
    warnings = [protocol.event(protocol.WARNING, message=proposals.unlabelled_message(p), code=proposals.UNLABELLED,
                               object=p.id) for p in found if mode == "ignore"]
    warnings += [protocol.event(protocol.WARNING, message=message, code=code, frame=lab["frame"],
                                **({"object": obj} if obj else {}),
                                **({protocol.CAMERA_FIELD: cam.name} if cam is not None else {}))
                 for cam, lab in done_labels for code, message, obj in labels_mod.warnings(lab)]
    n = len(done_labels)  # a rig's frames counted over its cameras, as the backend counts them
    rig = {} if job.rig is None else {"cameras": [c.name for c in job.rig.cameras]}
    done = protocol.event(protocol.DONE, frames=n, rendered=0, skipped=n, relabelled=0, output_dir=out,
                          stopped=False, warnings=len(warnings), up_to_date=True, **rig)
    return Check(job_path, out, done, warnings)
