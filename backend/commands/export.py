"""``python -m backend export``: a job's labels as a training dataset (KITTI, COCO or OpenLABEL), rendering missing
frames first; images: the generated frames, else the condition previews (``backend/export/command.py``;
docs/design.md §15). The formats: ``core.backend_protocol.EXPORT_FORMATS``.

Two forms: one job and one format (``export JOB --format coco [--out DIR]``), or one dataset from many jobs in
several formats (``export --list variants.txt --format coco,kitti,openlabel --out DATASET [--split val=0.1]``:
``backend/export/dataset.py``), which ``batch --command export`` runs too (``run_dataset``).
"""

from __future__ import annotations

import argparse

from .. import events
from . import options

NAME = "export"
ORDER = 40
SPLIT_HELP = ("NAME=FRACTION[,NAME=FRACTION]: the share of the base drives each split gets, the rest train's (e.g. "
              "val=0.1); a drive's jobs all go to one split (default: every job in train)")


class FormatChoices(tuple):
    """``--format``'s choices: the format names (what argparse lists and help shows), and a value is among them when
    each of its comma-separated names is one (``coco,kitti``: a dataset in both)."""

    def __contains__(self, value: object) -> bool:
        return isinstance(value, str) and all(tuple.__contains__(self, v.strip()) for v in value.split(","))


def _format_choices() -> FormatChoices:
    from scpainter_blender.core.backend_protocol import EXPORT_FORMAT_NAMES

    return FormatChoices(EXPORT_FORMAT_NAMES)


#: ``export --format`` and ``batch --format``'s choices.
FORMAT_CHOICES = _format_choices()


def dataset_options(p: argparse.ArgumentParser, what: str) -> None:
    """``--split`` (``export`` and ``batch``): how a dataset of many jobs is split."""
    p.add_argument("--split", help=SPLIT_HELP + what)


def nuscenes_options(p: argparse.ArgumentParser, what: str) -> None:
    """``--version`` and ``--keyframe-hz`` (``export`` and ``batch``): the nuScenes format's."""
    from ..export import nuscenes

    p.add_argument("--version", help=f"--format nuscenes{what}: the tables' "
                   f"folder, {' or '.join(nuscenes.VERSIONS)} (default {nuscenes.DEFAULT_VERSION}: what "
                   "mmdetection3d's create_data.py nuscenes --version v1.0-mini converts)")
    p.add_argument("--keyframe-hz", type=float,
                   help=f"--format nuscenes{what}: keyframes (samples) per second; the other frames are sweeps "
                        f"(default {nuscenes.DEFAULT_KEYFRAME_HZ:g}, nuScenes')")


def format_options(args: argparse.Namespace) -> dict:
    """The formats' own options of ``args`` (``nuscenes_options``), checked."""
    from ..export import nuscenes

    return nuscenes.check_options(nuscenes.DEFAULT_VERSION if args.version is None else args.version,
                                  nuscenes.DEFAULT_KEYFRAME_HZ if args.keyframe_hz is None else args.keyframe_hz)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``export``'s parser."""
    from scpainter_blender.core.backend_protocol import export_format_labels
    from scpainter_blender.core.output_layout import VariationLayout

    x = sub.add_parser(NAME, help=f"a job's labels as a training dataset ({export_format_labels()}), rendering "
                                  "missing frames first; images: the generated frames, else the condition "
                                  "previews; several jobs (--list) and formats: one dataset")
    x.add_argument("jobs", nargs="*", metavar="job", help="job.json (the job contract: docs/design.md); several, "
                                                          "or --list: one dataset of them all")
    x.add_argument("--list", action="append", help="a text file of job paths, one per line, as batch --list reads "
                                                   f"it (a vary run's {VariationLayout.LIST}): the jobs of one "
                                                   "dataset (repeatable)")
    x.add_argument("--format", required=True, choices=FORMAT_CHOICES,
                   help="kitti (image_2, label_2, calib), coco (annotations.json with uncompressed RLE masks), "
                        "openlabel (ASAM OpenLABEL 1.0 JSON) or kitti-tracking (image_02, label_02 with track ids, "
                        "calib, pose), nuscenes (the 13 nuScenes tables, samples/ and sweeps/ per camera and LiDAR, "
                        "maps/), or several separated by commas (a dataset): docs/design.md §15")
    x.add_argument("--out", help="destination folder, written whole (one job and format: default "
                                 "<output_dir>/export/<format>; a dataset: required, one folder per format in it); "
                                 "an existing one must be empty or a previous export of the same kind")
    dataset_options(x, " (a dataset)")
    nuscenes_options(x, "")
    options.device_option(x, "for rendering missing frames; " + options.DEVICE_HELP)
    options.confinement_options(x)
    options.proposals_option(x)
    x.set_defaults(func=run)
    return x


