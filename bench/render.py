"""The condition renderer: time per frame against error, the speed targets, and coverage on the ground-truth street.

    .venv/bin/python bench/render.py [--devices cpu cuda] [--sections speed accuracy street] [--threads 2]

speed     576 x 1024 frames of the synthetic street (``render_scene``): 1 M points + 100 k Gaussians on the CPU,
          3 M + 200 k on CUDA, whole frames and each pass alone; on CUDA also gsplat's rasterizer on the same
          Gaussians when ``gsplat`` imports (a benchmark-only dependency).
accuracy  each setting (cutoff, tile size, rasterizer, device) timed on the speed scene and compared
          with a float64 reference on a scene whose reference is affordable (1 M points + 20 k Gaussians, car
          8 m ahead): the torch pair rasterizer in float64 with a 4 σ cutoff, i.e. no cutoff at all (beyond
          sqrt(2 ln 255) σ every α is under 1/255 and skipped by the rules).
street    the ground-truth street (CPU, needs its cache or bpy to make it): for shifts 0, ±2, ±3 m, source windows
          0, ±2, ±8 frames and splat radius 0/1, the hole fraction and the PSNR of covered pixels against the
          Cycles renders of that view.

Prints tables and writes bench/results/render_<devices>.json and a plot beside it.
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

import render_scene  # noqa: E402
from backend import events  # noqa: E402
from backend.render import channels  # noqa: E402
from backend.render import frames as fr  # noqa: E402
from backend.render import gaussians as gs  # noqa: E402
from backend.render import points as pts  # noqa: E402
from backend.render import tiles  # noqa: E402
from scpainter_blender.core import outputs  # noqa: E402

W, H = 1024, 576


def timed(fn, device, repeat=10, warmup=2):
    """Median wall time of fn() in ms (CUDA synchronised around each call)."""
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    for _ in range(warmup):
        fn()
    sync()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        sync()
        times.append(1e3 * (time.perf_counter() - t))
    return statistics.median(times)


def gaussians_world(scene, entry):
    """The scene's asset Gaussians in scene-origin-relative world coordinates, with the camera for them."""
    a = scene.assets[0]
    A = np.array(a.object_to_world[entry.frame], np.float64)
    A[:3, 3] -= scene.origin
    At = torch.as_tensor(A, dtype=a.means.dtype, device=scene.device)
    w2c = pts.relative_camera(np.asarray(entry.world_to_camera), scene.origin)
    return a.means @ At[:3, :3].T + At[:3, 3], At[:3, :3] @ a.factors, a.opacities, a.sh, w2c


def gaussian_pass(scene, entry, tile=None, reference=False):
    means, factors, opac, sh, w2c = gaussians_world(scene, entry)
    proj = gs.project_factors(means, factors, opac, sh, entry.K, w2c, W, H)
    if reference:
        return gs.rasterize(proj, W, H)
    return tiles.rasterize(proj, W, H, tile=tile)


def point_pass(scene, entry):
    w2c = pts.relative_camera(np.asarray(entry.world_to_camera), scene.origin)
    return pts.render_points(scene.xyz, scene.rgb, entry.K, w2c, W, H)


def gsplat_pass(scene, entry, quats, scales):
    from gsplat import rasterization

    means, _, opac, sh, w2c = (x.float() if torch.is_tensor(x) else x for x in gaussians_world(scene, entry))
    dev = scene.device
    view = torch.as_tensor(w2c, dtype=torch.float32, device=dev)[None]
    K = torch.as_tensor(np.array(entry.K), dtype=torch.float32, device=dev)[None]
    img, asset_mask, _ = rasterization(means, quats, scales, opac, sh, view, K, W, H, near_plane=0.05, eps2d=0.3,
                                       sh_degree=0, packed=False, rasterize_mode="classic", tile_size=16)
    return img[0], asset_mask[0, ..., 0]


