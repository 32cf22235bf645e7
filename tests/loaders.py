"""The dataset loaders teams train with (requirements-loaders.txt: torchvision, vcd), run on our exports in a
subprocess: ``run(code, *args)`` executes ``code`` with ``.venv/loaders`` first on the path and returns the JSON
object it prints last. The loaders stay out of the test process itself, as out of the product's environment (the
requirements file says why); pycocotools, already a test dependency of the main environment, is there too.

torchvision on PyPI is built against CUDA torch. With the CPU build of torch its C operators cannot load, and its
import stops where it registers shapes for ``torchvision::nms`` and ``torchvision::qnms``; ``PRELUDE`` declares those
two schemas (no kernel: detection code would fail loudly) so that the pure-Python dataset code — ``CocoDetection``,
``wrap_dataset_for_transforms_v2`` — imports and runs unchanged. With a torchvision whose C operators load, nothing
is declared.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LOADERS = os.environ.get("SCPAINTER_LOADERS_DIR", os.path.join(ROOT, ".venv", "loaders"))

PRELUDE = """
import glob, importlib.util, json, os, sys
import torch
def _torchvision_ops():
    spec = importlib.util.find_spec("torchvision")
    libs = glob.glob(os.path.join(spec.submodule_search_locations[0], "_C*.so")) if spec else []
    try:
        torch.ops.load_library(libs[0])
        return True
    except (IndexError, OSError, RuntimeError):
        return False
if not _torchvision_ops():
    _lib = torch.library.Library("torchvision", "DEF")
    for _name in ("nms", "qnms"):
        _lib.define(_name + "(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
"""


def available(*modules: str) -> bool:
    """Whether ``LOADERS`` holds each of ``modules`` (top-level package names)."""
    return all(os.path.isdir(os.path.join(LOADERS, m)) for m in modules)


def require(*modules: str) -> None:
    """Skip the calling test, saying how to get them, when the loaders are not installed."""
    if not available(*modules):
        pytest.skip(f"the test-only loaders {modules} are not in {LOADERS}: run tools/setup.sh "
                    "(requirements-loaders.txt)")


def run(code: str, *args: str, timeout: float = 600.0) -> dict:
    """Run ``code`` (after ``PRELUDE``) in a fresh interpreter with the loaders on its path and ``args`` as
    ``sys.argv[1:]``; the JSON object it printed last. AssertionError with its output when it fails."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([LOADERS, ROOT, os.environ.get("PYTHONPATH", "")]),
           "PYTHONWARNINGS": "ignore"}
    proc = subprocess.run([sys.executable, "-c", PRELUDE + code, *args], capture_output=True, text=True,
                          env=env, timeout=timeout, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, f"loader run failed ({proc.returncode}):\n{proc.stdout}\n{proc.stderr}"
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    assert lines, f"the loader printed no JSON object:\n{proc.stdout}\n{proc.stderr}"
    return json.loads(lines[-1])
