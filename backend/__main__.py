"""``python -m backend <command>``: the backend's command line (DESIGN §4.4).

Exit codes: 0 done, 2 bad input, 1 anything else. Standard output carries JSON events only.
"""

from __future__ import annotations

import argparse
import sys
import traceback

from . import events


def _cmd_doctor(args) -> int:
    import importlib.util
    import platform

    report = {"python": sys.version.split()[0], "platform": platform.platform(), "executable": sys.executable}
    for mod in ("numpy", "torch", "diffusers", "transformers", "open3d"):
        spec = importlib.util.find_spec(mod)
        report[mod] = None
        if spec is not None:
            try:
                report[mod] = __import__(mod).__version__
            except Exception as e:  # an installed but broken package is worth reporting, not crashing on
                report[mod] = f"broken: {e}"
    if report.get("torch") and not str(report["torch"]).startswith("broken"):
        import torch

        report["cuda"] = torch.cuda.is_available()
        report["devices"] = [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())]
    events.done(command="doctor", report=report)
    return events.EXIT_OK


def _cmd_ground_plane(args) -> int:
    from scpainter_blender.core import vggt

    from .ground_plane import fit_ground_plane

    pred = vggt.load_predictions(args.predictions)
    events.progress("ground_plane", 0, 1)
    plane, stats = fit_ground_plane(pred, confidence_percentile=args.confidence_percentile, seed=args.seed)
    fit = vggt.world_from_vggt_by_camera_height(plane, pred.world_to_camera, args.camera_height,
                                                plane_inlier_rms=stats["inlier_rms_vggt"])
    fit.details.update(stats)
    events.progress("ground_plane", 1, 1)
    events.done(command="ground-plane", result=fit.to_json())
    return events.EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m backend", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("doctor", help="report the Python, packages and devices the backend would use")
    d.set_defaults(func=_cmd_doctor)
    g = sub.add_parser("ground-plane", help="metric world_from_vggt from a known camera height over the road")
    g.add_argument("predictions", help="VGGT predictions.npz")
    g.add_argument("--camera-height", type=float, required=True, help="camera height over the road, metres")
    g.add_argument("--confidence-percentile", type=float, default=50.0)
    g.add_argument("--seed", type=int, default=0)
    g.set_defaults(func=_cmd_ground_plane)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as e:  # bad input: the message names the file and field
        events.error(str(e), hint="check the input file and arguments")
        return events.EXIT_BAD_INPUT
    except KeyboardInterrupt:
        events.error("interrupted")
        return events.EXIT_FAILED
    except Exception as e:
        events.log(traceback.format_exc())
        events.error(f"{type(e).__name__}: {e}", hint="see the log on standard error")
        return events.EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
