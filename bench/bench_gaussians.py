"""Gaussian asset import and viewport-preview cost at 100 k and 500 k Gaussians.

    .venv/bin/python bench/bench_gaussians.py [--counts 100000 500000] [--smoke] [--out DIR]

The procedural car saved as Amodal3R saves it, imported through the real operator; then the Geometry Nodes
preview evaluated (the CPU side of what the viewport pays on every change of the asset) for sprites and for
ellipsoids. GPU drawing is not measured: there is no display here.
Prints a table and writes <--out>/gaussians.json (default bench/results). ``--smoke``: one 2 000-Gaussian car, in
seconds (tests/bench/test_bench_gaussians.py runs it in a process of its own: Blender's user folder must be set
before bpy is imported).
"""

import argparse
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from tools import blender_env  # noqa: E402


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--counts", type=int, nargs="+", default=None, help="default 100000 500000 (--smoke: 2000)")
    p.add_argument("--smoke", action="store_true", help="one small car: the suite's check that the bench runs")
    p.add_argument("--out", default=os.path.join(ROOT, "bench", "results"), help="where gaussians.json goes")
    args = p.parse_args(argv)
    counts = args.counts or ([2_000] if args.smoke else [100_000, 500_000])
    json_path = os.path.join(args.out, "gaussians.json")
    work = tempfile.mkdtemp(prefix="scpainter-bench-")
    pkg = blender_env.install_for_script(work)
    import bpy

    from scpainter_blender.core import shapes

    gaussians = sys.modules[pkg + ".scpainter_blender.scene.gaussians"]
    rows = []
    for n in counts:
        path = os.path.join(work, f"car_{n}.ply")
        shapes.save_as_amodal3r(path, shapes.procedural_car_gaussians(count=n, seed=0))
        bpy.ops.wm.read_homefile(use_empty=True)
        t = time.perf_counter()
        assert bpy.ops.scpainter.import_gaussians(filepath=path) == {"FINISHED"}
        row = {"gaussians": n, "file_mb": os.path.getsize(path) / 1e6, "import_s": time.perf_counter() - t}
        obj = bpy.context.active_object
        mod, ident = gaussians.preview_input(obj, "Ellipsoids")
        _, size = gaussians.preview_input(obj, "Size")
        for mode, value in (("sprites", False), ("ellipsoids", True)):
            mod[ident] = value
            best = float("inf")
            for k in range(3):
                mod[size] = 2.0 + 0.01 * k  # a changed input: the modifier really runs again
                obj.update_tag()
                t = time.perf_counter()
                geometry = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).evaluated_geometry()
                count = sum(len(g.attributes["position"].data)
                            for g in (geometry.pointcloud, geometry.instances_pointcloud()) if g)
                best = min(best, time.perf_counter() - t)
                assert count == n
            row[f"{mode}_eval_s"] = best
        rows.append(row)
    head = ["gaussians", "file_mb", "import_s", "sprites_eval_s", "ellipsoids_eval_s"]
    print(" | ".join(f"{h:>17}" for h in head))
    for r in rows:
        print(" | ".join(f"{r[h]:>17,.3f}" if isinstance(r[h], float) else f"{r[h]:>17,}" for h in head))
    blender_env.write_bench_json(json_path, rows)
    print(f"saved {json_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