def section_speed(device, rows):
    n_pts, n_gs = (1_000_000, 100_000) if device == "cpu" else (3_000_000, 200_000)
    scene, entry = render_scene.build(n_pts, n_gs, W, H, device=device)
    full = lambda: fr.render_frame(scene, entry, W, H, to_numpy=False)  # noqa: E731
    with_copy = lambda: fr.render_frame(scene, entry, W, H, to_numpy=True)  # noqa: E731
    res = {"device": device, "points": n_pts, "gaussians": n_gs,
           "frame_ms": timed(full, device), "frame_with_download_ms": timed(with_copy, device),
           "points_ms": timed(lambda: point_pass(scene, entry), device),
           "gaussians_ms": timed(lambda: gaussian_pass(scene, entry), device)}
    layers = full()
    res["asset_pixels"] = int((layers[channels.ASSET_MASK] > 0.5).sum())
    res["hole_fraction"] = float(layers[channels.HOLE].mean())
    if device == "cuda":
        # determinism across devices: the same points z-buffered on the CPU pick the same winners
        cpu_scene = fr.Scene(origin=scene.origin, device=torch.device("cpu"), xyz=scene.xyz.cpu(),
                             rgb=scene.rgb.cpu(), frame=scene.frame.cpu())
        win_gpu = point_pass(scene, entry)[2].cpu()
        win_cpu = point_pass(cpu_scene, entry)[2]
        res["points_winner_mismatch_cpu_vs_cuda"] = int((win_gpu != win_cpu).sum())
        try:
            import gsplat  # noqa: F401
        except ImportError as e:
            res["gsplat"] = f"not available: {e}"
        else:
            g = render_scene.car_gaussians(n_gs)
            quats = torch.as_tensor(g.quats, device=device)
            scales = torch.as_tensor(g.scales, device=device)
            res["gsplat_ms"] = timed(lambda: gsplat_pass(scene, entry, quats, scales), device)
            ours_c, ours_mask, _ = gaussian_pass(scene, entry)
            gc, gmask = gsplat_pass(scene, entry, quats, scales)
            res["gsplat_mean_abs_diff_rgb"] = float((ours_c - gc).abs().mean())
            res["gsplat_max_abs_diff_asset_mask"] = float((ours_mask - gmask).abs().max())
            res["gaussians_vs_gsplat"] = res["gaussians_ms"] / res["gsplat_ms"]
    rows.append(res)
    return scene, entry


def section_accuracy(device, rows, speed_scene):
    acc_scene, acc_entry = render_scene.build(1_000_000, 20_000, W, H, device=device, car_distance=8.0)
    ref = reference_layers(acc_scene, acc_entry)
    scene, entry = speed_scene
    same = {}  # float64 pair renders at each cutoff: what is left is the float32 and kernel error alone
    settings = [("default (tiles, 3σ, tile 8 CPU / 16 CUDA)", {}),
                ("cutoff 2σ", {"cutoff": 2.0}), ("cutoff 2.5σ", {"cutoff": 2.5}), ("cutoff 3.5σ", {"cutoff": 3.5}),
                ("tile 8", {"tile": 8}), ("tile 16", {"tile": 16}), ("tile 32", {"tile": 32}),
                ("pair rasterizer (the reference)", {"reference": True})]
    for name, kw in settings:
        try:
            ms = timed(lambda: render_with(scene, entry, **kw), device, repeat=3, warmup=1)
        except MemoryError as e:  # the pair rasterizer refuses scenes over its pair budget
            ms = f"refused: {e}"
        out = render_with(acc_scene, acc_entry, **kw)
        cutoff = kw.get("cutoff", gs.CUTOFF)
        if cutoff not in same:
            same[cutoff] = render_with(acc_scene, acc_entry, cutoff=cutoff, reference=True)
        dI = np.abs(out["I"] - ref["I"])
        rows.append({"device": device, "setting": name, "frame_ms": ms, "max_abs_err_I": float(dI.max()),
                     "mean_abs_err_I": float(dI.mean()),
                     "max_abs_err_asset_mask": float(np.abs(out["asset_mask"] - ref["asset_mask"]).max()),
                     "max_abs_err_I_same_cutoff": float(np.abs(out["I"] - same[cutoff]["I"]).max()),
                     "max_abs_err_asset_mask_same_cutoff": float(np.abs(out["asset_mask"]
                                                                        - same[cutoff]["asset_mask"]).max())})


