"""PlayCanvas splat-transform (the real writer and reader of today's splat formats) for tests, or a skip.

``convert(src, dst, *options)`` runs ``tools/splat_transform/node_modules/.bin/splat-transform -q -w -g cpu
[options] SRC DST`` (installed by ``npm ci`` in ``tools/splat_transform`` when Node is there) and fails the test
with its output when it fails; a test calling it is skipped, saying why, when Node or the tool is absent. Node is
for tests only: the product never runs it.
"""

import os
import shutil
import subprocess

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXECUTABLE = os.path.join(ROOT, "tools", "splat_transform", "node_modules", ".bin", "splat-transform")


def executable() -> str:
    """The splat-transform command, or skip the test saying what is missing."""
    if shutil.which("node") is None:
        pytest.skip("node is not on PATH: splat-transform (tools/splat_transform) cannot run")
    if not os.path.isfile(EXECUTABLE):
        pytest.skip(f"splat-transform is not installed at {EXECUTABLE}: run `npm ci` in tools/splat_transform")
    return EXECUTABLE


def convert(src, dst, *options, timeout: float = 600.0) -> str:
    """Convert ``src`` to ``dst`` (formats by extension) with splat-transform; the output path."""
    cmd = [executable(), "-q", "-w", "-g", "cpu", *map(str, options), os.fspath(src), os.fspath(dst)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0 and os.path.isfile(dst), f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stdout}{r.stderr}"
    return os.fspath(dst)
