"""PlayCanvas splat-transform (the real writer and reader of today's splat formats) for tests, or a skip.

``convert(src, dst, *options)`` runs ``tools/splat_transform/node_modules/.bin/splat-transform -q -w -g cpu
[options] SRC DST`` (installed by ``npm ci`` in ``tools/splat_transform`` when Node is there) and fails the test
with its output when it fails; a test calling it is skipped, saying why, when Node or the tool is absent. Node is
for tests only: the product never runs it. ``niantic_load(paths)`` reads SPZ files with Niantic's own loader (its
WebAssembly build ``@adobe/spz``, which splat-transform installs and writes with).
"""

import json
import os
import shutil
import subprocess

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXECUTABLE = os.path.join(ROOT, "tools", "splat_transform", "node_modules", ".bin", "splat-transform")
#: Niantic's SPZ library as WebAssembly (a dependency of splat-transform, pinned by its package-lock.json).
NIANTIC_SPZ = os.path.join(ROOT, "tools", "splat_transform", "node_modules", "@adobe", "spz", "dist", "spz.js")
#: Loads each SPZ file named on the command line with ``loadSpzFromBuffer(bytes, {to: RUB})`` and prints one JSON
#: line: per file numPoints, shDegree, positions (x y z), rotations (x y z w), scales (log), sh (coefficient-major,
#: colour innermost), the number of extensions read. (The library also logs to stdout: the JSON is the last line.)
_NIANTIC_LOAD = """
const {default: createSpzModule} = await import(process.argv[1]);
const fs = await import("fs");
const spz = await createSpzModule();
const out = {};
for (const f of process.argv.slice(2)) {
  const c = spz.loadSpzFromBuffer(new Uint8Array(fs.readFileSync(f)), {to: spz.CoordinateSystem.RUB});
  out[f] = {numPoints: c.numPoints, shDegree: c.shDegree, positions: Array.from(c.positions),
            rotations: Array.from(c.rotations), scales: Array.from(c.scales), sh: Array.from(c.sh),
            extensions: c.extensions.length};
}
console.log(JSON.stringify(out));
"""


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


def niantic_load(paths, timeout: float = 120.0) -> dict:
    """{path: what Niantic's loader returns for it with ``to = RUB``} (``_NIANTIC_LOAD``'s fields, lists of floats),
    or skip the test saying what is missing."""
    executable()
    if not os.path.isfile(NIANTIC_SPZ):
        pytest.skip(f"Niantic's SPZ library is not installed at {NIANTIC_SPZ}: run `npm ci` in tools/splat_transform")
    paths = [os.fspath(p) for p in paths]
    cmd = ["node", "--input-type=module", "-e", _NIANTIC_LOAD, NIANTIC_SPZ, *paths]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    lines = [line for line in r.stdout.splitlines() if line.startswith("{")]
    assert r.returncode == 0 and lines, f"Niantic's loader failed ({r.returncode}):\n{r.stdout[-2000:]}{r.stderr}"
    return json.loads(lines[-1])