def render_with(scene, entry, cutoff=gs.CUTOFF, tile=None, reference=False):
    """render_frame's work with one setting changed; returns numpy I (H, W, 3) and the asset mask."""
    layers = fr.render_frame(scene, entry, W, H, reference=reference, cutoff=cutoff, tile=tile)
    return {"I": np.stack([layers[c] for c in channels.IMAGE], -1), "asset_mask": layers[channels.ASSET_MASK]}


def reference_layers(scene, entry):
    return render_with(scene, entry, cutoff=4.0, reference=True)  # float64: the projection's precision


def section_street(rows):
    info = {}
    for percentile in (0.0, 50.0):
        info = street_rows(rows, percentile, radii=(0, 1) if percentile == 0 else (0,))
    return info


def street_rows(rows, percentile, radii):
    from PIL import Image

    from scpainter_blender.core import point_cloud, vggt_io
    from scpainter_blender.street.dataset import ensure_street, view_name

    street = ensure_street(log=lambda m: None)
    metric = street.metric()
    pred = vggt_io.load_predictions(street.predictions_path, world_points=False)
    cloud = point_cloud.point_cloud(pred, percentile, vggt_to_world=metric["vggt_to_world"])
    S = len(metric["world_to_camera"])
    w2c0 = metric["world_to_camera"][0]
    origin = -w2c0[:3, :3].T @ w2c0[:3, 3]
    scene = fr.Scene(origin=origin, device=torch.device("cpu"))
    scene.xyz = torch.as_tensor((cloud.positions - origin).astype(np.float32))
    scene.rgb = torch.as_tensor(cloud.colors)
    scene.frame = torch.as_tensor(cloud.frame.astype(np.int64))
    Hs, Ws = metric["depth"].shape[1:3]
    for shift in (0.0, 2.0, -2.0, 3.0, -3.0):
        view = "recorded" if shift == 0 else view_name(shift)
        cams = metric["world_to_camera"] if shift == 0 else metric[f"world_to_camera_{view}"]
        truth = [np.asarray(Image.open(street.frame_path(view, i)).convert("RGB"), np.float64) / 255.0
                 for i in range(S)]
        for window in (0, 2, 8):
            for radius in radii:
                t, holes, se, n = 0.0, [], 0.0, 0
                for i in range(S):
                    entry = {"frame": i, "K": metric["K"][i].tolist(), "world_to_camera": cams[i].tolist(),
                             "source_frames": list(range(max(0, i - window), min(S, i + window + 1)))}
                    t0 = time.perf_counter()
                    layers = fr.render_frame(scene, entry, Ws, Hs, point_radius_px=radius)
                    t += time.perf_counter() - t0
                    covered = layers["hole"] < 0.5
                    img = np.stack([layers["R"], layers["G"], layers["B"]], -1).astype(np.float64)
                    holes.append(1.0 - covered.mean())
                    se += ((img - truth[i]) ** 2)[covered].sum()
                    n += 3 * int(covered.sum())
                mse = se / max(n, 1)
                rows.append({"shift_m": shift, "window": window, "point_radius_px": radius,
                             "hole_fraction": float(np.mean(holes)),
                             "psnr_covered_db": float(10 * np.log10(1.0 / mse)) if mse > 0 else float("inf"),
                             "frame_ms": 1e3 * t / S, "confidence_percentile": percentile})
    return {"frames": S, "resolution": [Ws, Hs], "points": len(cloud.positions), "root": street.root}


def print_table(title, rows, cols):
    print(f"\n{title}")
    print(" | ".join(cols))
    print(" | ".join("---" for _ in cols))
    for r in rows:
        print(" | ".join(fmt(r.get(c)) for c in cols))


