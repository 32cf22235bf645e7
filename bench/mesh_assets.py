"""Mesh -> Gaussian assets: the rendered asset mask against the mesh's own silhouette, by Gaussian count and σ factor.

    .venv/bin/python bench/mesh_assets.py [--counts 5000 20000 ...] [--factors 0.5 0.7 1.0 1.4] [--views 6]
    .venv/bin/python bench/mesh_assets.py --smoke --out /tmp/x   # the procedural car, 2,000 Gaussians, 2 views

Meshes: the procedural test car (``core.shapes.add_car``, 4.4 m, face colours) and, when ``shared/realdata/trellis``
(or ``$SCPAINTER_REALDATA/trellis``) holds them, the real TRELLIS GLBs. Each is converted with
``backend.mesh.asset.sample_gaussians`` and rendered by the condition renderer on the CPU
(``backend.render.gaussians.project`` + ``tiles.rasterize``, the numba kernel ``render`` uses) from ``--views``
cameras around it (15° above the horizon, 50° horizontal field of view, the object's bounding sphere filling 80 % of
the image height: a car close to the camera). The truth is the mesh's own silhouette from the same K and
world_to_camera (``mesh_silhouette.silhouette``: exact point-in-triangle tests at pixel centres).

Reported per (mesh, resolution, σ factor c, count), averaged over the views: IoU of M_a >= 0.5 with the silhouette
(and its worst view), mean |M_a - silhouette| over the pixels of either, how transparent the car is inside its
outline (``leak``) and how much it bleeds outside (``spill``, both per silhouette pixel), the boundary error (mean
distance in pixels between the two masks' boundaries, both directions) and its 95th percentile, σ in pixels at the
object's distance, conversion time (sampling, colours, rotations; the file load is apart) and the median render
time per view. Two sweeps: counts at the default c (512 x 288 and 1024 x 576), and c at a few counts (1024 x 576).

Prints tables and writes bench/results/mesh_assets.json (``--out DIR``). Not a test; ``--smoke``: the procedural
car alone at 128 x 72, 2,000 Gaussians, two σ factors, two views (what its smoke test runs).
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
import torch  # noqa: E402
import trimesh  # noqa: E402

from backend import events  # noqa: E402
from backend.mesh import asset as ma  # noqa: E402
from backend.mesh import load as mesh_load  # noqa: E402
from backend.mesh import silhouette as ms  # noqa: E402
from scpainter_blender.core import outputs, shapes  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)

REALDATA = os.environ.get("SCPAINTER_REALDATA") or os.path.join(ROOT, "..", "shared", "realdata")


def procedural_car() -> mesh_load.MeshAsset:
    """The test car as a face-coloured triangle mesh (Z up, metres, length along Y)."""
    b = shapes.MeshBuilder()
    shapes.add_car(b, np.random.default_rng(0), "paint", "glass", "tyre")
    tri, slot = b.triangles()
    rgb = {"paint": (0.7, 0.1, 0.1), "glass": (0.05, 0.06, 0.08), "tyre": (0.03, 0.03, 0.03)}
    colours = np.array([rgb[m] for m in b.materials])[slot]
    mesh = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3), process=False,
                           face_colors=np.c_[np.round(255 * colours), np.full(len(tri), 255)].astype(np.uint8))
    return mesh_load.MeshAsset("procedural car", [mesh], "z")


def meshes(real: bool = True):
    """[(name, loader)]: the procedural car, then the real TRELLIS GLBs where ``real`` and they are there."""
    out = [("procedural car", procedural_car)]
    if not real:
        return out
    folder = os.path.join(REALDATA, "trellis")
    if os.path.isdir(folder):
        for f in sorted(os.listdir(folder)):
            if f.endswith(".glb"):
                out.append((f, lambda p=os.path.join(folder, f): mesh_load.load_mesh(p)))
    else:
        print(f"(no real TRELLIS GLBs: {os.path.abspath(folder)} is absent)")
    return out


def cameras_for(asset, width, height, views):
    V = asset.vertices
    V = V[np.isfinite(V).all(1)]
    centre = (V.min(0) + V.max(0)) / 2
    r = float(np.linalg.norm(V - centre, axis=1).max())
    fov_x = 50.0
    tan_y = np.tan(np.radians(fov_x) / 2) * height / width
    dist = r / (0.8 * tan_y)                                   # the bounding sphere ~ 80 % of the image height
    return ms.orbit_cameras(centre, dist, width, height, views=views, elevation_deg=15.0, fov_x_deg=fov_x)


def evaluate(asset, sils, cams, width, height, count, factor, seed=0):
    t = time.perf_counter()
    res = ma.sample_gaussians(asset, count, seed=seed, sigma_factor=factor)
    t_convert = time.perf_counter() - t
    per_view, t_render = [], []
    for (K, w2c), sil in zip(cams, sils):
        t = time.perf_counter()
        asset_mask = ms.render_mask(res.gaussians, K, w2c, width, height)
        t_render.append(time.perf_counter() - t)
        per_view.append(ms.mask_metrics(asset_mask, sil))
    row = {k: float(np.mean([m[k] for m in per_view])) for k in per_view[0]}
    row["iou_min"] = float(min(m["iou"] for m in per_view))
    row.update(count=count, factor=factor, sigma=res.sigma, sigma_px=None, convert_s=t_convert,
               render_s=statistics.median(t_render), colour_source=res.colour_source)
    # σ in pixels at the object's centre distance (the scale that decides coverage and edge blur)
    K, w2c = cams[0]
    row["sigma_px"] = float(res.sigma * K[0, 0] / np.linalg.norm(w2c[:3, 3]))
    return row


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--counts", type=int, nargs="+", default=[5_000, 20_000, 50_000, 100_000, 200_000, 500_000])
    p.add_argument("--factors", type=float, nargs="+", default=[0.4, 0.5, 0.7, 0.85, 1.0])
    p.add_argument("--factor-counts", type=int, nargs="+", default=[20_000, 50_000, 200_000])
    p.add_argument("--resolutions", nargs="+", default=["512x288", "1024x576"])
    p.add_argument("--views", type=int, default=6)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--json", help="the JSON file (default: mesh_assets.json in --out)")
    bench_cli.add_smoke_and_out(p, "the procedural car at 128 x 72, 2,000 Gaussians, two σ factors, two views")
    args = p.parse_args(argv)
    if args.smoke:
        args.counts, args.factor_counts, args.factors = [2000], [2000], [0.7]
        args.resolutions, args.views = ["128x72"], 2
    args.json = args.json or bench_cli.json_path(args.out, "mesh_assets")
    if not args.smoke:   # (the smoke runs inside the test process: its thread count is left as it is)
        torch.set_num_threads(args.threads)
    res_list = [tuple(int(v) for v in r.split("x")) for r in args.resolutions]
    rows = []
    head = ["mesh", "res", "c", "count", "sigma_px", "iou", "iou_min", "mean_abs", "leak", "spill", "boundary_px",
            "boundary_p95_px", "convert_s", "render_s"]

    def show(r):
        cells = [f"{r['mesh'][:22]:<22}", f"{r['res']:>9}", f"{r['factor']:>4.2f}", f"{r['count']:>8,}"]
        cells += [f"{r[k]:>{max(len(k), 8)}.3f}" for k in head[4:]]
        print(" | ".join(cells), flush=True)

    print(" | ".join([f"{'mesh':<22}", f"{'res':>9}", f"{'c':>4}", f"{'count':>8}"]
                     + [f"{k:>{max(len(k), 8)}}" for k in head[4:]]))
    warm = procedural_car()
    ms.render_mask(ma.mesh_to_gaussians(warm, 1000), *ms.orbit_cameras((0, 0, 0.7), 8, 64, 36, 1)[0], 64, 36)
    for name, make in meshes(real=not args.smoke):
        t = time.perf_counter()
        asset = make()
        t_load = time.perf_counter() - t
        for width, height in res_list:
            cams = cameras_for(asset, width, height, args.views)
            t = time.perf_counter()
            sils = [ms.silhouette(asset.vertices, asset.faces, K, w2c, width, height) for K, w2c in cams]
            t_sil = (time.perf_counter() - t) / len(cams)
            jobs = [(ma.SIGMA_FACTOR, n) for n in args.counts]
            if (width, height) == res_list[-1]:
                jobs += [(c, n) for n in args.factor_counts for c in args.factors if c != ma.SIGMA_FACTOR]
            for factor, count in jobs:
                r = evaluate(asset, sils, cams, width, height, count, factor)
                r.update(mesh=name, res=f"{width}x{height}", load_s=t_load, silhouette_s=t_sil,
                         faces=int(len(asset.faces)),
                         area=float(mesh_load.face_areas(asset.vertices, asset.faces).sum()))
                rows.append(r)
                show(r)
    os.makedirs(os.path.dirname(args.json), exist_ok=True)
    # strict JSON: a boundary distance with no boundary to measure (inf) is written as null
    outputs.write_json(args.json, events.json_safe({
        "machine": {"cpus": os.cpu_count(), "threads": args.threads, "platform": platform.platform(),
                    "torch": torch.__version__, "trimesh": trimesh.__version__},
        "defaults": {"sigma_factor": ma.SIGMA_FACTOR, "opacity": ma.OPACITY, "normal_ratio": ma.NORMAL_RATIO,
                     "count": ma.DEFAULT_COUNT},
        "views": args.views, "rows": rows}))
    print(f"saved {args.json}")


if __name__ == "__main__":
    main()
