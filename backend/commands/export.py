"""``python -m backend export``: a job's labels as a training dataset (KITTI, COCO or OpenLABEL), rendering missing
frames first; images: the generated frames, else the condition previews (``backend/export/command.py``;
docs/design.md §15). The formats: ``core.backend_protocol.EXPORT_FORMATS``.
"""

from __future__ import annotations

import argparse

from .. import events
from . import options

NAME = "export"
ORDER = 40


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``export``'s parser."""
    from scpainter_blender.core.backend_protocol import EXPORT_FORMAT_NAMES, export_format_labels

    x = sub.add_parser(NAME, help=f"a job's labels as a training dataset ({export_format_labels()}), rendering "
                                  "missing frames first; images: the generated frames, else the condition "
                                  "previews")
    x.add_argument("job", help="job.json (the job contract: docs/design.md)")
    x.add_argument("--format", required=True, choices=EXPORT_FORMAT_NAMES,
                   help="kitti (image_2, label_2, calib), coco (annotations.json with RLE masks), openlabel "
                        "(ASAM OpenLABEL 1.0 JSON) or kitti-tracking (image_02, label_02 with track ids, calib, "
                        "pose): docs/design.md §15")
    x.add_argument("--out", help="destination folder, written whole (default: <output_dir>/export/<format>); an "
                                 "existing one must be empty or a previous export")
    options.device_option(x, "for rendering missing frames; " + options.DEVICE_HELP)
    options.confinement_options(x)
    options.proposals_option(x)
    x.set_defaults(func=run)
    return x


def run(args: argparse.Namespace) -> int:
    """Export the job; a ``done`` event, else an error event when SIGTERM stopped the rendering (exit 1)."""
    import time

    from scpainter_blender.core import job as job_mod
    from scpainter_blender.core import outputs

    from ..export import command
    from ..render import proposals

    roots = outputs.data_roots_option(args.data_root)
    if args.out is not None and not args.out.strip():
        from scpainter_blender.core.errors import ArgumentError

        raise ArgumentError("--out", "is empty", hint="give a folder, or leave --out out for export/<format>/")
    job = job_mod.load(args.job)
    device = options.resolve_device(args.device)
    t0 = time.perf_counter()
    job, _ = proposals.apply(args.job, job, args.proposals, args.allow_outside, roots)
    with events.stop_on_sigterm() as stop:
        result = command.export_job(args.job, job, args.format, args.out, device, args.allow_outside, stop, roots)
    if result.pop("stopped"):
        events.error("stopped by SIGTERM while rendering the missing frames: nothing exported",
                     hint="finished frames are kept: run the same command again to resume")
        return events.EXIT_FAILED
    events.done(command=NAME, device=device, seconds=time.perf_counter() - t0, **result)
    return events.EXIT_OK
