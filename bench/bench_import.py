"""Import throughput: VGGT predictions -> Blender point cloud + camera, through the real operator.

    .venv/bin/python bench/bench_import.py [--frames 20 100] [--out bench/results] [--json FILE]
    .venv/bin/python bench/bench_import.py --smoke --out /tmp/x      # 2 frames, percentile 50, one repeat

Synthetic predictions at VGGT's working size (518 x 294, ~152 k pixels a frame), saved as VGGT's demo saves them
(np.savez, with world_points). Reports the whole operator (load, unproject, filter, mesh, camera) and its phases,
in points per second; prints a table and writes bench/results/import.json (or --json). It imports bpy with a
private user folder: run it in a process of its own.
"""

import argparse
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

import bench_cli  # noqa: E402  (bench/, the script's folder)
from tools import blender_env  # noqa: E402


def make_predictions(path, S, H=294, W=518, seed=0):
    import numpy as np

    rng = np.random.default_rng(seed)
    ext = np.tile(np.eye(3, 4, dtype=np.float32), (S, 1, 1))
    ext[:, 2, 3] = -np.arange(S, dtype=np.float32) * 0.05  # driving forward
    intr = np.tile(np.array([[300, 0, W / 2], [0, 300, H / 2], [0, 0, 1]], np.float32), (S, 1, 1))
    # smooth depth from 0.2 to 3 (per-pixel noise would make every pixel a depth edge, which cleaning removes)
    v, u = np.mgrid[0:H, 0:W].astype(np.float32) + 0.5
    depth = np.broadcast_to((0.2 + 2.8 * v / H + 0.05 * np.sin(u / 40))[None, :, :, None], (S, H, W, 1))
    depth = depth.astype(np.float32)
    # world_points: the depth unprojected through the same cameras (the import checks that they agree)
    cam = np.stack([(u - W / 2) / 300, (v - H / 2) / 300, np.ones_like(u)], -1)[None] * depth    # (S, H, W, 3)
    world = np.einsum("sji,shwj->shwi", ext[:, :, :3], cam - ext[:, None, None, :, 3])         # R^T (x - t)
    np.savez(path, images=rng.random((S, 3, H, W), dtype=np.float32), depth=depth,
             depth_conf=(1 + rng.exponential(2.0, (S, H, W))).astype(np.float32), extrinsic=ext, intrinsic=intr,
             world_points=world.astype(np.float32),
             world_points_conf=(1 + rng.exponential(2.0, (S, H, W))).astype(np.float32))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", type=int, nargs="+", default=[20, 100])
    p.add_argument("--percentiles", type=float, nargs="+", default=[0.0, 50.0])
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--json", help="the JSON file (default: import.json in --out)")
    bench_cli.add_smoke_and_out(p, "2 frames, percentile 50, one repeat")
    args = p.parse_args(argv)
    if args.smoke:
        args.frames, args.percentiles, args.repeats = [2], [50.0], 1
    args.json = args.json or bench_cli.json_path(args.out, "import")
    work = tempfile.mkdtemp(prefix="scpainter-bench-")
    pkg = blender_env.install_for_script(work)
    import bpy
    importer = sys.modules[pkg + ".scpainter_blender.scene.importer"]
    options = sys.modules[pkg + ".scpainter_blender.core.import_options"]
    rows = []
    for S in args.frames:
        path = os.path.join(work, f"pred_{S}.npz")
        make_predictions(path, S)
        for pct in args.percentiles:
            best = None
            for _ in range(args.repeats):
                bpy.ops.wm.read_homefile(use_empty=True)
                t = time.perf_counter()
                assert bpy.ops.scpainter.import_vggt(filepath=path, confidence_percentile=pct) == {"FINISHED"}
                op = time.perf_counter() - t
                bpy.ops.wm.read_homefile(use_empty=True)
                r = importer.import_vggt(bpy.context, path, options.ImportOptions(confidence_percentile=pct))
                row = {"frames": S, "percentile": pct, "points": r.num_points, "operator_s": op,
                       **{f"{k}_s": v for k, v in r.timings.items()}}
                if best is None or op < best["operator_s"]:
                    best = row
            best["points_per_s"] = best["points"] / best["operator_s"]
            rows.append(best)
    head = ["frames", "percentile", "points", "operator_s", "load_s", "unproject_s", "points_object_s",
            "camera_s", "points_per_s"]
    print(" | ".join(f"{h:>15}" for h in head))
    for r in rows:
        print(" | ".join(f"{r[h]:>15,.3f}" if isinstance(r[h], float) else f"{r[h]:>15,}" for h in head))
    blender_env.write_bench_json(args.json, rows)
    print(f"saved {args.json}")


if __name__ == "__main__":
    main()
