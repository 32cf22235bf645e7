"""``python -m backend doctor``: report the Python, packages and devices the backend would use.

Imports nothing but the standard library before it reports (this module's top included: ``backend.__main__``
parses ``doctor`` with this module alone), so it reports what an interpreter lacks (numpy, torch) instead of failing
on it; with ``--checkpoint`` it also checks that checkpoint's config when numpy is there.
"""

from __future__ import annotations

import argparse
import os
import sys

from .. import events

NAME = "doctor"
ORDER = 10

#: The PyPI distributions that install the module cv2 (more than one installed: they overwrite each other's files).
OPENCV_DISTRIBUTIONS = ("opencv-contrib-python-headless", "opencv-contrib-python", "opencv-python-headless",
                        "opencv-python")


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``doctor``'s parser: stdlib only, so it parses in an interpreter that lacks numpy."""
    d = sub.add_parser(NAME, help="report the Python, packages and devices the backend would use")
    d.add_argument("--checkpoint", help="also check this SCPainter checkpoint folder")
    d.set_defaults(func=run)
    return d


def run(args: argparse.Namespace) -> int:
    """The report as one ``done`` event: the versions of the backend's packages (None: missing; "broken: ..."),
    OpenCV's build, CUDA's devices, Ray's version, what is missing and how to install it, the checkpoint's state."""
    import contextlib
    import importlib.metadata
    import importlib.util
    import platform

    report = {"python": sys.version.split()[0], "platform": platform.platform(), "executable": sys.executable}
    for mod in ("numpy", "torch", "numba", "OpenEXR", "cv2", "diffusers", "transformers", "safetensors", "av", "open3d",
                "trimesh"):
        spec = importlib.util.find_spec(mod)
        report[mod] = None
        if spec is not None:
            try:  # standard output is the event stream: what an import prints (cv2 without numpy) goes to stderr
                with contextlib.redirect_stdout(sys.stderr):
                    report[mod] = __import__(mod).__version__
            except Exception as e:  # an installed but broken package is worth reporting, not crashing on
                report[mod] = f"broken: {e}"
    if report.get("cv2") and not str(report["cv2"]).startswith("broken"):
        report["opencv"] = opencv_report()
    if report.get("torch") and not str(report["torch"]).startswith("broken"):
        import torch

        report["cuda"] = torch.cuda.is_available()
        report["devices"] = [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())]
    try:  # optional (batch --ray, evaluate --ray); its version without importing it (a second)
        report["ray"] = importlib.metadata.version("ray") if importlib.util.find_spec("ray") else None
    except importlib.metadata.PackageNotFoundError:
        report["ray"] = "installed, version unknown"
    needed = ("numpy", "torch", "numba", "OpenEXR", "cv2", "diffusers", "transformers", "safetensors", "av", "trimesh")
    report["missing"] = [m for m in needed if not report.get(m) or str(report[m]).startswith("broken")]
    if report["missing"]:
        from scpainter_blender.core.backend_protocol import install_hint

        report["install"] = install_hint(sys.executable)
    if args.checkpoint and "numpy" in report["missing"]:
        report["checkpoint"] = "not checked: this Python lacks numpy"
    elif args.checkpoint:
        from scpainter_blender.core import errors

        from ..model import checkpoint, checkpoint_config

        try:
            checkpoint_config.ScpainterConfig.load(os.path.join(checkpoint.resolve(args.checkpoint), "scpainter.json"))
            report["checkpoint"] = "ok"
        except errors.InputError as e:
            report["checkpoint"] = str(e)
    events.done(command=NAME, report=report)
    return events.EXIT_OK


def opencv_report() -> dict:
    """What ``doctor`` says of OpenCV beside cv2's version: ``distributions`` ({name: version} of those installed;
    requirements.txt pins one, opencv-contrib-python-headless), ``contrib`` (opencv_contrib's modules are there:
    ``cv2.ximgproc``), ``video_io`` (the "Video I/O" section of ``cv2.getBuildInformation()``: {backend: "YES ..." |
    "NO"}, e.g. FFMPEG, GStreamer, v4l/v4l2)."""
    import importlib.metadata

    import cv2

    dists = {}
    for name in OPENCV_DISTRIBUTIONS:
        try:
            dists[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    video_io, inside = {}, False
    for line in cv2.getBuildInformation().splitlines():
        if line.strip() == "Video I/O:":
            inside = True
        elif inside and line.startswith("    ") and not line.startswith("      ") and ":" in line:
            name, value = line.strip().split(":", 1)  # a backend, not one of its libraries (indented deeper)
            video_io[name.strip()] = value.strip()
        elif inside and line.strip() and not line.startswith("    "):
            break  # the next section
    return {"distributions": dists, "contrib": hasattr(cv2, "ximgproc"), "video_io": video_io}
