"""Point cleaning and frame culling on the ground-truth street: error against run time.

    .venv/bin/python bench/clean_points.py [--sections cleaning sweep timing skip] [--threads 2] [--window 8]
                                           [--percentiles 50 0] [--out bench/results] [--smoke]

cleaning  the street's exact depth made VGGT-like (``vggt_like``, below), then rendered through the real job path
          (``job.save`` → ``frames.load_scene`` → ``frames.render_frame``) into the recorded drive and the drive
          shifted ±2, ±3 m sideways (the Cycles renders of those views are the truth), source frames t ± 8 (the
          evaluation's window), with each filter off and on and both, at confidence percentile 50 (the job's
          default) and 0 (every pixel kept). Per view: PSNR of covered pixels, hole fraction, and the fraction of
          covered pixels showing the wrong surface — ``nearer`` (depth more than 5 % in front of the exact depth's
          render of the same view: streaks and floaters) and ``farther`` (more than 5 % behind it: seen through a
          surface whose points are gone); points kept, cleaning time. Rows "exact depth" use the street's own
          depth: what perfect depth gives, and what each filter costs on it.
sweep     a few values of each filter's parameters (depth-edge ratio; statistical neighbours × std ratio; radius ×
          min points), scored on the ±2, ±3 m views, to choose the defaults in ``core.job.POINT_CLEANING``.
timing    cleaning time per scene and render time per frame, the settings alternated in one run (the other
          sections' times are single runs on a shared machine: read them as orders of magnitude).
skip      time per frame with and without ``Scene.skip_unseen`` (source frames and assets the frame cannot see),
          alternated frame by frame, with a check that the layers are identical: the street job on a path shifted
          3 m with every source frame; and a car (100 k Gaussians) that the camera passes, leaving the view.

VGGT-like depth (``vggt_like``), in this order on each frame's depth map (VGGT units; the sky has the far depth
the street's predictions give it):
  1. blur across discontinuities: a Gaussian blur of σ = ``BLUR_PX`` px of the depth map, so pixels near an edge
     get depths between the two surfaces (flying pixels), as a network's regression head produces;
  2. a smooth multiplicative error: white noise blurred with σ = ``FIELD_PX`` px, scaled to ``FIELD_STD``
     relative standard deviation (depth is wrong by a slowly varying scale, as VGGT's is), times a per-pixel
     ``PIXEL_STD`` relative noise;
  3. floaters: a fraction ``FLOATERS`` of the pixels get their depth multiplied by exp(U(−0.4, 0.4));
  4. confidence as VGGT's is trained (loss conf·err − α log conf: the best conf ∝ 1/err): the street's
     confidence c (1 + 30 e^(−d/20 m)) becomes 1 + (c − 1) / (1 + e/``CONF_ERROR``), e = |d' − d| / d the
     pixel's relative error, so the confidence filter (the job's default percentile, 50) removes part of them.
The colour images are the Cycles renders, unchanged. Seeded (``SEED``).

Timings on a shared 2-core machine are noisy: the timing and skip sections alternate the settings and report
medians (skip: the paired ratio's quartiles too); compare ratios within one run. Prints tables, writes
bench/results/clean_points.json (``--out DIR``; a run keeps the sections it does not redo). ``--smoke``: the
cleaning section alone on the street's first 2 frames, window ±1, the recorded and the 2 m left view, three settings
(exact depth, VGGT-like, VGGT-like with the depth-edge filter), percentile 50.
"""

from __future__ import annotations

import argparse
import json
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
import torch  # noqa: E402
from scipy import ndimage  # noqa: E402

from backend.render import frames as fr  # noqa: E402
from scpainter_blender.core import job as job_mod  # noqa: E402
from scpainter_blender.core import outputs, shapes
from scpainter_blender.core.vggt import npz as vggt_io  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)

