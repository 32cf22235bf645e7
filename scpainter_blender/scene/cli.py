"""``blender -c scpainter <command> ...``: the add-on's headless commands for batch pipelines.

    blender -c scpainter import predictions.npz --camera-height 1.6 --save scene.blend

``-c`` implies background mode; the import goes into the scene that is open (``blender -b scene.blend -c ...``
imports into scene.blend). With the ``bpy`` module (no ``-c``), call ``execute(argv)`` directly. Output: a JSON summary on standard output; exit code 0 done, 2 bad input,
1 anything else (the backend's convention, DESIGN §4.4).
"""

from __future__ import annotations

import argparse
import json
import os

import bpy

from .. import backend_client
from . import importer


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse would sys.exit() from inside Blender: raise, return 2 instead
        raise ValueError(f"{self.prog}: {message}")


def _parser():
    p = _Parser(prog="blender -c scpainter", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    i = sub.add_parser("import", help="import VGGT predictions as points + recorded camera")
    i.add_argument("predictions")
    scale = i.add_mutually_exclusive_group()
    scale.add_argument("--scale-factor", type=float, help="metres per VGGT unit")
    scale.add_argument("--trajectory", help="metric camera path (.npz world_to_camera, xyz or TUM text)")
    scale.add_argument("--camera-height", type=float, help="camera height over the road, metres")
    i.add_argument("--confidence-percentile", type=float, default=50.0)
    i.add_argument("--point-source", choices=["depth", "world_points"], default="depth")
    i.add_argument("--backend-python", default="", help="interpreter for the backend (camera-height mode)")
    i.add_argument("--save", help="write the scene to this .blend (written to a temporary file, then renamed)")
    return p


def _import(args) -> dict:
    opts = importer.ImportOptions(confidence_percentile=args.confidence_percentile, point_source=args.point_source,
                                  backend_python=args.backend_python)
    if args.trajectory:
        opts.scale_mode, opts.trajectory_path = "TRAJECTORY", args.trajectory
    elif args.camera_height is not None:
        opts.scale_mode, opts.camera_height = "CAMERA_HEIGHT", args.camera_height
    else:
        opts.scale_mode, opts.scale_factor = "FACTOR", args.scale_factor if args.scale_factor else 1.0
    result = importer.import_vggt(bpy.context, args.predictions, opts)
    out = {"points": result.num_points, "points_object": result.points.name, "camera": result.camera.name,
           "scale": result.fit.scale, "scale_method": result.fit.method, "residual_m": result.fit.residual_m,
           "warnings": result.warnings, "timings_s": result.timings}
    if args.save:
        path = os.path.abspath(args.save)
        tmp = path + ".tmp.blend"
        bpy.ops.wm.save_as_mainfile(filepath=tmp, copy=True)
        os.replace(tmp, path)
        out["blend"] = path
    return out


def execute(argv) -> int:
    try:
        args = _parser().parse_args(list(argv))
        summary = _import(args)
    except (ValueError, backend_client.BackendError) as e:
        print(json.dumps({"event": "error", "message": str(e)}), flush=True)
        return 2
    print(json.dumps({"event": "done", "command": args.command, **summary}), flush=True)
    return 0


_handle = None


def register():
    global _handle
    if hasattr(bpy.utils, "register_cli_command"):
        _handle = bpy.utils.register_cli_command("scpainter", execute)


def unregister():
    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None

