"""``blender -c scpainter sensors TABLES --scene NAME --out FILE``: the sensors sidecar (``core.vggt.sensors``) of a
multi-camera reconstruction made from a nuScenes scene's keyframe images, written from the devkit's tables
(``core.recording.nuscenes.sensors``): frames in sample order, and within a sample in the order of ``--channels``
(default: the scene's cameras in ``core.rig.NUSCENES_CAMERAS`` order). The summary lists the images
(``sample_data.filename``, relative to the dataroot) in that order: the order to give VGGT. With
``--calibration`` (the default) each sensor's ``calibrated_sensor`` pose and image size go into the sidecar, so the
import takes nuScenes' own rig instead of estimating it; ``--no-calibration`` leaves them out (the import estimates
the rig from the reconstruction). ``--trajectory-out NPZ``: the frames' camera poses in nuScenes' global frame, a
metric trajectory for the import's ``--trajectory`` (metric scale; the global frame's z = 0 is near the road, where
nuScenes' ego poses lie).
"""

from __future__ import annotations

import argparse
import os

from ..core import backend_protocol as protocol
from ..core import rig
from ..core.geometry import metric_scale
from ..core.recording import nuscenes
from ..core.vggt import sensors as sensors_mod

NAME = "sensors"
ORDER = 15


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``sensors TABLES``, ``--scene``, ``--channels``, ``--[no-]calibration``, ``--out``."""
    s = sub.add_parser(NAME, help="the sensors sidecar of a multi-camera reconstruction, from a nuScenes scene's "
                                  "tables")
    s.add_argument("tables", help="the folder of the devkit's JSON tables (<dataroot>/v1.0-mini)")
    s.add_argument("--scene", default="", help="the scene's name or token (needed when the tables hold several)")
    s.add_argument("--channels", nargs="+", metavar="CHANNEL",
                   help="the camera channels VGGT was given, in the order it was given each sample's images "
                        f"(default: the scene's of {', '.join(rig.NUSCENES_CAMERAS)}, in that order)")
    s.add_argument("--calibration", action=argparse.BooleanOptionalAction, default=True,
                   help="write each sensor's calibrated_sensor pose (camera_to_ego) and image size, so the import "
                        "takes nuScenes' rig; --no-calibration: the import estimates it from the reconstruction")
    s.add_argument("--trajectory-out", metavar="NPZ",
                   help="also write the frames' camera poses in nuScenes' global frame (metres) as a metric "
                        "trajectory (.npz world_to_camera), for the import's --trajectory")
    s.add_argument("--out", required=True, help="the sidecar to write, e.g. <predictions stem>.sensors.json beside "
                                                "the predictions (where the import finds it)")
    s.set_defaults(func=run)
    return s


def run(args: argparse.Namespace) -> tuple[dict, int]:
    """The sidecar written (atomically); the summary: its path, frames, sensors in order, calibrated or not."""
    read = nuscenes.sensors(os.path.abspath(args.tables), args.scene, args.channels or (), args.calibration)
    made = read.sensors
    out = os.path.abspath(args.out)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    sensors_mod.write(out, made)
    summary = {"sensors_file": out, "frames": made.num_frames, "sensors": made.names,
               "calibrated": sorted(n for n, i in made.info.items() if i.camera_to_ego is not None),
               "images": read.images}
    if args.trajectory_out:
        path = os.path.abspath(args.trajectory_out)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        metric_scale.save_metric_trajectory(path, read.world_to_camera)
        summary["trajectory"] = path
    return summary, protocol.EXIT_OK