BLUR_PX = 1.5
FIELD_PX = 8.0
FIELD_STD = 0.01
PIXEL_STD = 0.0025
FLOATERS = 0.003
CONF_ERROR = 0.05
SEED = 0
SHIFTS = (0.0, 2.0, -2.0, 3.0, -3.0)
WRONG_DEPTH = 0.05  # relative depth error that counts a covered pixel as showing the wrong surface
SMOKE = {"frames": 2, "window": 1, "shifts": (0.0, 2.0), "settings": 3}   # what --smoke keeps
_frames = None   # the street's first N frames only (--smoke), else all


def vggt_like(depth, conf, seed=SEED):
    """VGGT-like depth (S, H, W) and confidence from exact ``depth`` (S, H, W) and ``conf``: see the module text."""
    rng = np.random.default_rng(seed)
    d_out, c_out = np.empty_like(depth), np.empty_like(conf)
    for i in range(len(depth)):
        d = depth[i].astype(np.float64)
        blurred = ndimage.gaussian_filter(d, BLUR_PX, mode="nearest")
        field = ndimage.gaussian_filter(rng.standard_normal(d.shape), FIELD_PX, mode="wrap")
        field *= FIELD_STD / field.std()
        noisy = blurred * (1.0 + field) * (1.0 + PIXEL_STD * rng.standard_normal(d.shape))
        floaters = rng.random(d.shape) < FLOATERS
        noisy[floaters] *= np.exp(rng.uniform(-0.4, 0.4, int(floaters.sum())))
        err = np.abs(noisy - d) / d
        d_out[i] = noisy
        c_out[i] = 1.0 + (conf[i] - 1.0) / (1.0 + err / CONF_ERROR)
    return d_out, c_out


def write_predictions(street, folder, noisy: bool) -> str:
    """The street's predictions, with VGGT-like depth when ``noisy``, into ``folder``; returns the file name."""
    with np.load(street.predictions_path, allow_pickle=False) as z:
        a = {k: z[k] for k in ("images", "depth", "depth_conf", "extrinsic", "intrinsic")}
    depth, conf = a["depth"][..., 0], a["depth_conf"]
    if noisy:
        depth, conf = vggt_like(depth, conf)
    name = "noisy.npz" if noisy else "exact.npz"
    vggt_io.save_predictions(os.path.join(folder, name), a["images"], depth, conf, a["extrinsic"], a["intrinsic"])
    return name


def street_job(metric, predictions, cams, window, cleaning, folder, assets=(), confidence_percentile=50.0):
    """A job over the street's 16 frames with cameras ``cams`` (S, 4, 4), saved (validated) into ``folder``."""
    S = len(cams) if _frames is None else min(len(cams), _frames)
    frames = [job_mod.Frame(i, metric["K"][i], cams[i], list(range(max(0, i - window), min(S, i + window + 1))))
              for i in range(S)]
    scene = job_mod.Scene(predictions, metric["vggt_to_world"], confidence_percentile, point_cleaning=cleaning)
    job = job_mod.Job((518, 294), frames, "out", scene=scene, assets=list(assets))
    path = os.path.join(folder, "job.json")
    return path, job_mod.save(path, job)


def truth_images(street, view, S):
    from PIL import Image

    return [np.asarray(Image.open(street.frame_path(view, i)).convert("RGB"), np.float64) / 255.0 for i in range(S)]


