"""``blender -c scpainter import``: VGGT predictions imported as points + the recorded camera into the scene that
is open (``blender -b scene.blend -c ...`` imports into scene.blend), with the import options as
``core/import_options.py`` defines them (``--objects FILE``: the drive's tracked boxes as recorded objects);
``--save`` writes the scene to a .blend (a temporary file, then renamed). ``--proposals``: the objects above the road
that nothing labels (``scene/proposals.py``) left as box proposals for review (``review``, as after File > Import),
made recorded objects (``accept``), ignore regions (``ignore``), or not proposed (``off``). A multi-camera recording
(``--sensors SIDECAR``, or ``<predictions stem>.sensors.json`` beside the predictions) imports one recorded camera per
sensor; the summary's ``recording_rig`` holds the rig's spread per sensor, and ``--save-rig FILE`` writes the rig as
a rig file (``scpainter.rig/1``, ``core.rig.save``) for the commands that render rigs.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile

import bpy

from ..core import backend_protocol as protocol
from ..core import errors, import_options, rig
from ..core.variation import proposals as proposals_core
from ..scene import importer, keys, proposals
from ..scene.props import SceneError

NAME = "import"
ORDER = 10


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``import PREDICTIONS``, the import options, ``--save``."""
    i = sub.add_parser(NAME, help="import VGGT predictions as points + recorded camera")
    i.add_argument("predictions")
    import_options.add_arguments(i)  # the import options, as core.import_options defines them
    i.add_argument("--save", help="write the scene to this .blend (written to a temporary file, then renamed)")
    i.add_argument("--save-rig", metavar="FILE",
                   help="a multi-camera recording (--sensors): write its rig (the sidecar's camera_to_ego or the "
                        "estimate) to this rig file (scpainter.rig/1 JSON)")
    i.add_argument("--proposals", choices=("review", *proposals_core.MODES), default="review",
                   help="objects above the road that nothing labels (parked cars), found in the points: box "
                        "proposals to review in Blender (review, the default), recorded objects labelled with the "
                        "class their size suggests (accept), recorded objects that every export makes ignore "
                        "regions (ignore), or nothing (off)")
    i.set_defaults(func=run)
    return i


def run(args: argparse.Namespace) -> tuple[dict, int]:
    """The import (options checked first: ``ArgumentError`` names the option); the summary (points, camera, the
    scale fit, the load report, timings; ``blend`` when saved) and exit code 0."""
    opts = import_options.from_arguments(args)  # checked: ArgumentError names the option
    result = importer.import_vggt(bpy.context, args.predictions, opts)
    out = {"points": result.num_points, "points_object": result.points.name, "camera": result.camera.name,
           "depth_edge_ratio": result.depth_edge_ratio, "depth_edge_points": result.depth_edge_points,
           "scale": result.fit.scale, "scale_method": result.fit.method, "residual_m": result.fit.residual_m,
           "warnings": result.warnings, "predictions": result.load_report.to_json(), "timings_s": result.timings,
           # a camera path stays the scene camera when the scene had one (importer.import_vggt)
           "scene_camera": bpy.context.scene.camera.name if bpy.context.scene.camera else None}
    if opts.objects:  # the recorded objects the import made (--objects)
        out["recorded_objects"] = [o.name for o in result.recorded_objects]
    if result.rig_fit is not None:   # a multi-camera recording: its cameras, its rig and the spread per sensor
        out["cameras"] = [c.name for c in result.cameras]
        out["sensors"] = result.sensors_path
        out["recording_rig"] = result.rig_fit.to_json()
    if args.save_rig:
        if result.rig_fit is None:
            raise errors.ArgumentError("--save-rig", "the predictions were imported as one camera: there is no "
                                                     "recording rig to save",
                                       hint="give the sensors sidecar (--sensors) of a multi-camera recording")
        out["rig_file"] = os.path.abspath(args.save_rig)
        os.makedirs(os.path.dirname(out["rig_file"]), exist_ok=True)
        rig.save(out["rig_file"], result.rig_fit.rig)
    out["proposals"] = [] if args.proposals == "off" else _proposals(args.proposals)
    if args.save:
        path = os.path.abspath(args.save)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        # into a fresh private folder beside the target (Blender makes its own "@" temporary and ".blend1" backup
        # of an existing file there), then renamed over the target
        tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(path)}.", dir=os.path.dirname(path))
        try:
            bpy.ops.wm.save_as_mainfile(filepath=os.path.join(tmp, "scene.blend"), copy=True)
            os.replace(os.path.join(tmp, "scene.blend"), path)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        out["blend"] = path
    return out, protocol.EXIT_OK


def _proposals(mode: str) -> list:
    """The track ids of the box proposals made (``mode``: review, accept or ignore); none without a road under the
    drive (a reconstruction not in metres)."""
    try:
        made = proposals.propose(bpy.context)
    except SceneError:
        return []
    ids = [str(o[keys.TRACK_ID]) for o in made]
    if mode != "review":
        for o in made:
            proposals.accept(bpy.context, o, ignore=mode == "ignore")
    return ids
