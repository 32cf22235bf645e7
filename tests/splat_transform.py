"""PlayCanvas splat-transform for tests (``tools/splat_transform``, pinned; Node is never part of the product's
runtime): the command line that converts Gaussian files with it, or a skip saying what is missing."""

import os
import shutil

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: The installed command (``npm ci`` in tools/splat_transform).
BIN = os.path.join(ROOT, "tools", "splat_transform", "node_modules", ".bin", "splat-transform")


def splat_transform() -> list:
    """The argv prefix ``[node, splat-transform, -q, -w, -g, cpu]`` (quiet, overwrite, CPU k-means) to which the
    input and output files are appended; skips the test when Node or the tool is absent."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not on PATH: splat-transform (the reference writer) runs on Node")
    if not os.path.isfile(BIN):
        pytest.skip(f"splat-transform is not installed at {BIN} (npm ci in tools/splat_transform)")
    return [node, BIN, "-q", "-w", "-g", "cpu"]