def fmt(v):
    if isinstance(v, float):
        return f"{v:.3g}" if abs(v) < 1e-2 or abs(v) >= 1e4 else f"{v:.3f}"
    return str(v)


def street_curve(result, window):
    return sorted((r for r in result["street"] if r["window"] == window and r["point_radius_px"] == 0
                   and r["confidence_percentile"] == 0), key=lambda r: r["shift_m"])


def plot(result, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    ax = axes[0]
    for r in result["accuracy"]:
        if isinstance(r["frame_ms"], (int, float)):
            ax.scatter(r["frame_ms"], max(r["max_abs_err_I"], 1e-8), label=f"{r['setting']} ({r['device']})")
    ax.set(xscale="log", yscale="log", xlabel="ms per frame (speed scene)", ylabel="max |ΔI| vs float64 reference",
           title="error against run time")
    ax.legend(fontsize=6)
    ax = axes[1]
    for window in (0, 2, 8):
        sel = street_curve(result, window)
        if sel:
            ax.plot([r["shift_m"] for r in sel], [r["psnr_covered_db"] for r in sel], "o-", label=f"PSNR ±{window}")
    ax.set(xlabel="shift (m, + left)", ylabel="PSNR of covered pixels (dB)", title="ground-truth street")
    if result["street"]:
        twin = ax.twinx()
        for window in (0, 2, 8):
            sel = street_curve(result, window)
            twin.plot([r["shift_m"] for r in sel], [r["hole_fraction"] for r in sel], "x--", label=f"holes ±{window}")
        twin.set_ylabel("hole fraction")
        twin.legend(fontsize=7, loc="lower right")
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--devices", nargs="+", default=["cpu"], choices=["cpu", "cuda"])
    p.add_argument("--sections", nargs="+", default=["speed", "accuracy", "street"],
                   choices=["speed", "accuracy", "street"])
    p.add_argument("--threads", type=int, default=2, help="CPU threads (torch and numba); the target is 2 cores")
    p.add_argument("--out", default=os.path.join(ROOT, "bench", "results"))
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    if "cpu" in args.devices:
        import numba

        numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    result = {"machine": platform.node(), "cpu_threads": args.threads, "torch": torch.__version__,
              "gpu": torch.cuda.get_device_name() if "cuda" in args.devices else None,
              "speed": [], "accuracy": [], "street": []}
    for device in args.devices:
        speed_scene = section_speed(device, result["speed"]) if "speed" in args.sections or \
            "accuracy" in args.sections else None
        if "accuracy" in args.sections:
            section_accuracy(device, result["accuracy"], speed_scene)
    if "street" in args.sections:
        result["street_info"] = section_street(result["street"])
    print_table("speed, 576 x 1024 (ms per frame; median of 10)", result["speed"],
                ["device", "points", "gaussians", "frame_ms", "frame_with_download_ms", "points_ms", "gaussians_ms",
                 "gsplat_ms", "gaussians_vs_gsplat", "gsplat_mean_abs_diff_rgb", "asset_pixels",
                 "points_winner_mismatch_cpu_vs_cuda"])
    print_table("error against run time (time: speed scene; error: 1 M points + 20 k Gaussians against float64 "
                "without a cutoff, and against float64 with the same cutoff)",
                result["accuracy"], ["device", "setting", "frame_ms", "max_abs_err_I", "mean_abs_err_I",
                                     "max_abs_err_asset_mask", "max_abs_err_I_same_cutoff",
                                     "max_abs_err_asset_mask_same_cutoff"])
    print_table("ground-truth street (16 frames 518 x 294, CPU)", result["street"],
                ["confidence_percentile", "shift_m", "window", "point_radius_px", "hole_fraction", "psnr_covered_db",
                 "frame_ms"])
    os.makedirs(args.out, exist_ok=True)
    stem = os.path.join(args.out, "render_" + "_".join(args.devices))
    outputs.write_json(stem + ".json", events.json_safe(result))  # a PSNR of a perfect match (inf) becomes null
    plot(result, stem + ".png")
    print(f"\nwrote {stem}.json and {stem}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
