"""Condition EXR size and speed by compression and precision, on the demo's 16 frames.

    .venv/bin/python tools/demo.py --out build/demo        # once: the README's demo, its conditions/
    .venv/bin/python bench/exr_sizes.py [--demo build/demo] [--repeats 3] [--out bench/results]
    .venv/bin/python bench/exr_sizes.py --smoke --out /tmp/x       # two synthetic 64 x 48 frames, one repeat

The layers are the demo's own condition frames (the ground-truth street seen from the camera path 2 m to the left,
a procedural Gaussian car parked beside the road; ``tools/demo.py``), read with ``channels.read`` and written
again in each variant: uncompressed float32 (what the former hand-made writer made), ZIP float32 (the default of
``channels.write``), ZIP with I, M, M_a as half and Z float32 (``--half-float``), and the same two with PIZ and
ZSTD (OpenEXR ≥ 3.4 only) for comparison. Every variant is written the way ``channels.write`` writes (OpenEXR,
one scanline part, atomically); the ZIP ones are checked to be byte-identical to ``channels.write``'s files.

Per variant: total MB of the 16 frames, write and read ms per frame (``channels.read``; the median over the
repeats of the mean over the frames, the variants interleaved in each repeat so that a busy machine slows all
alike), and the largest absolute error per layer against the float32 layers (0 for lossless variants).
Prints a table and writes bench/results/exr_sizes.json.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

import numpy as np  # noqa: E402
import OpenEXR  # noqa: E402

from backend.render import channels  # noqa: E402
from scpainter_blender.core import outputs  # noqa: E402
from scpainter_blender.core.output_layout import CONDITION_EXR, OutputLayout  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)

#: name -> (OpenEXR compression, half): the variants measured.
VARIANTS = {
    "none float32": (OpenEXR.NO_COMPRESSION, False),
    "ZIP float32": (OpenEXR.ZIP_COMPRESSION, False),
    "ZIP half I/M/M_a + float Z": (OpenEXR.ZIP_COMPRESSION, True),
    "PIZ float32": (OpenEXR.PIZ_COMPRESSION, False),
    "PIZ half I/M/M_a + float Z": (OpenEXR.PIZ_COMPRESSION, True),
    "ZSTD float32": (OpenEXR.ZSTD_COMPRESSION, False),
}


def write_variant(path, layers: dict, compression, half: bool) -> None:
    """``channels.write`` with another compression: the same names, pixel types, single scanline part, stream."""
    pixels = {channels.FILE_NAMES[c]: np.ascontiguousarray(
        layers[c], np.float16 if half and c in channels.HALF_LAYERS else np.float32) for c in channels.CHANNELS}
    image = OpenEXR.File({"compression": compression, "type": OpenEXR.scanlineimage}, pixels)
    with outputs.atomic_write(path) as f:
        image.write(f)


def max_abs_error(a, b) -> float:
    """The largest |a − b|, equal infinities (an empty pixel's depth) counting as no error."""
    same = (a == b)  # (inf == inf is True; inf − inf would be NaN)
    with np.errstate(invalid="ignore"):
        return float(np.max(np.where(same, 0.0, np.abs(a.astype(np.float64) - b))))


def synthetic_frames(count: int = 2, width: int = 64, height: int = 48) -> list:
    """``count`` condition frames (``channels.CHANNELS`` -> (H, W) float32) of a smooth image with a hole, a car
    mask, depth with empty (inf) pixels and instance ids: what ``--smoke`` measures instead of the demo's frames."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    frames = []
    for i in range(count):
        hole = ((xx - width * (0.3 + 0.1 * i)) ** 2 + (yy - height / 2) ** 2 < (height / 4) ** 2).astype(np.float32)
        car = ((abs(xx - width * 0.7) < width / 8) & (abs(yy - height * 0.6) < height / 6)).astype(np.float32)
        image = {c: (0.5 + 0.5 * np.sin(xx / (7 + k) + yy / 11 + i)) * (1 - hole) for k, c in enumerate(channels.IMAGE)}
        depth = np.where(hole > 0, np.inf, 5.0 + yy / height * 20).astype(np.float32)
        frames.append({**{c: v.astype(np.float32) for c, v in image.items()}, channels.HOLE: hole,
                       channels.ASSET_MASK: car, channels.DEPTH: depth, channels.INSTANCE: car * 1.0})
    return frames


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--demo", default=os.path.join(ROOT, "build", "demo"), help="tools/demo.py's --out folder")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", help="the JSON file (default: exr_sizes.json in --out)")
    bench_cli.add_smoke_and_out(p, "two synthetic 64 x 48 frames, one repeat")
    args = p.parse_args(argv)
    args.json = args.json or bench_cli.json_path(args.out, "exr_sizes")
    if args.smoke:
        args.repeats, args.demo, frames = 1, "synthetic (--smoke)", synthetic_frames()
    else:
        folder = OutputLayout(args.demo).conditions
        sources = CONDITION_EXR.in_folder(folder)
        if not sources:
            raise SystemExit(f"no condition frames in {folder}: run tools/demo.py --out {args.demo}")
        frames = [channels.read(f) for f in sources]
    H, W = frames[0]["R"].shape
    print(f"{len(frames)} demo frames {W}x{H} from {args.demo}; {args.repeats} repeats", file=sys.stderr)
    times = {v: {"write": [], "read": []} for v in VARIANTS}
    sizes, errors = {}, {}
    with tempfile.TemporaryDirectory(prefix="exr_sizes_") as tmp:
        for r in range(args.repeats):
            for name, (compression, half) in VARIANTS.items():
                paths = [os.path.join(tmp, f"{name.split()[0]}_{half}_{i}.exr") for i in range(len(frames))]
                t = time.perf_counter()
                for path, layers in zip(paths, frames):
                    write_variant(path, layers, compression, half)
                times[name]["write"].append((time.perf_counter() - t) / len(frames))
                t = time.perf_counter()
                back = [channels.read(path) for path in paths]
                times[name]["read"].append((time.perf_counter() - t) / len(frames))
                if r == 0:
                    sizes[name] = sum(os.path.getsize(path) for path in paths)
                    errors[name] = {c: max(max_abs_error(a[c], b[c]) for a, b in zip(frames, back))
                                    for c in channels.CHANNELS}
                    if compression == OpenEXR.ZIP_COMPRESSION:  # the bench writes what the product writes
                        channels.write(os.path.join(tmp, "product.exr"), frames[0], half=half)
                        with open(os.path.join(tmp, "product.exr"), "rb") as a, open(paths[0], "rb") as b:
                            assert a.read() == b.read(), f"{name}: not channels.write's bytes"
    rows = []
    base = sizes["none float32"]
    for name in VARIANTS:
        rows.append({"variant": name, "total_mb": sizes[name] / 1e6, "ratio_to_uncompressed": base / sizes[name],
                     "write_ms_per_frame": 1e3 * statistics.median(times[name]["write"]),
                     "read_ms_per_frame": 1e3 * statistics.median(times[name]["read"]),
                     "write_ms_all_repeats": [1e3 * t for t in times[name]["write"]],
                     "read_ms_all_repeats": [1e3 * t for t in times[name]["read"]],
                     "max_abs_error": errors[name]})
    print(f"{'variant':28s} {'MB':>7s} {'ratio':>6s} {'write ms':>9s} {'read ms':>8s}  "
          "max |error| R G B hole asset_mask Z")
    for row in rows:
        e = row["max_abs_error"]
        print(f"{row['variant']:28s} {row['total_mb']:7.2f} {row['ratio_to_uncompressed']:6.2f} "
              f"{row['write_ms_per_frame']:9.1f} {row['read_ms_per_frame']:8.1f}  "
              + " ".join(f"{e[c]:.1e}" if e[c] else "0" for c in channels.CHANNELS))
    outputs.write_json(args.json, {
        "what": "condition EXR size and speed per compression/precision on the demo's frames (bench/exr_sizes.py)",
        "source": args.demo if args.smoke else os.path.abspath(args.demo), "frames": len(frames), "width": W, "height": H,
        "repeats": args.repeats, "openexr": OpenEXR.__version__, "machine": platform.machine(),
        "cpus": os.cpu_count(), "python": platform.python_version(), "rows": rows})
    print(f"wrote {args.json}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