def run(args: argparse.Namespace) -> int:
    """Export the job, or the jobs as one dataset; a ``done`` event, else an error event when SIGTERM stopped the
    rendering (exit 1)."""
    import time

    from scpainter_blender.core import batch_items
    from scpainter_blender.core import job as job_mod
    from scpainter_blender.core import outputs
    from scpainter_blender.core.errors import ArgumentError

    from ..export import command, dataset
    from ..render import proposals

    roots = outputs.data_roots_option(args.data_root)
    if args.out is not None and not args.out.strip():
        raise ArgumentError("--out", "is empty", hint="give a folder, or leave --out out for export/<format>/")
    formats = dataset.parse_formats(args.format)
    split = dataset.parse_split(args.split)
    fmt_options = format_options(args)
    listed = [batch_items.read_job_list(f) for f in args.list or []]
    if args.list or len(args.jobs) != 1 or len(formats) > 1 or args.split is not None:
        from ..batch import command as batch

        items = list(args.jobs) + [p for jobs in listed for p in jobs.paths]
        return run_dataset(items, formats, args.out, split, args.device, args.allow_outside,
                           batch.job_data_roots(args.jobs, listed, roots), proposals=args.proposals,
                           fmt_options=fmt_options)
    job = job_mod.load(args.jobs[0])
    device = options.resolve_device(args.device)
    t0 = time.perf_counter()
    job, _ = proposals.apply(args.jobs[0], job, args.proposals, args.allow_outside, roots)
    with events.stop_on_sigterm() as stop:
        result = command.export_job(args.jobs[0], job, formats[0], args.out, device, args.allow_outside, stop, roots,
                                    fmt_options if formats[0] == "nuscenes" else None)
    return _finished(result, NAME, device, time.perf_counter() - t0)


def run_dataset(items: list, formats: list, out: str | None, split: dict, device: str,
                allow_outside: bool | frozenset, data_roots: dict, command_name: str = NAME,
                proposals: str | None = None, fmt_options: dict | None = None) -> int:
    """One dataset of ``items`` (``backend.export.dataset.export_dataset``) and its ``done`` event (``command``:
    ``command_name``), or an error event when SIGTERM stopped a render (exit 1)."""
    import time

    from scpainter_blender.core.errors import ArgumentError

    from ..export import dataset

    if not items:
        raise ArgumentError("jobs", "no jobs given", hint="give job.json paths, or --list FILE")
    if not out:
        raise ArgumentError("--out", "a dataset (several jobs or formats, --list, --split) needs --out DATASET",
                            hint="name a new folder: one folder per format is written in it")
    device = options.resolve_device(device)
    t0 = time.perf_counter()
    with events.stop_on_sigterm() as stop:
        result = dataset.export_dataset(items, formats, out, split, device, allow_outside, stop, data_roots,
                                        proposals=proposals, options=fmt_options)
    return _finished(result, command_name, device, time.perf_counter() - t0)


def _finished(result: dict, command_name: str, device: str, seconds: float) -> int:
    """The end of an export (one job's or a dataset's): an error event when SIGTERM stopped the rendering of the
    missing frames (exit 1), else the ``done`` event with ``result``."""
    if result.pop("stopped"):
        events.error("stopped by SIGTERM while rendering the missing frames: nothing exported",
                     hint="finished frames are kept: run the same command again to resume")
        return events.EXIT_FAILED
    events.done(command=command_name, device=device, seconds=seconds, **result)
    return events.EXIT_OK
