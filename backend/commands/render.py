"""``python -m backend render``: render a job's condition layers (EXR + PNG previews) frame by frame
(``backend/render/command.py``; docs/design.md §4.3, §10).

``--check`` validates the job, its paths, its input files and the output folder and stops, rendering nothing.
SIGTERM stops after the frame being rendered; finished frames are kept, so running again resumes.
"""

from __future__ import annotations

import argparse

from .. import events
from . import options

NAME = "render"
ORDER = 20


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``render``'s parser."""
    r = sub.add_parser(NAME, help="render a job's condition layers (EXR + PNG previews) frame by frame")
    r.add_argument("job", help="job.json (the job contract: docs/design.md)")
    options.device_option(r)
    r.add_argument("--force", action="store_true", help="render frames that are already finished again")
    r.add_argument("--point-radius", type=options.bounded_int(0, 16), default=0,
                   help="splat each point over (2r+1)^2 pixels (0-16)")
    r.add_argument("--half-float", action="store_true", help=options.HALF_FLOAT_HELP)
    options.input_options(r)
    options.proposals_option(r)
    r.set_defaults(func=run)
    return r


def run(args: argparse.Namespace) -> int:
    """Check (``--check``) or render the job; a ``done`` event with the counts, else an error event when SIGTERM
    stopped it (exit 1)."""
    import time

    from scpainter_blender.core import job_inputs, locking, outputs
    from scpainter_blender.core import job as job_mod

    from ..render import command, proposals

    roots = outputs.data_roots_option(args.data_root)
    job = job_mod.load(args.job)
    if args.check:  # (render_job checks the same before it writes anything)
        paths = job_inputs.check_inputs(args.job, job, args.allow_outside, roots)
        outputs.check_output(paths["output_dir"], args.allow_outside)
        command.warn_inputs(job, paths)
        rig = {}
        if job.rig is not None:  # each camera's folder checked too; the frames counted over the cameras
            from ..render import rig_jobs

            for c in job.rig.cameras:
                outputs.check_output(rig_jobs.camera_output(paths["output_dir"], c.name), args.allow_outside)
            rig = {"cameras": [c.name for c in job.rig.cameras]}
        events.done(command=NAME, check=True, frames=len(job.frames) * len(rig.get("cameras", [None])),
                    output_dir=paths["output_dir"], locked_by=locking.lock_owner(paths["output_dir"]), **rig)
        return events.EXIT_OK
    device = options.resolve_device(args.device)
    t0 = time.perf_counter()
    job, proposed = proposals.apply(args.job, job, args.proposals, args.allow_outside, roots)
    with events.stop_on_sigterm() as stop:
        result = command.render_job(args.job, job, device, force=args.force, point_radius=args.point_radius,
                                    stop=stop, allow_outside=args.allow_outside, half=args.half_float,
                                    data_roots=roots)
    if result["stopped"]:
        events.error(f"stopped by SIGTERM after {result['rendered'] + result['skipped']} of {result['frames']} "
                     "frames", hint="finished frames are kept: run the same command again to resume")
        return events.EXIT_FAILED
    result.pop("stopped")
    result["warnings"] += proposed
    events.done(command=NAME, device=device, seconds=time.perf_counter() - t0, **result)
    return events.EXIT_OK