def score(scene, job, truth, ref_depth=None, skip=True):
    """PSNR of covered pixels, hole fraction, median render ms over the job's frames; with ``ref_depth`` (one
    (H, W) per frame: the exact depth's render of the same view and source frames, every pixel confidence kept),
    the fraction of covered pixels whose depth is more than ``WRONG_DEPTH`` off it: nearer (a streak or floater in
    front of the true surface) or farther (seen through a surface whose points are gone)."""
    scene.skip_unseen = skip
    se, n, holes, times, nearer, farther = 0.0, 0, [], [], 0, 0
    for i, entry in enumerate(job.frames):
        t0 = time.perf_counter()
        layers = fr.render_frame(scene, entry, job.width, job.height)
        times.append(1e3 * (time.perf_counter() - t0))
        covered = layers["hole"] < 0.5
        img = np.stack([layers["R"], layers["G"], layers["B"]], -1).astype(np.float64)
        holes.append(1.0 - covered.mean())
        se += ((img - truth[i]) ** 2)[covered].sum()
        n += 3 * int(covered.sum())
        if ref_depth is not None:
            z, zr = layers["Z"][covered], ref_depth[i][covered]
            nearer += int((z < (1 - WRONG_DEPTH) * zr).sum())
            farther += int((z > (1 + WRONG_DEPTH) * zr).sum())
    mse = se / max(n, 1)
    out = {"psnr_covered_db": float(10 * np.log10(1.0 / mse)), "hole_fraction": float(np.mean(holes)),
           "frame_ms": statistics.median(times)}
    if ref_depth is not None:
        out.update(nearer_fraction=nearer / max(n // 3, 1), farther_fraction=farther / max(n // 3, 1))
    return out


def reference_depths(metric, folder, exact, window, shifts=SHIFTS):
    """Per view: the Z layer of every frame rendered from the exact depth, confidence percentile 0, no cleaning."""
    path, job = street_job(metric, exact, metric["world_to_camera"], window, job_mod.PointCleaning(None, None),
                           folder, confidence_percentile=0.0)
    scene = fr.load_scene(job, path, "cpu")
    out = {}
    for shift in shifts:
        view = "recorded" if shift == 0 else _view(shift)
        cams = metric["world_to_camera"] if shift == 0 else metric[f"world_to_camera_{view}"]
        _, job = street_job(metric, exact, cams, window, job_mod.PointCleaning(None, None), folder)
        out[view] = [fr.render_frame(scene, e, job.width, job.height)["Z"] for e in job.frames]
    return out


def cleaning_setting(edge, outliers):
    return job_mod.PointCleaning(edge, None if outliers is None else job_mod.OutlierRemoval(**outliers))


def run_setting(street, metric, truths, refs, folder, predictions, label, cleaning, window, shifts=SHIFTS,
                percentile=50.0):
    """One cleaning setting: the scene loaded (and cleaned) once, then rendered into every view's cameras."""
    path, job = street_job(metric, predictions, metric["world_to_camera"], window, cleaning, folder,
                           confidence_percentile=percentile)
    t0 = time.perf_counter()
    scene = fr.load_scene(job, path, "cpu")
    load_s = time.perf_counter() - t0
    c = scene.cleaning
    clean_s = c["cloud_s"] + c["outliers_s"]
    rows = []
    for shift in shifts:
        view = "recorded" if shift == 0 else _view(shift)
        cams = metric["world_to_camera"] if shift == 0 else metric[f"world_to_camera_{view}"]
        _, job = street_job(metric, predictions, cams, window, cleaning, folder)
        r = score(scene, job, truths[view], refs[view])
        rows.append({"setting": label, "confidence_percentile": percentile, "shift_m": shift, **r,
                     "points": int(len(scene.xyz)),
                     "depth_edge_points": c["depth_edge_points"], "outlier_points": c["outlier_points"],
                     "load_s": load_s, "cloud_s": c["cloud_s"], "outliers_s": c["outliers_s"],
                     "cleaning_ms_per_frame": 1e3 * clean_s / len(job.frames),
                     "depth_edge_ratio": cleaning.depth_edge_ratio,
                     "outliers": None if cleaning.outliers is None else cleaning.outliers.to_dict()})
        print(f"  {label:38s} p{percentile:g} shift {shift:+.0f}: {r['psnr_covered_db']:.2f} dB, holes "
              f"{r['hole_fraction']:.3f}, nearer {r['nearer_fraction']:.4f}, farther {r['farther_fraction']:.4f}, "
              f"{len(scene.xyz):,} points, cloud {c['cloud_s']:.1f} s, outliers {c['outliers_s']:.1f} s, "
              f"{r['frame_ms']:.0f} ms/frame", flush=True)
    return rows


def _view(shift):
    from scpainter_blender.street.dataset import view_name

    return view_name(shift)


def section_cleaning(street, metric, truths, refs, folder, window, percentiles, shifts=SHIFTS, settings_kept=None):
    exact = write_predictions(street, folder, noisy=False)
    noisy = write_predictions(street, folder, noisy=True)
    d = job_mod.POINT_CLEANING
    stat = d["outliers"] if d["outliers"] and d["outliers"]["method"] == "statistical" else \
        {"method": "statistical", **job_mod.OUTLIER_FIELDS["statistical"]}
    radius = d["outliers"] if d["outliers"] and d["outliers"]["method"] == "radius" else \
        {"method": "radius", **job_mod.OUTLIER_FIELDS["radius"]}
    ratio = d["depth_edge_ratio"] or 0.05
    sname = f"statistical k={stat['neighbours']} std {stat['std_ratio']:g}"
    rname = f"radius {radius['radius_m']:g} m n={radius['min_points']}"
    default = " (default)" if d["outliers"] is None else ""
    settings = [("exact depth, no filter", exact, None, None),
                ("VGGT-like, no filter", noisy, None, None),
                (f"edges {ratio:g}{default}", noisy, ratio, None),
                (sname, noisy, None, stat),
                (rname, noisy, None, radius),
                (f"edges {ratio:g} + {sname}", noisy, ratio, stat),
                (f"edges {ratio:g} + {rname}", noisy, ratio, radius)]
    if d["outliers"] is not None:
        settings.append(("VGGT-like, defaults", noisy, d["depth_edge_ratio"], d["outliers"]))
    settings.append(("exact depth, defaults", exact, d["depth_edge_ratio"], d["outliers"]))
    rows = []
    for pct in percentiles:
        for label, pred, edge, outl in settings[:settings_kept]:
            rows += run_setting(street, metric, truths, refs, folder, pred, label, cleaning_setting(edge, outl),
                                window, shifts, pct)
    return rows


def section_sweep(street, metric, truths, refs, folder, window, percentiles):
    noisy = write_predictions(street, folder, noisy=True)
    shifts = (2.0, -2.0, 3.0, -3.0)
    settings = [("none", None, None)]
    settings += [(f"edges {r:g}", r, None) for r in (0.02, 0.03, 0.05, 0.08, 0.12)]
    settings += [(f"statistical k={k} std {s:g}", None, {"method": "statistical", "neighbours": k, "std_ratio": s})
                 for k in (8, 16, 32) for s in (1.0, 2.0)]
    settings += [(f"radius {r:g} m n={n}", None, {"method": "radius", "radius_m": r, "min_points": n})
                 for r in (0.05, 0.1, 0.2) for n in (4, 16)]
    rows = []
    for pct in percentiles:
        for label, edge, outl in settings:
            rows += run_setting(street, metric, truths, refs, folder, noisy, label, cleaning_setting(edge, outl),
                                window, shifts, pct)
    return rows


def section_timing(street, metric, folder, window, percentiles, repeat=3):
    """Cleaning time per scene and render time per frame, the settings alternated ``repeat`` times in one run
    (medians): the noisy street, VGGT-like depth."""
    noisy = write_predictions(street, folder, noisy=True)
    settings = [("none", None, None), ("edges 0.05", 0.05, None),
                ("statistical k=16 std 2", None, {"method": "statistical", "neighbours": 16, "std_ratio": 2.0}),
                ("radius 0.1 m n=4", None, {"method": "radius", "radius_m": 0.1, "min_points": 4})]
    rows = []
    for pct in percentiles:
        t = {label: {"load": [], "cloud": [], "outliers": [], "frame": []} for label, _, _ in settings}
        for _ in range(repeat):
            for label, edge, outl in settings:
                path, job = street_job(metric, noisy, metric["world_to_camera_left_2m"], window,
                                       cleaning_setting(edge, outl), folder, confidence_percentile=pct)
                t0 = time.perf_counter()
                scene = fr.load_scene(job, path, "cpu")
                t[label]["load"].append(time.perf_counter() - t0)
                t[label]["cloud"].append(scene.cleaning["cloud_s"])
                t[label]["outliers"].append(scene.cleaning["outliers_s"])
                for entry in job.frames:
                    t0 = time.perf_counter()
                    fr.render_frame(scene, entry, job.width, job.height)
                    t[label]["frame"].append(1e3 * (time.perf_counter() - t0))
                t[label]["points"] = int(len(scene.xyz))
        S = len(metric["world_to_camera"])
        for label, _, _ in settings:
            m = {k: statistics.median(v) for k, v in t[label].items() if k != "points"}
            rows.append({"setting": label, "confidence_percentile": pct, "points": t[label]["points"],
                         "load_s": m["load"], "point_cloud_s": m["cloud"], "outliers_s": m["outliers"],
                         "cleaning_ms_per_frame": 1e3 * (m["cloud"] + m["outliers"]) / S, "frame_ms": m["frame"]})
            print(f"  timing {label:24s} p{pct:g}: {rows[-1]}", flush=True)
    return rows


def _equal(a, b):
    return all(np.array_equal(a[k], b[k]) for k in a)


def side_by_side(scene, job, repeat=5):
    """Median ms per frame with and without the skip, alternating frame by frame (so load changes hit both); the
    median and quartiles of the paired ratio without / with; and whether every layer matched."""
    on, off, ratios, same = [], [], [], True
    for _ in range(repeat):
        for entry in job.frames:
            pair = {}
            for skip in (True, False):
                scene.skip_unseen = skip
                t0 = time.perf_counter()
                layers = fr.render_frame(scene, entry, job.width, job.height)
                pair[skip] = 1e3 * (time.perf_counter() - t0)
                if skip:
                    first = layers
                else:
                    same &= _equal(first, layers)
            on.append(pair[True])
            off.append(pair[False])
            ratios.append(pair[False] / pair[True])
    q1, q2, q3 = np.percentile(ratios, [25, 50, 75])
    return {"skip_ms": statistics.median(on), "no_skip_ms": statistics.median(off), "speedup": float(q2),
            "speedup_q1": float(q1), "speedup_q3": float(q3), "identical": bool(same)}


def test_ms(scene, job, repeat=20):
    """Median ms per frame of the skip tests alone (visible_frames, and asset_unseen for each asset)."""
    scene.skip_unseen = True
    times = []
    for _ in range(repeat):
        for e in job.frames:
            w2c = _rel(e, scene)
            t0 = time.perf_counter()
            fr.visible_frames(scene, e.source_frames, e.K, w2c, job.width, job.height, 0)
            for a in scene.assets:
                fr.asset_unseen(a, e.frame, scene.origin, e.K, w2c, job.width, job.height)
            times.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(times)


def section_skip(street, metric, folder):
    rows = []
    exact = write_predictions(street, folder, noisy=False)
    off = job_mod.PointCleaning(None, None)
    S = len(metric["world_to_camera"])
    # the street job on a path shifted 3 m left, every frame's points into every output frame
    path, job = street_job(metric, exact, metric["world_to_camera_left_3m"], S, off, folder)
    scene = fr.load_scene(job, path, "cpu")
    kept = [len(fr.visible_frames(scene, e.source_frames, e.K, _rel(e, scene), job.width, job.height, 0))
            for e in job.frames]
    rows.append({"case": "street, 3 m left, all 16 source frames", **side_by_side(scene, job),
                 "tests_ms": test_ms(scene, job),
                 "source_frames_kept_mean": float(np.mean(kept)), "asset_frames_skipped": 0})
    # a car of 100 k Gaussians (4.4 m, as an Amodal3R file) passed by the camera: 12 m ahead in the next lane at
    # frame 0, 3 m nearer each frame, beside the camera at frame 4 and behind it from frame 5 on
    ply = os.path.join(folder, "car.ply")
    file_from_metric = shapes.save_as_amodal3r(ply, shapes.procedural_car_gaussians(count=100_000, seed=7))
    o2w = {}
    for i in range(S):
        centre = np.linalg.inv(metric["world_to_camera"][i])[:3, 3]
        T = np.eye(4)
        T[:3, 3] = centre + np.array([3.5, 12.0 - 3.0 * i, -street.params.camera_height_m])
        o2w[i] = T @ np.linalg.inv(file_from_metric)
    path, job = street_job(metric, exact, metric["world_to_camera"], 2, off, folder,
                           assets=[job_mod.Asset("car", "car.ply", o2w)])
    scene = fr.load_scene(job, path, "cpu")
    skipped = sum(fr.asset_unseen(scene.assets[0], e.frame, scene.origin, e.K, _rel(e, scene), job.width,
                                  job.height) for e in job.frames)
    kept = [len(fr.visible_frames(scene, e.source_frames, e.K, _rel(e, scene), job.width, job.height, 0))
            for e in job.frames]
    rows.append({"case": "recorded drive, window ±2, a car that leaves the view", **side_by_side(scene, job),
                 "tests_ms": test_ms(scene, job),
                 "source_frames_kept_mean": float(np.mean(kept)), "asset_frames_skipped": int(skipped)})
    return rows


def _rel(entry, scene):
    from backend.render import points as pts

    return pts.relative_camera(np.asarray(entry.world_to_camera, np.float64), scene.origin)


def print_table(title, rows, cols):
    print(f"\n{title}")
    print("| " + " | ".join(cols) + " |")
    print("|" + "|".join("---" for _ in cols) + "|")
    for r in rows:
        print("| " + " | ".join(fmt(r.get(c)) for c in cols) + " |")


def fmt(v):
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 1e-2 or abs(v) >= 1e4 else f"{v:.3f}" if abs(v) < 10 else f"{v:.1f}"
    return str(v)


def summary(rows):
    """Per setting and confidence percentile: means over the shifted views (±2, ±3 m), the 0 m view's PSNR."""
    out = []
    for label, pct in dict.fromkeys((r["setting"], r["confidence_percentile"]) for r in rows):
        sel = [r for r in rows if r["setting"] == label and r["confidence_percentile"] == pct]
        shifted = [r for r in sel if r["shift_m"] != 0]
        mean = lambda k: float(np.mean([r[k] for r in shifted]))  # noqa: E731
        out.append({"setting": label, "confidence_percentile": pct, "psnr_shifted_db": mean("psnr_covered_db"),
                    "holes_shifted": mean("hole_fraction"), "nearer_shifted": mean("nearer_fraction"),
                    "farther_shifted": mean("farther_fraction"),
                    "psnr_0m_db": next((r["psnr_covered_db"] for r in sel if r["shift_m"] == 0), None),
                    "points": sel[0]["points"], "cleaning_s": sel[0]["cloud_s"] + sel[0]["outliers_s"],
                    "cleaning_ms_per_frame": sel[0]["cleaning_ms_per_frame"],
                    "frame_ms": float(np.median([r["frame_ms"] for r in sel]))})
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sections", nargs="+", default=["cleaning", "sweep", "timing", "skip"],
                   choices=["cleaning", "sweep", "timing", "skip"])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--window", type=int, default=8, help="source frames t ± window (the evaluation's default, 8)")
    p.add_argument("--percentiles", type=float, nargs="+", default=[50.0, 0.0],
                   help="confidence percentiles (the job's default 50; 0 keeps every pixel)")
    bench_cli.add_smoke_and_out(p, "the cleaning section on 2 frames, 2 views, 3 settings")
    args = p.parse_args(argv)
    global _frames
    shifts, kept, _frames = SHIFTS, None, None
    if args.smoke:
        args.sections, args.window, args.percentiles = ["cleaning"], SMOKE["window"], [50.0]
        shifts, kept, _frames = SMOKE["shifts"], SMOKE["settings"], SMOKE["frames"]
    args.out = bench_cli.json_path(args.out, "clean_points")
    if not args.smoke:   # (the smoke runs inside the test process: its thread count is left as it is)
        torch.set_num_threads(args.threads)
    from scpainter_blender.street.dataset import ensure_street

    street = ensure_street(log=lambda m: None)
    metric = street.metric()
    S = len(metric["world_to_camera"])
    truths = {("recorded" if s == 0 else _view(s)): truth_images(street, "recorded" if s == 0 else _view(s),
                                                                  S if _frames is None else min(S, _frames))
              for s in shifts}
    result = {"machine": platform.node(), "threads": args.threads, "torch": torch.__version__,
              "window": args.window, "frames": S if _frames is None else min(S, _frames), "resolution": [518, 294],
              "noise": {"blur_px": BLUR_PX, "field_px": FIELD_PX, "field_std": FIELD_STD, "pixel_std": PIXEL_STD,
                        "floaters": FLOATERS, "conf_error": CONF_ERROR, "seed": SEED},
              "defaults": job_mod.POINT_CLEANING}
    if os.path.exists(args.out) and not args.smoke:  # keep the sections this run does not redo
        with open(args.out) as f:
            old = json.load(f)
        result.update({k: old[k] for k in ("cleaning", "cleaning_summary", "sweep", "sweep_summary", "timing",
                                           "skip") if k in old})
    with tempfile.TemporaryDirectory() as folder:
        if "cleaning" in args.sections or "sweep" in args.sections:
            refs = reference_depths(metric, folder, write_predictions(street, folder, noisy=False), args.window,
                                    shifts)
        if "cleaning" in args.sections:
            result["cleaning"] = section_cleaning(street, metric, truths, refs, folder, args.window,
                                                  args.percentiles, shifts, kept)
            result["cleaning_summary"] = summary(result["cleaning"])
        if "sweep" in args.sections:
            result["sweep"] = section_sweep(street, metric, truths, refs, folder, args.window, args.percentiles)
            result["sweep_summary"] = summary(result["sweep"])
        if "timing" in args.sections:
            result["timing"] = section_timing(street, metric, folder, args.window, args.percentiles)
        if "skip" in args.sections:
            result["skip"] = section_skip(street, metric, folder)
    cols = ["setting", "confidence_percentile", "shift_m", "psnr_covered_db", "hole_fraction", "nearer_fraction",
            "farther_fraction", "points", "cleaning_ms_per_frame", "frame_ms"]
    scols = ["setting", "confidence_percentile", "psnr_shifted_db", "holes_shifted", "nearer_shifted",
             "farther_shifted", "psnr_0m_db", "points", "cleaning_s", "cleaning_ms_per_frame", "frame_ms"]
    if "cleaning" in result:
        print_table(f"cleaning on the street (VGGT-like depth, window ±{result['window']}, 518 x 294, CPU)",
                    result["cleaning"], cols)
        print_table("cleaning, summary (mean over ±2, ±3 m)", result["cleaning_summary"], scols)
    if "sweep" in result:
        print_table("parameter sweep (mean over ±2, ±3 m)", result["sweep_summary"],
                    [c for c in scols if c != "psnr_0m_db"])
    if "timing" in result:
        print_table("time, settings alternated in one run (medians; 2 m left view)", result["timing"],
                    ["setting", "confidence_percentile", "points", "point_cloud_s", "outliers_s",
                     "cleaning_ms_per_frame", "frame_ms"])
    if "skip" in result:
        print_table("skipping what a frame cannot see (median ms per frame, alternating)", result["skip"],
                    ["case", "skip_ms", "no_skip_ms", "speedup", "speedup_q1", "speedup_q3", "tests_ms", "identical",
                     "source_frames_kept_mean", "asset_frames_skipped"])
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    outputs.write_json(args.out, result)
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
