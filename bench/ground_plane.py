"""The ground plane behind the camera-height scale: the core numpy RANSAC against open3d's ``segment_plane``.

    .venv/bin/python bench/ground_plane.py [--repeats 5] [--seeds 0 1 2 3 4] [--smoke] [--out bench/results]

Both fit the same ground candidates of the ground-truth street (``point_cloud.ground_candidates``: the confident
pixels of the lower 40 % of each image, as the import takes them) with the same inlier threshold (1 % of the
median candidate depth) and the same iteration budget; open3d's plane is then refined by least squares on its
inliers, as the core fit refines its own. Reported per fit, side by side in one run: seconds (median of the
repeats), the angle between the normal and the true road normal, the metric scale's error against the street's
known metres per unit (via ``vggt_to_world_by_camera_height`` with the street's camera height), and the inlier
count. The ratio of the two times is what carries to other machines. open3d is a benchmark-only comparison
here: the add-on fits in Blender's own process with the core fit.

Prints a table and writes bench/results/ground_plane.json. ``--smoke``: one seed, one run, 200 iterations on a
tenth of the candidates.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

import numpy as np  # noqa: E402

from scpainter_blender.core.geometry import cameras, fits as geometry, metric_scale, point_cloud
from scpainter_blender.core import outputs
from scpainter_blender.core.vggt import npz as vggt_io  # noqa: E402
from scpainter_blender.street.dataset import ensure_street  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)


def open3d_fit(points, threshold, iterations, seed, up):
    """open3d's RANSAC (inlier: distance < threshold), refined by least squares on its inliers like the core fit."""
    import open3d as o3d

    o3d.utility.random.seed(seed)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    _, idx = cloud.segment_plane(distance_threshold=threshold, ransac_n=3, num_iterations=iterations)
    inliers = np.zeros(len(points), bool)
    inliers[np.asarray(idx)] = True
    Q = points[inliers]
    c = Q.mean(axis=0)
    n = np.linalg.svd(Q - c, full_matrices=False)[2][2]
    n = n if n @ up >= 0 else -n
    return np.append(n, -n @ c), inliers


def timed(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--iterations", type=int, default=2000)
    bench_cli.add_smoke_and_out(ap, "one seed, one run, 200 iterations")
    args = ap.parse_args(argv)
    if args.smoke:
        args.repeats, args.seeds, args.iterations = 1, args.seeds[:1], 200

    street = ensure_street()
    metric = street.metric()
    height = float(metric["camera_height_m"])
    true_scale = float(metric["metres_per_unit"])
    pred = vggt_io.load_predictions(street.predictions_path, world_points=False)
    w2c = pred.world_to_camera
    # the true road normal in VGGT's world: world +Z taken back through vggt_to_world's rotation
    W = np.asarray(metric["vggt_to_world"], np.float64)
    true_up = np.linalg.solve(W[:3, :3], [0.0, 0.0, 1.0])
    true_up /= np.linalg.norm(true_up)
    t0 = time.perf_counter()
    points = point_cloud.ground_candidates(pred, 50.0, seed=0)
    candidates_s = time.perf_counter() - t0
    if args.smoke:  # a tenth of the candidates: open3d's fit alone takes seconds on all of them
        points = points[::10]
    up = geometry.cameras_up(w2c)
    depth = float(np.median(np.linalg.norm(points - cameras.camera_centers(w2c).mean(axis=0), axis=1)))
    threshold = 0.01 * depth

    def score(plane, inliers):
        n = plane[:3] / np.linalg.norm(plane[:3])
        angle = float(np.degrees(np.arccos(min(1.0, abs(n @ true_up)))))
        fit = metric_scale.vggt_to_world_by_camera_height(plane if np.median(
            cameras.camera_centers(w2c) @ plane[:3] + plane[3]) >= 0 else -plane, w2c, height)
        return {"normal_error_deg": angle, "scale_rel_error": abs(fit.scale / true_scale - 1.0),
                "inliers": int(np.count_nonzero(inliers))}

    rows = []
    for seed in args.seeds:
        core_s, core = timed(lambda: geometry.fit_plane_ransac(points, threshold, iterations=args.iterations,
                                                               seed=seed, up=up, max_tilt_deg=30.0), args.repeats)
        o3d_s, o3d = timed(lambda: open3d_fit(points, threshold, args.iterations, seed, up), args.repeats)
        for name, s, (plane, inliers) in (("core numpy", core_s, core[:2]), ("open3d", o3d_s, o3d)):
            rows.append({"fit": name, "seed": seed, "seconds": s, **score(plane, inliers)})
    print(f"{len(points):,} ground candidates ({candidates_s:.3f} s), threshold {threshold:.4g} VGGT units, "
          f"{args.iterations} iterations, median of {args.repeats} runs")
    print(f"{'fit':<11} {'seed':>4} {'seconds':>8} {'normal err (deg)':>17} {'scale rel err':>14} {'inliers':>9}")
    for r in rows:
        print(f"{r['fit']:<11} {r['seed']:>4} {r['seconds']:>8.3f} {r['normal_error_deg']:>17.5f} "
              f"{r['scale_rel_error']:>14.2e} {r['inliers']:>9,}")
    core_t = statistics.median(r["seconds"] for r in rows if r["fit"] == "core numpy")
    o3d_t = statistics.median(r["seconds"] for r in rows if r["fit"] == "open3d")
    print(f"median time: core {core_t:.3f} s, open3d {o3d_t:.3f} s (open3d / core = {o3d_t / core_t:.2f})")
    import open3d

    outputs.write_json(bench_cli.json_path(args.out, "ground_plane"), {
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "open3d": open3d.__version__,
                    "numpy": np.__version__},
        "candidates": len(points), "candidates_seconds": candidates_s, "threshold": threshold,
        "iterations": args.iterations, "repeats": args.repeats, "rows": rows,
        "median_seconds": {"core": core_t, "open3d": o3d_t}})


if __name__ == "__main__":
    main()
