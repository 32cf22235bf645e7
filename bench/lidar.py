"""The simulated LiDAR (``backend/lidar``): its error against its time, and its speed on a street-sized scene.

    .venv/bin/python bench/lidar.py [--smoke] [--repeats 5] [--out bench/results] [--json FILE]

(a) **Error against time** on the plane-and-box scene of the tests (``tests/backend/lidar/lidar_scenes.py``: a
    60 m square of ground and a 1.8 x 4.5 x 1.5 m box 9.5 m away, sampled as points, the ground's density ∝ 1/r³
    from the sensor's foot), the ``nuscenes-32`` model, one row per resolution setting: the footprint α, the
    azimuth step (the model's 1/3°, or 1/6°) and the point density (ground points, box points per m²). Per row:
    seconds per sweep (the median of the repeats), the returns, the largest range error of the returns at least
    two footprints from any edge and the share of such rays that return nothing, the 99th percentile of the error
    over every return with an analytic hit, and the box's count (returns in its label box, 5 cm larger) against
    the analytic one (rays whose first hit is the box).
(b) **Speed**: a street of 3 M points (road, pavements, two facades) with three Gaussian cars (procedural, 100 k
    Gaussians each), the sensor driven along it, ``nuscenes-32`` and ``velodyne-64``, the points stored as a
    reconstruction stores them (frame by frame) and, for ``nuscenes-32``, shuffled: the first call (numba
    compiles, or loads its cache: said in the table), then the median and best wall time of the sweeps after it
    and their CPU time (all threads: on an idle machine the wall time is about CPU / threads; this machine is
    shared, so the load average is printed beside), and the same for the kernels alone (the arrays already
    relative to the sensor, as ``sweep_for_frame`` hands them over: no float64 copy of the points).

Prints the tables and writes the JSON (bench/results/lidar.json by default). ``--smoke``: the smallest sizes, one
setting each, in seconds (tests/bench/test_lidar.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import statistics
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

import backend  # noqa: E402,F401  (NUMBA_CACHE_DIR, OMP_WAIT_POLICY before numba loads)
import numpy as np  # noqa: E402

from backend.lidar import cast, cast_cpu, simulate as sim  # noqa: E402
from backend.lidar.sweep import counts  # noqa: E402
from scpainter_blender.core import outputs, shapes  # noqa: E402
from scpainter_blender.core.lidar_model import MODELS  # noqa: E402
from tests.backend.lidar.lidar_scenes import PlaneBox, edge_clearance  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)



def accuracy_row(scene, pts, rgb, model, settings, repeats):
    T = scene.lidar_to_world()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        sweep = sim.simulate(model, T, pts, rgb, settings=settings)
        times.append(time.perf_counter() - t)
    d0, e1, e2 = cast.ray_bases(model)
    rng, surface = scene.cast(T[:3, 3], d0)
    clear = edge_clearance(scene, T[:3, 3], d0, e1, e2, 2 * np.deg2rad(settings.footprint_deg))
    col, row = sweep.column, model.beams - 1 - sweep.ring
    err = np.abs(sweep.range_m - rng[col, row])
    both = np.isfinite(err)
    returned = np.zeros(rng.shape, bool)
    returned[col, row] = True
    want = clear & (surface >= 0)
    analytic = int((surface == 1).sum())
    got = int(counts(sweep, [(scene.box_to_world, np.asarray(scene.box_size) + 0.1)])[0])
    return {"seconds": statistics.median(times), "returns": len(sweep), "rays": model.rays,
            "clear_max_error_m": float(err[clear[col, row]].max()),
            "clear_missed_share": float((want & ~returned).sum() / max(want.sum(), 1)),
            "p99_error_m": float(np.percentile(err[both], 99)), "box_count": got, "box_analytic": analytic,
            "box_count_error": (got - analytic) / analytic}


def accuracy_table(smoke: bool, repeats: int) -> list:
    scene = PlaneBox()
    base = MODELS["nuscenes-32"]
    fine = dataclasses.replace(base, name="nuscenes-32/2", azimuth_step_deg=base.azimuth_step_deg / 2)
    if smoke:
        grid = [(0.3, base, 200_000, 1000.0)]
    else:
        grid = [(a, base, 2_000_000, 7000.0) for a in (0.1, 0.15, 0.2, 0.3, 0.45)]
        grid += [(0.3, base, n, d) for n, d in ((500_000, 1750.0), (1_000_000, 3500.0), (4_000_000, 14000.0))]
        grid += [(a, fine, 2_000_000, 7000.0) for a in (0.15, 0.3)]
    rows, samples = [], {}
    for footprint, model, n, density in grid:
        if (n, density) not in samples:
            samples[(n, density)] = scene.sample(n, density, seed=0)
        pts, rgb = samples[(n, density)]
        settings = cast.LidarSettings(footprint_deg=footprint)
        sim.simulate(model, scene.lidar_to_world(), pts[:1000], rgb[:1000], settings=settings)  # compiled
        row = {"footprint_deg": footprint, "azimuth_step_deg": model.azimuth_step_deg, "points": len(pts),
               "ground_points": n, "box_density_m2": density}
        row.update(accuracy_row(scene, pts, rgb, model, settings, repeats))
        rows.append(row)
    return rows


def street(points: int, seed: int = 0, order: str = "frames") -> tuple:
    """(points (N, 3) float64, colours (N, 3)): a 120 m street, y along it: road and pavements (z = 0, |x| <= 10),
    two facades (x = ±10, 0 <= z <= 12); half the points on the ground, half on the facades. ``order``: "frames"
    stores them as a reconstruction does (source frame by source frame, here 2 m of street each, and in rows
    within one), "shuffled" at random (the worst case for the kernels' memory traffic)."""
    rng = np.random.default_rng(seed)
    g, w = points // 2, points - points // 2
    ground = np.column_stack([rng.uniform(-10, 10, g), rng.uniform(-60, 60, g), np.zeros(g)])
    side = np.where(rng.uniform(size=w) < 0.5, -10.0, 10.0)
    walls = np.column_stack([side, rng.uniform(-60, 60, w), rng.uniform(0, 12, w)])
    pts = np.concatenate([ground, walls])
    if order == "frames":
        pts = pts[np.lexsort((pts[:, 0], np.floor(pts[:, 2] / 0.05), np.floor(pts[:, 1] / 2.0)))]
    rgb = rng.uniform(0.2, 0.8, (points, 3)).astype(np.float32)
    return pts, rgb


def speed_table(smoke: bool, repeats: int) -> list:
    n_points, n_gauss, sweeps = (200_000, 5_000, 2) if smoke else (3_000_000, 100_000, max(repeats, 5) * 2)
    streets = {order: street(n_points, order=order) for order in ("frames", "shuffled")}
    cars = []
    for k, (x, y) in enumerate(((-3.5, 8.0), (3.5, -6.0), (-3.5, 20.0))):
        g = shapes.procedural_car_gaussians(count=n_gauss, seed=k)
        cars.append((g.means + (x, y, 0.0), g.opacities, None))
    rows = []
    for name, order in (("nuscenes-32", "frames"), ("nuscenes-32", "shuffled"), ("velodyne-64", "frames")):
        model = MODELS[name]
        pts, rgb = streets[order]
        poses = []
        for i in range(sweeps + 1):
            T = np.eye(4)
            T[:3, 3] = (0.5, -20.0 + 40.0 * i / max(sweeps, 1), 1.84)
            poses.append(T)
        cached = cast_cpu.kernels_cached()
        t = time.perf_counter()
        first = sim.simulate(model, poses[0], pts, rgb, gaussians=cars)
        first_s = time.perf_counter() - t
        times, cpu, returns, car_returns = [], [], [], []
        for T in poses[1:]:
            t, c = time.perf_counter(), time.process_time()
            s = sim.simulate(model, T, pts, rgb, gaussians=cars)
            times.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
            returns.append(len(s))
            car_returns.append(int((s.source > 0).sum()))
        # the kernels alone, on arrays already relative to the sensor (what sweep_for_frame hands them)
        xyz = (pts - poses[1][:3, 3]).astype(np.float32)
        cx = np.concatenate([sim.gaussian_samples(m, o, c, np.eye(4), poses[1][:3, 3], 0.5)[0] for m, o, c in cars])
        crgb = np.full((len(cx), 3), 0.5, np.float32)
        kt, kc = [], []
        for _ in range(max(2, repeats)):
            t, c = time.perf_counter(), time.process_time()
            cast_cpu.cast(model, xyz, rgb, cx, crgb, np.eye(3), np.zeros(3), cast.LidarSettings())
            kt.append(time.perf_counter() - t)
            kc.append(time.process_time() - c)
        rows.append({"model": name, "order": order, "points": n_points, "gaussians": 3 * n_gauss, "rays": model.rays,
                     "kernels_cached_before": cached, "first_call_s": first_s,
                     "sweep_median_s": statistics.median(times), "sweep_best_s": min(times),
                     "kernels_median_s": statistics.median(kt), "kernels_best_s": min(kt),
                     "sweep_cpu_median_s": statistics.median(cpu), "kernels_cpu_median_s": statistics.median(kc),
                     "load_average": os.getloadavg()[0],
                     "returns": int(statistics.median(returns)), "car_returns": int(statistics.median(car_returns)),
                     "first_returns": len(first)})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5, help="(--smoke: 1)")
    ap.add_argument("--json", help="the JSON file (default: lidar.json in --out)")
    bench_cli.add_smoke_and_out(ap, "the smallest sizes, one setting each, one repeat")
    args = ap.parse_args(argv)
    if args.smoke:
        args.repeats = 1
    args.json = args.json or bench_cli.json_path(args.out, "lidar")
    import numba

    t = time.perf_counter()
    cached = cast_cpu.kernels_cached()
    warm_s = cast_cpu.warm()
    print(f"kernels: {'loaded from the cache' if cached else 'compiled'} in {warm_s:.2f} s "
          f"(numba {numba.__version__}, {numba.get_num_threads()} threads, {os.cpu_count()} CPUs)")
    acc = accuracy_table(args.smoke, args.repeats)
    print("\n(a) error against time: nuscenes-32 over a ground plane and a box (ranges in mm)")
    print(f"{'footprint':>9} {'az step':>8} {'points':>9} {'s/sweep':>8} {'returns':>7} {'clear max':>9} "
          f"{'missed %':>8} {'p99':>7} {'box':>5} {'analytic':>8} {'box err %':>9}")
    for r in acc:
        print(f"{r['footprint_deg']:>9.2f} {r['azimuth_step_deg']:>8.3f} {r['points']:>9d} {r['seconds']:>8.3f} "
              f"{r['returns']:>7d} {1000 * r['clear_max_error_m']:>9.2f} {100 * r['clear_missed_share']:>8.2f} "
              f"{1000 * r['p99_error_m']:>7.2f} {r['box_count']:>5d} {r['box_analytic']:>8d} "
              f"{100 * r['box_count_error']:>9.1f}")
    speed = speed_table(args.smoke, args.repeats)
    print("\n(b) speed: a street of points with three Gaussian cars, the sensor driven along it")
    print(f"{'model':>12} {'order':>8} {'points':>9} {'gaussians':>9} {'rays':>7} {'first s':>8} {'median s':>8} {'best s':>7} "
          f"{'cpu s':>6} {'kernels s':>9} {'k cpu s':>7} {'returns':>7} {'on cars':>7} {'load':>5}")
    for r in speed:
        print(f"{r['model']:>12} {r['order']:>8} {r['points']:>9d} {r['gaussians']:>9d} {r['rays']:>7d} {r['first_call_s']:>8.3f} "
              f"{r['sweep_median_s']:>8.3f} {r['sweep_best_s']:>7.3f} {r['sweep_cpu_median_s']:>6.3f} "
              f"{r['kernels_median_s']:>9.3f} {r['kernels_cpu_median_s']:>7.3f} {r['returns']:>7d} "
              f"{r['car_returns']:>7d} {r['load_average']:>5.1f}")
    out = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "numba": numba.__version__,
                       "numba_threads": numba.get_num_threads()},
           "kernels": {"cached_before": cached, "warm_s": warm_s}, "smoke": args.smoke,
           "accuracy": acc, "speed": speed, "total_s": time.perf_counter() - t}
    os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
    outputs.write_json(args.json, out)
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
