"""``python -m backend <command>``: the backend's command line (DESIGN §4.4).

Exit codes: 0 done, 2 bad input, 1 anything else. Standard output carries JSON events only.
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback

import numpy as np

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


def _device(name: str) -> str:
    """cpu, cuda or auto; CUDA is touched only when asked for (auto or cuda), never at start-up."""
    if name == "cpu":
        return "cpu"
    import torch

    if torch.cuda.is_available():
        return "cuda"
    if name == "cuda":
        raise ValueError("--device cuda: torch sees no CUDA GPU on this machine (use --device cpu or auto)")
    return "cpu"


def _cmd_render(args) -> int:
    import signal
    import time

    from scpainter_blender.core import job as job_mod

    job = job_mod.load(args.job)
    device = _device(args.device)
    from .render import exr
    from .render import frames as fr

    out = job_mod.resolve(args.job, job["output_dir"])
    cond = os.path.join(out, "conditions")
    os.makedirs(cond, exist_ok=True)
    log = events.FileLog(os.path.join(out, "backend.log"))
    stop = []
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    try:
        t0 = time.perf_counter()
        W, H = job["resolution"]
        scene = fr.load_scene(job, args.job, device)
        log(f"render {args.job}: {len(job['frames'])} frames {W}x{H} on {device}; "
            f"{0 if scene.xyz is None else len(scene.xyz):,} points ({scene.removed_points:,} removed by boxes), "
            f"{len(scene.assets)} assets")
        total, rendered, skipped = len(job["frames"]), 0, 0
        for n, entry in enumerate(job["frames"]):
            if stop:
                break
            f = entry["frame"]
            exr_path = os.path.join(cond, f"frame_{f:06d}.exr")
            png_path = os.path.join(cond, f"preview_{f:06d}.png")
            if not args.force and os.path.isfile(exr_path) and os.path.isfile(png_path):
                skipped += 1
            else:
                t = time.perf_counter()
                layers = fr.render_frame(scene, entry, W, H, args.point_radius)
                exr.write(exr_path, layers)
                fr.write_png(png_path, np.stack([layers["R"], layers["G"], layers["B"]], axis=-1))
                rendered += 1
                log(f"frame {f}: {time.perf_counter() - t:.3f} s, hole {layers['hole'].mean():.3f}")
                events.artifact(exr_path, frame=f, kind="conditions")
                events.artifact(png_path, frame=f, kind="preview")
            events.progress("render", n + 1, total, frame=f)
        if stop:
            events.error(f"stopped by SIGTERM after {rendered + skipped} of {total} frames",
                         hint="finished frames are kept: run the same command again to resume")
            return events.EXIT_FAILED
        events.done(command="render", frames=total, rendered=rendered, skipped=skipped, device=device,
                    output_dir=out, seconds=time.perf_counter() - t0)
        return events.EXIT_OK
    finally:
        signal.signal(signal.SIGTERM, previous)


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
    r = sub.add_parser("render", help="render a job's condition layers (EXR + PNG previews) frame by frame")
    r.add_argument("job", help="job.json (DESIGN §4.2)")
    r.add_argument("--device", choices=["auto", "cpu", "cuda"], default="auto")
    r.add_argument("--force", action="store_true", help="render frames that are already finished again")
    r.add_argument("--point-radius", type=int, default=0, help="splat each point over (2r+1)^2 pixels")
    r.set_defaults(func=_cmd_render)
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
