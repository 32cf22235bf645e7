"""The condition renderer: today's code against a baseline revision, time per frame against error, the speed
targets, and coverage on the ground-truth street.

    .venv/bin/python bench/render.py [--devices cpu cuda] [--sections ab speed accuracy choice street] [--threads 2]
                                     [--baseline 3fcda49] [--rounds 5] [--repeat 3] [--load-rounds 3]
                                     [--smoke] [--out DIR]
    GPU (bench/device_all.sh): python3 bench/render.py --devices cuda --sections speed accuracy choice

ab        (CPU) the working tree against ``--baseline`` (a git revision, extracted with ``git archive`` into a temp
          folder), side by side in one run: each tree in its own worker process (``render_scene.py --worker``)
          with the same timing code on the same inputs (1 M points + a 100 k Gaussian car, or ``--ab-cars`` 2–3
          cars sharing them, at 576 x 1024, saved once to an .npz), requests interleaved A/B for ``--rounds``
          rounds (order alternating) of ``--repeat`` timed calls each. Reports, per tree: the median ms of a
          whole frame, of the point pass and of the Gaussian pass (projection + tile compositing over the points'
          depth), the ratio baseline / now; the working tree's ``frames.amodal_pixels`` alone; whether
          the point pass is identical (rgb, depth, winner, bit for bit); the Gaussian layers' error against the
          float64 pair rasterizer without any cutoff; the pixel–Gaussian pairs (``pixel_boxes``). Then under load:
          one competing CPU-bound process (a second Python process spinning in a pure-Python loop: one busy core,
          like Blender or a second program working beside the render, and with no OpenMP of its own to make the
          measure depend on its wait policy), each arm's frame and point pass quiet and loaded, interleaved: the
          baseline as shipped (OpenMP's default wait policy), the working tree as shipped (``backend`` sets
          OMP_WAIT_POLICY=PASSIVE) and the working tree with the variable removed again before torch loads.
speed     576 x 1024 frames of the synthetic street (``render_scene``): 1 M points + 100 k Gaussians on the CPU,
          3 M + 200 k on CUDA, whole frames and each pass alone; on CUDA also gsplat's rasterizer on the same
          Gaussians when ``gsplat`` imports (a benchmark-only dependency).
accuracy  each setting (tile size, rasterizer, device) timed on the speed scene and compared with a float64
          reference on a scene whose reference is affordable (1 M points + 20 k Gaussians, car 8 m ahead): the torch
          pair rasterizer in float64, whose per-axis extent holds every pixel with α >= 1/255 (the render without a
          cutoff).
choice    the table ``backend/render/raster_choice.py``'s thresholds come from: for several Gaussian counts (the
          car 8 m ahead, over the speed scene's points), the Gaussian pass (projection + compositing over the
          points' depth) with each method and tile size: ms, error against the float64 pair rasterizer, which one
          ``raster_choice.choose`` picks and which was fastest. On CUDA also the tile kernel's work (entries, and
          the batches its programs composited before leaving early, against all of them).
street    the ground-truth street (CPU, needs its cache or bpy to make it): for shifts 0, ±2, ±3 m, source windows
          0, ±2, ±8 frames and splat radius 0/1, the hole fraction and the PSNR of covered pixels against the
          Cycles renders of that view.

Prints tables and writes <--out>/render_<devices>.json (default bench/results) and a plot beside it. Timings on a
shared machine are noisy: the ab section reports the spread of the per-round ratios beside their medians.
``--smoke``: every section but ab and street at 256 x 144 with tens of thousands of points and a few thousand
Gaussians, on the CPU in seconds (the suite runs it: tests/bench/test_render.py); every code path of the CUDA
rows that does not need a GPU runs too (the comparison code of the gsplat row against the pair rasterizer, the
inputs gsplat would get, the CPU-vs-device point winners).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

USER_WAIT_POLICY = os.environ.get("OMP_WAIT_POLICY")  # what the user set, before the backend's default
import backend  # noqa: E402,F401  (first, as python -m backend: OMP_WAIT_POLICY=PASSIVE before torch loads)
import numpy as np  # noqa: E402
import torch  # noqa: E402

import render_scene  # noqa: E402
from backend import events  # noqa: E402
from backend.render import channels  # noqa: E402
from backend.render import frames as fr  # noqa: E402
from backend.render import gaussians as gs  # noqa: E402
from backend.render import points as pts  # noqa: E402
from backend.render import raster_choice  # noqa: E402
from backend.render import tiles  # noqa: E402
from scpainter_blender.core import job as job_mod  # noqa: E402
from scpainter_blender.core import outputs  # noqa: E402

W, H = 1024, 576  # set by main (--smoke: SMOKE_SIZE)
SMOKE_SIZE = (256, 144)
#: (points, Gaussians) of the speed scene, the accuracy scene and the choice section's Gaussian counts, per mode
SIZES = {"cpu": {"speed": (1_000_000, 100_000), "accuracy": (1_000_000, 20_000), "choice": (2_000, 20_000, 100_000)},
         "cuda": {"speed": (3_000_000, 200_000), "accuracy": (1_000_000, 20_000),
                  "choice": (2_000, 20_000, 200_000, 1_000_000)},
         "smoke": {"speed": (20_000, 2_000), "accuracy": (20_000, 1_000), "choice": (300, 3_000)}}


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


def gaussian_pass(scene, entry, tile=None, reference=False, method="auto", background_depth=None):
    """The Gaussian pass alone (projection + compositing): ``tiles.rasterize``' four layers (colour, asset mask,
    depth, instance)."""
    means, factors, opac, sh, w2c = gaussians_world(scene, entry)
    proj = gs.project_factors(means, factors, opac, sh, entry.K, w2c, W, H)
    if reference:
        return gs.rasterize(proj, W, H, background_depth)
    return tiles.rasterize(proj, W, H, background_depth, tile=tile, method=method)


def gaussian_layers(scene, entry, **kw):
    """(colour (H, W, 3), asset mask (H, W)) of ``gaussian_pass``: what the comparisons read."""
    color, asset_mask, _depth, _instance = gaussian_pass(scene, entry, **kw)
    return color, asset_mask


def point_pass(scene, entry):
    w2c = pts.relative_camera(np.asarray(entry.world_to_camera), scene.origin)
    return pts.render_points(scene.xyz, scene.rgb, entry.K, w2c, W, H)


def gsplat_inputs(scene, entry, quats, scales):
    """The arguments of gsplat's ``rasterization`` for the scene's car, float32 on the scene's device: means (N, 3),
    quats (N, 4), scales (N, 3), opacities (N,), colours (N, K, 3) SH, viewmats (1, 4, 4), Ks (1, 3, 3). Shapes are
    checked here so the CPU smoke run catches a mismatch the GPU run would only meet after gsplat's build."""
    means, _, opac, sh, w2c = (x.float() if torch.is_tensor(x) else x for x in gaussians_world(scene, entry))
    dev = scene.device
    args = {"means": means, "quats": quats.to(dev, torch.float32), "scales": scales.to(dev, torch.float32),  # no-ops
            "opacities": opac, "colors": sh,
            "viewmats": torch.as_tensor(w2c, dtype=torch.float32, device=dev)[None],
            "Ks": torch.as_tensor(np.array(entry.K), dtype=torch.float32, device=dev)[None]}
    n = len(means)
    expect = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,), "viewmats": (1, 4, 4),
              "Ks": (1, 3, 3)}
    for k, shape in expect.items():
        if tuple(args[k].shape) != shape:
            raise ValueError(f"gsplat input {k}: shape {tuple(args[k].shape)}, expected {shape}")
    if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3:
        raise ValueError(f"gsplat input colors: shape {tuple(sh.shape)}, expected ({n}, K, 3)")
    return args


def gsplat_pass(scene, entry, quats, scales):
    from gsplat import rasterization

    a = gsplat_inputs(scene, entry, quats, scales)
    img, asset_mask, _ = rasterization(a["means"], a["quats"], a["scales"], a["opacities"], a["colors"],
                                       a["viewmats"], a["Ks"], W, H, near_plane=0.05, eps2d=0.3, sh_degree=0,
                                       packed=False, rasterize_mode="classic", tile_size=16)
    return img[0], asset_mask[0, ..., 0]


def compare_layers(name, ours, theirs):
    """{name_mean_abs_diff_rgb, name_max_abs_diff_asset_mask} between two (colour (H, W, 3), asset mask (H, W))."""
    (oc, om), (tc, tm) = ours, theirs
    if oc.shape != tc.shape or om.shape != tm.shape:
        raise ValueError(f"{name}: layers of shapes {tuple(tc.shape)}, {tuple(tm.shape)}; ours "
                         f"{tuple(oc.shape)}, {tuple(om.shape)}")
    return {f"{name}_mean_abs_diff_rgb": float((oc.float() - tc.float()).abs().mean()),
            f"{name}_max_abs_diff_asset_mask": float((om.float() - tm.float()).abs().max())}


def kernel_work(scene, entry, device, repeat, tile=None):
    """The CUDA tile path's parts on the scene's Gaussian pass, over the points' depth: ms of the projection, the
    binning (``tiles.bin_tiles``), the kernel's inputs and the kernel; its work (``tiles.composite_triton``'
    stats: entries, the batches its programs composited, and the batches of the whole lists, no early exit); and
    ``kernel_sweep``: the kernel alone for tiles 8 and 16 and batches 16, 32, 64 (what retunes
    ``tiles_cuda.launch_config``). Runs wherever Triton does (its interpreter on the CPU)."""
    from backend.render import tiles_cuda

    means, factors, opac, sh, w2c = gaussians_world(scene, entry)
    project = lambda: gs.project_factors(means, factors, opac, sh, entry.K, w2c, W, H)  # noqa: E731
    proj = project()
    bg = point_pass(scene, entry)[1]
    tile = tile or raster_choice.choose(scene.device.type, len(proj["depth"]), W, H).tile
    stats = {}
    tiles.composite_triton(proj, W, H, bg, tile, 1, stats)
    batch = tiles_cuda.launch_config(tile)[0]
    e = stats["entries"]
    out = {"kernel_tile": tile, "kernel_batch": batch, "kernel_entries": int(e.sum()),
           "kernel_batches_done": int(stats["batches"].sum()),
           "kernel_batches_full": int(((e + batch - 1) // batch).sum()),
           "kernel_longest_list": int(e.max()) if len(e) else 0,
           "projection_ms": timed(project, device, repeat),
           "binning_ms": timed(lambda: tiles.bin_tiles(proj, W, H, tile), device, repeat)}
    sweep = []
    for t in (8, 16):
        bins = tiles.bin_tiles(proj, W, H, t)
        inputs = tiles.kernel_inputs(proj, bins, W, H, bg)
        if t == tile:
            out["inputs_ms"] = timed(lambda: tiles.kernel_inputs(proj, bins, W, H, bg), device, repeat)
        for b in (16, 32, 64):
            ms = timed(lambda: tiles_cuda.composite(*inputs, W, H, bins["tiles_x"], t, 1, batch=b), device, repeat)
            sweep.append({"tile": t, "batch": b, "kernel_ms": ms, "default": (t, b) == (tile, batch)})
            if (t, b) == (tile, batch):
                out["kernel_ms"] = ms
    out["kernel_sweep"] = sweep
    return out


def section_speed(device, rows, sizes):
    n_pts, n_gs = sizes["speed"]
    scene, entry = render_scene.build(n_pts, n_gs, W, H, device=device)
    full = lambda: fr.render_frame(scene, entry, W, H, to_numpy=False)  # noqa: E731
    with_copy = lambda: fr.render_frame(scene, entry, W, H, to_numpy=True)  # noqa: E731
    repeat = sizes.get("repeat", 10)
    res = {"device": device, "points": n_pts, "gaussians": n_gs, "size": [W, H],
           "frame_ms": timed(full, device, repeat), "frame_with_download_ms": timed(with_copy, device, repeat),
           "points_ms": timed(lambda: point_pass(scene, entry), device, repeat),
           "gaussians_ms": timed(lambda: gaussian_pass(scene, entry), device, repeat)}
    layers = full()
    res["asset_pixels"] = int((layers[channels.ASSET_MASK] > 0.5).sum())
    res["hole_fraction"] = float(layers[channels.HOLE].mean())
    # determinism across devices: the same points z-buffered on the CPU pick the same winners (on the CPU: the
    # same code against itself, so the comparison runs wherever the bench does)
    cpu_scene = fr.Scene(origin=scene.origin, device=torch.device("cpu"), xyz=scene.xyz.cpu(),
                         rgb=scene.rgb.cpu(), frame=scene.frame.cpu())
    win_dev = point_pass(scene, entry)[2].cpu()
    win_cpu = point_pass(cpu_scene, entry)[2]
    res["points_winner_mismatch_cpu_vs_device"] = int((win_dev != win_cpu).sum())
    ours = gaussian_layers(scene, entry)
    # the tile kernels against the pair rasterizer on the same float64 projection: the comparison the gsplat row
    # makes, run on every device
    res.update(compare_layers("pairs", ours, gaussian_layers(scene, entry, reference=True)))
    g = render_scene.car_gaussians(n_gs)
    # on the device once: gsplat's timed calls must not include a host-to-device copy
    quats = torch.as_tensor(g.quats, dtype=torch.float32, device=device)
    scales = torch.as_tensor(g.scales, dtype=torch.float32, device=device)
    gsplat_inputs(scene, entry, quats, scales)  # shapes checked on every device
    if device == "cuda":
        res.update(kernel_work(scene, entry, device, repeat))
        try:
            import gsplat  # noqa: F401
        except ImportError as e:
            res["gsplat"] = f"not available: {e}"
        else:
            res["gsplat_ms"] = timed(lambda: gsplat_pass(scene, entry, quats, scales), device, repeat)
            res.update(compare_layers("gsplat", ours, gsplat_pass(scene, entry, quats, scales)))
            res["gaussians_vs_gsplat"] = res["gaussians_ms"] / res["gsplat_ms"]
    rows.append(res)
    return scene, entry


def section_accuracy(device, rows, speed_scene, sizes):
    n_pts, n_gs = sizes["accuracy"]
    acc_scene, acc_entry = render_scene.build(n_pts, n_gs, W, H, device=device, car_distance=8.0)
    ref = render_with(acc_scene, acc_entry, reference=True)
    scene, entry = speed_scene
    settings = [("default (raster_choice)", {}), ("tile 8", {"tile": 8}), ("tile 16", {"tile": 16}),
                ("tile 32", {"tile": 32}), ("pair rasterizer (the reference)", {"reference": True})]
    for name, kw in settings:
        try:
            ms = timed(lambda: render_with(scene, entry, **kw), device, repeat=sizes.get("repeat_accuracy", 3),
                       warmup=1)
        except MemoryError as e:  # the pair rasterizer refuses scenes over its pair budget
            ms = f"refused: {e}"
        out = render_with(acc_scene, acc_entry, **kw)
        dI = np.abs(out["I"] - ref["I"])
        rows.append({"device": device, "setting": name, "frame_ms": ms, "max_abs_err_I": float(dI.max()),
                     "mean_abs_err_I": float(dI.mean()),
                     "max_abs_err_asset_mask": float(np.abs(out["asset_mask"] - ref["asset_mask"]).max())})


def section_choice(device, rows, sizes):
    """Per Gaussian count (the car 8 m ahead over the speed scene's points): each method and tile size's Gaussian
    pass (projection + compositing over the points' depth), its error against the float64 pair rasterizer, and
    ``raster_choice.choose``'s pick (see the module docstring)."""
    n_pts = sizes["speed"][0]
    tiles_sizes = (4, 8, 16) if device == "cpu" else (8, 16, 32)
    for n_gs in sizes["choice"]:
        scene, entry = render_scene.build(n_pts, n_gs, W, H, device=device, car_distance=8.0)
        bg = point_pass(scene, entry)[1]
        means, factors, opac, sh, w2c = gaussians_world(scene, entry)
        projected = len(gs.project_factors(means, factors, opac, sh, entry.K, w2c, W, H)["depth"])
        pick = raster_choice.choose(device, projected, W, H)
        try:
            ref = gaussian_pass(scene, entry, reference=True, background_depth=bg)
        except MemoryError:
            ref = None
        group = []
        for method, tile in [("pairs", None)] + [("tiles", t) for t in tiles_sizes]:
            kw = {"method": method, "tile": tile, "background_depth": bg}
            row = {"device": device, "gaussians": n_gs, "projected": projected, "method": method, "tile": tile,
                   "chosen": (method, tile) == (pick.method, pick.tile), "reason": pick.reason}
            try:
                row["gaussians_ms"] = timed(lambda: gaussian_pass(scene, entry, **kw), device,
                                            repeat=sizes.get("repeat_accuracy", 3), warmup=1)
                out = gaussian_pass(scene, entry, **kw)
            except MemoryError as e:  # the pair rasterizer refuses scenes over its pair budget
                row["gaussians_ms"] = None
                row["refused"] = str(e)
            else:
                if ref is not None:
                    row["max_abs_err_rgb"] = float((out[0].double() - ref[0].double()).abs().max())
                    row["max_abs_err_asset_mask"] = float((out[1].double() - ref[1].double()).abs().max())
                    row["instance_differing_pixels"] = int((out[3] != ref[3]).sum())
            group.append(row)
        timed_rows = [r for r in group if r["gaussians_ms"] is not None]
        fastest = min(timed_rows, key=lambda r: r["gaussians_ms"])
        for r in group:
            r["fastest"] = r is fastest
        rows.extend(group)


def render_with(scene, entry, tile=None, reference=False):
    """render_frame's work with one setting changed; returns numpy I (H, W, 3) and the asset mask. The reference
    (``reference=True``) runs on the scene's float64 projection: float64 throughout."""
    layers = fr.render_frame(scene, entry, W, H, reference=reference, tile=tile)
    return {"I": np.stack([layers[c] for c in channels.IMAGE], -1), "asset_mask": layers[channels.ASSET_MASK]}


def section_street(rows):
    info = {}
    for percentile in (0.0, 50.0):
        info = street_rows(rows, percentile, radii=(0, 1) if percentile == 0 else (0,))
    return info


def street_rows(rows, percentile, radii):
    from PIL import Image

    from scpainter_blender.core.geometry import point_cloud
    from scpainter_blender.core.vggt import npz as vggt_io
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
                    entry = job_mod.Frame(frame=i, K=np.asarray(metric["K"][i], np.float64),
                                          world_to_camera=np.asarray(cams[i], np.float64),
                                          source_frames=list(range(max(0, i - window), min(S, i + window + 1))))
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


# -- ab: the working tree against a baseline revision, in worker processes -----------------------------------

def baseline_tree(rev: str) -> tuple[str, str]:
    """(folder, commit): ``backend`` and ``scpainter_blender`` of git revision ``rev`` extracted with ``git archive``
    (the repository is only read) into a temp folder kept between runs (numba's cache in it stays warm)."""
    import io
    import tarfile

    sha = subprocess.run(["git", "-C", ROOT, "rev-parse", "--verify", rev + "^{commit}"], capture_output=True,
                         text=True, check=True).stdout.strip()
    folder = os.path.join(tempfile.gettempdir(), f"scpainter-bench-{sha[:12]}")
    marker = os.path.join(folder, ".complete")
    if not os.path.exists(marker):
        tar = subprocess.run(["git", "-C", ROOT, "archive", "--format=tar", sha, "backend", "scpainter_blender"],
                             capture_output=True, check=True).stdout
        with tarfile.open(fileobj=io.BytesIO(tar)) as t:
            t.extractall(folder, filter="data")
        open(marker, "w").close()
    return folder, sha


class Worker:
    """A timing worker (``render_scene.py --worker``) on one source tree; ``ask`` sends one request and waits."""

    def __init__(self, name, tree, data, threads, log_dir, policy="shipped"):
        """``policy``: "shipped" (the tree's own: OMP_WAIT_POLICY absent from the environment, the tree's
        ``backend`` package may set it), "unset" (absent, and removed again after ``backend`` is imported: OpenMP's
        default) or a value for OMP_WAIT_POLICY. A policy the user set before running the bench goes to the
        "shipped" arms."""
        env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
        if policy not in ("shipped", "unset"):
            env["OMP_WAIT_POLICY"] = policy
        elif policy == "shipped" and USER_WAIT_POLICY is not None:
            env["OMP_WAIT_POLICY"] = USER_WAIT_POLICY
        cmd = [sys.executable, os.path.join(ROOT, "bench", "render_scene.py"), "--worker", "--tree", tree,
               "--data", data, "--threads", str(threads)] + (["--unset-wait-policy"] if policy == "unset" else [])
        self.name = name
        self.log = os.path.join(log_dir, f"worker_{name}.log")
        with open(self.log, "w") as log:
            self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log, env=env,
                                         text=True)
        self.hello = self._read()

    def _read(self):
        line = self.proc.stdout.readline()
        if not line:
            with open(self.log) as f:
                tail = f.read()[-3000:]
            raise RuntimeError(f"worker {self.name} stopped (exit {self.proc.poll()}); its log {self.log}:\n{tail}")
        return json.loads(line)

    def ask(self, **req):
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        return self._read()

    def close(self):
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write('{"cmd": "quit"}\n')
                self.proc.stdin.flush()
                self.proc.wait(timeout=30)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()


class Spinner:
    """One competing CPU-bound process: Python spinning in a pure-Python loop (one core busy, no threads)."""

    def __enter__(self):
        self.proc = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        time.sleep(0.3)  # let it reach the loop and the scheduler give it its share
        return self

    def __exit__(self, *exc):
        self.proc.kill()
        self.proc.wait()


def settle():
    """A pause between requests to different workers: OpenMP threads that spin after a parallel region (the
    default wait policy) stop spinning before the next worker is timed."""
    time.sleep(0.15)


def med(xs):
    return statistics.median(xs) if xs else None


def layer_errors(dump, ref):
    """Max and mean |Δ| of I (R G B) and the asset mask of a dumped frame against the reference frame."""
    I = np.stack([dump[f"layer_{c}"] for c in channels.IMAGE], -1)
    I_ref = np.stack([ref[f"reference_{c}"] for c in channels.IMAGE], -1)
    dI = np.abs(I.astype(np.float64) - I_ref)
    dM = np.abs(dump[f"layer_{channels.ASSET_MASK}"].astype(np.float64) - ref[f"reference_{channels.ASSET_MASK}"])
    return {"max_abs_err_I": float(dI.max()), "mean_abs_err_I": float(dI.mean()),
            "max_abs_err_asset_mask": float(dM.max())}


QUIET_ARMS = {"baseline": ("baseline", "shipped"), "baseline_passive": ("baseline", "PASSIVE"),
              "now": ("now", "shipped")}
LOAD_ARMS = dict(QUIET_ARMS, now_unset=("now", "unset"))


def section_ab(args, result):
    """Fills result["ab"]: see the module docstring. Arms: the baseline as shipped (no OMP_WAIT_POLICY: OpenMP's
    spinning default), the baseline with PASSIVE (its code alone, without the wait policy's share of the gain),
    the working tree as shipped (PASSIVE from ``backend``), and under load also the working tree without it."""
    base_dir, sha = baseline_tree(args.baseline)
    trees = {"baseline": base_dir, "now": ROOT}
    tmp = tempfile.mkdtemp(prefix="scpainter-bench-ab-")
    data = os.path.join(tmp, "scene.npz")
    np.savez(data, **render_scene.scene_arrays(args.ab_points, args.ab_gaussians, W, H, cars=args.ab_cars))
    ab = {"baseline": args.baseline, "baseline_commit": sha, "baseline_tree": base_dir, "points": args.ab_points,
          "gaussians": args.ab_gaussians, "cars": args.ab_cars, "size": [W, H], "threads": args.threads,
          "rounds": args.rounds, "repeat": args.repeat, "user_wait_policy": USER_WAIT_POLICY, "cpus": os.cpu_count(),
          "measured": time.strftime("%Y-%m-%d %H:%M:%S"), "load_before": os.getloadavg()}
    workers = {}
    t_start = time.perf_counter()
    try:
        for arm, (tree, policy) in QUIET_ARMS.items():
            workers[arm] = Worker(arm, trees[tree], data, args.threads, tmp, policy)
        tasks = ("frame", "points", "gaussians")
        for w in workers.values():  # compile (numba) and warm caches outside the timed rounds
            for task in tasks:
                w.ask(cmd="time", task=task, repeat=1, warmup=1)
        arms = list(QUIET_ARMS)
        ms = {(a, t): [] for a in arms for t in tasks}
        ratios = {(a, t): [] for a in arms for t in tasks}
        for rnd in range(args.rounds):
            order = arms[rnd % len(arms):] + arms[:rnd % len(arms)]
            for task in tasks:
                got = {}
                for arm in order:
                    settle()
                    got[arm] = workers[arm].ask(cmd="time", task=task, repeat=args.repeat, warmup=1)["ms"]
                    ms[arm, task] += got[arm]
                for arm in arms:
                    ratios[arm, task].append(med(got[arm]) / med(got["now"]))
        ab["timing"] = [{"arm": arm, "tree": QUIET_ARMS[arm][0], "wait_policy": workers[arm].hello["wait_policy"],
                         "frame_ms": med(ms[arm, "frame"]), "points_ms": med(ms[arm, "points"]),
                         "gaussians_ms": med(ms[arm, "gaussians"]), "samples": len(ms[arm, "frame"])}
                        for arm in arms]
        ab["speedup"] = [{"arm": arm, "part": t, "speedup": med(ms[arm, t]) / med(ms["now", t]),
                          "per_round_min": min(ratios[arm, t]), "per_round_max": max(ratios[arm, t])}
                         for arm in ("baseline", "baseline_passive") for t in tasks]
        # frames.amodal_pixels (the working tree only): a separate cost, not part of the frame
        ab["amodal_ms"] = med(workers["now"].ask(cmd="time", task="amodal", repeat=args.repeat, warmup=1)["ms"])
        ab["pairs"] = [{"tree": QUIET_ARMS[arm][0], **workers[arm].ask(cmd="pairs"),
                        "gaussians_ms": med(ms[arm, "gaussians"]), "frame_ms": med(ms[arm, "frame"])}
                       for arm in ("baseline", "now")]
        # outputs: the point pass bit for bit; the Gaussian layers against the float64 render without a cutoff, on
        # this scene and on the accuracy scene (20 k Gaussians, car 8 m ahead: larger on screen)
        ab["outputs"] = [compare_outputs(workers, "speed scene", tmp)]
        acc = os.path.join(tmp, "accuracy_scene.npz")
        np.savez(acc, **render_scene.scene_arrays(args.ab_points, 20_000, W, H, car_distance=8.0,
                                                  cars=args.ab_cars))
        for arm in ("baseline", "now"):
            workers[arm].ask(cmd="load", data=acc)
        ab["outputs"].append(compare_outputs(workers, "accuracy scene (20 k Gaussians, 8 m)", tmp))
        for arm in ("baseline", "now"):
            workers[arm].ask(cmd="load", data=data)
        ab["seconds_quiet_part"] = time.perf_counter() - t_start
        if args.load_rounds:
            workers["now_unset"] = Worker("now_unset", ROOT, data, args.threads, tmp, "unset")
            workers["now_unset"].ask(cmd="time", task="frame", repeat=1, warmup=1)
            ab["load"] = section_load(workers, args)
        ab["workers"] = {k: w.hello for k, w in workers.items()}
    finally:
        for w in workers.values():
            w.close()
        shutil.rmtree(tmp, ignore_errors=True)  # the scene .npz and the dumps (the worker logs go with them)
    ab["seconds"] = time.perf_counter() - t_start
    ab["load_after"] = os.getloadavg()
    result["ab"] = ab


def compare_outputs(workers, scene_name, tmp):
    """Dumps of the baseline and of the working tree (with the float64 reference frame) compared."""
    tag = scene_name.split()[0]
    old = np.load(workers["baseline"].ask(cmd="dump", path=os.path.join(tmp, f"baseline_{tag}.npz"))["path"])
    new = np.load(workers["now"].ask(cmd="dump", path=os.path.join(tmp, f"now_{tag}.npz"), reference=True)["path"])
    diff = {k: int(np.any((old[k] != new[k]).reshape(H, W, -1), -1).sum())  # pixels, not values
            for k in ("points_rgb", "points_depth", "points_winner")}
    inst = f"layer_{channels.INSTANCE}"
    return {"scene": scene_name, "points_identical": all(v == 0 for v in diff.values()),
            "points_differing_pixels": diff,
            "instance_differing_pixels": (int((new[inst] != new[f"reference_{channels.INSTANCE}"]).sum())
                                          if inst in new.files else None),
            "layers_vs_reference": [{"scene": scene_name, "tree": "baseline", **layer_errors(old, new)},
                                    {"scene": scene_name, "tree": "now", **layer_errors(new, new)}]}


def section_load(workers, args):
    """Each arm's frame and point pass, quiet then beside one spinning process, interleaved over rounds."""
    arms = list(LOAD_ARMS)
    ms = {(a, t, c): [] for a in arms for t in ("frame", "points") for c in ("quiet", "loaded")}
    for rnd in range(args.load_rounds):
        for arm in arms[rnd % len(arms):] + arms[:rnd % len(arms)]:
            for task in ("frame", "points"):
                settle()
                ms[arm, task, "quiet"] += workers[arm].ask(cmd="time", task=task, repeat=args.repeat)["ms"]
                with Spinner():
                    ms[arm, task, "loaded"] += workers[arm].ask(cmd="time", task=task, repeat=args.repeat)["ms"]
    rows = []
    for arm in arms:
        h = workers[arm].hello
        row = {"arm": arm, "tree": LOAD_ARMS[arm][0], "wait_policy": h["wait_policy"] or "unset (spin 300000)",
               "threading_layer": h["threading_layer"]}
        for task in ("frame", "points"):
            q, lo = med(ms[arm, task, "quiet"]), med(ms[arm, task, "loaded"])
            row.update({f"{task}_quiet_ms": q, f"{task}_loaded_ms": lo, f"{task}_loaded_over_quiet": lo / q})
        rows.append(row)
    return {"competitor": "one process: python -c 'while True: pass'", "rounds": args.load_rounds, "rows": rows}


def print_ab(ab):
    print(f"\nab: working tree vs {ab['baseline']} ({ab['baseline_commit'][:10]}), {ab['points']} points + "
          f"{ab['gaussians']} Gaussians at {ab['size'][1]} x {ab['size'][0]}, CPU, {ab['threads']} threads of "
          f"{ab['cpus']} CPUs, measured {ab['measured']} (load average before {ab['load_before'][0]:.2f}, after "
          f"{ab['load_after'][0]:.2f}); {ab['rounds']} interleaved rounds x {ab['repeat']} calls")
    print_table("median ms", ab["timing"], ["arm", "tree", "wait_policy", "frame_ms", "points_ms", "gaussians_ms",
                                            "samples"])
    if ab.get("amodal_ms") is not None:
        print(f"\nframes.amodal_pixels (working tree, {ab['cars']} cars, separate from the frame): "
              f"{ab['amodal_ms']:.1f} ms")
    print_table("speed-up arm / now (ratio of the medians; spread of the per-round ratios)", ab["speedup"],
                ["arm", "part", "speedup", "per_round_min", "per_round_max"])
    for o in ab["outputs"]:
        print(f"\n{o['scene']}: point pass identical (rgb, depth, winner): {o['points_identical']} "
              f"(differing pixels {o['points_differing_pixels']}); instance pixels differing from the reference "
              f"frame's: {o.get('instance_differing_pixels')}")
    print_table("Gaussian layers (whole frame) against the float64 pair rasterizer without a cutoff",
                [r for o in ab["outputs"] for r in o["layers_vs_reference"]],
                ["scene", "tree", "max_abs_err_I", "mean_abs_err_I", "max_abs_err_asset_mask"])
    print_table("pixel–Gaussian pairs (pixel_boxes) and time", ab["pairs"],
                ["tree", "pairs", "gaussians", "gaussians_ms", "frame_ms"])
    if "load" in ab:
        print_table(f"under load ({ab['load']['competitor']}), {ab['load']['rounds']} rounds x {ab['repeat']} calls",
                    ab["load"]["rows"], ["arm", "tree", "wait_policy", "threading_layer", "frame_quiet_ms",
                                         "frame_loaded_ms", "frame_loaded_over_quiet", "points_quiet_ms",
                                         "points_loaded_ms", "points_loaded_over_quiet"])
    print(f"\nab section: {ab['seconds']:.0f} s")


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
    if result["accuracy"]:
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
    if result["street"]:
        ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def keep_previous_sections(path, result, sections):
    """The sections not run this time keep their figures from the previous run's JSON (if any), so running one
    section does not wipe the others' results."""
    try:
        with open(path, encoding="utf-8") as f:
            previous = json.load(f)
    except (OSError, ValueError):
        return
    for key, section in (("ab", "ab"), ("speed", "speed"), ("accuracy", "accuracy"), ("choice", "choice"),
                         ("street", "street"), ("street_info", "street")):
        ran = section in sections or (key == "speed" and "accuracy" in sections)
        if not ran and key in previous:
            result[key] = previous[key]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--devices", nargs="+", default=["cpu"], choices=["cpu", "cuda"])
    p.add_argument("--sections", nargs="+", default=None, choices=["ab", "speed", "accuracy", "choice", "street"],
                   help="default: ab speed accuracy street (--smoke: speed accuracy choice)")
    p.add_argument("--threads", type=int, default=2, help="CPU threads (torch and numba); the target is 2 cores")
    p.add_argument("--baseline", default="3fcda49", help="ab: the git revision to compare with (before issue 16)")
    p.add_argument("--rounds", type=int, default=5, help="ab: interleaved A/B rounds")
    p.add_argument("--repeat", type=int, default=3, help="ab: timed calls per request")
    p.add_argument("--load-rounds", type=int, default=3, help="ab: rounds under load (0: leave that part out)")
    p.add_argument("--ab-points", type=int, default=1_000_000)
    p.add_argument("--ab-gaussians", type=int, default=100_000)
    p.add_argument("--ab-cars", type=int, default=1, choices=[1, 2, 3],
                   help="ab: the Gaussians split between this many cars (render_scene.CAR_OFFSETS)")
    p.add_argument("--out", default=os.path.join(ROOT, "bench", "results"), help="where the JSON and plot go")
    p.add_argument("--smoke", action="store_true",
                   help="the smallest sizes on the CPU, in seconds (the suite's check that the bench still runs)")
    args = p.parse_args(argv)
    global W, H
    if args.smoke:
        if args.devices != ["cpu"]:
            p.error("--smoke runs on the CPU only")
        W, H = SMOKE_SIZE
        args.sections = args.sections or ["speed", "accuracy", "choice"]
        if set(args.sections) & {"ab", "street"}:
            p.error("--smoke has no ab or street section (worker processes, the ground-truth street)")
    else:
        W, H = 1024, 576
        args.sections = args.sections or ["ab", "speed", "accuracy", "street"]
    torch.set_num_threads(args.threads)
    if "cpu" in args.devices:
        import numba

        numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    result = {"machine": platform.node(), "cpu_threads": args.threads, "cpus": os.cpu_count(),
              "torch": torch.__version__, "gpu": torch.cuda.get_device_name() if "cuda" in args.devices else None,
              "wait_policy": os.environ.get("OMP_WAIT_POLICY"), "smoke": args.smoke, "size": [W, H], "speed": [],
              "accuracy": [], "choice": [], "street": []}
    if "ab" in args.sections and "cpu" in args.devices:
        section_ab(args, result)
    for device in args.devices:
        sizes = dict(SIZES["smoke" if args.smoke else device], **({"repeat": 2, "repeat_accuracy": 1}
                                                                  if args.smoke else {}))
        speed_scene = section_speed(device, result["speed"], sizes) if "speed" in args.sections or \
            "accuracy" in args.sections else None
        if "accuracy" in args.sections:
            section_accuracy(device, result["accuracy"], speed_scene, sizes)
        if "choice" in args.sections:
            section_choice(device, result["choice"], sizes)
    if "street" in args.sections:
        result["street_info"] = section_street(result["street"])
    if "ab" in result:
        print_ab(result["ab"])
    print_table(f"speed, {H} x {W} (ms per frame; median of {2 if args.smoke else 10})", result["speed"],
                ["device", "points", "gaussians", "frame_ms", "frame_with_download_ms", "points_ms", "gaussians_ms",
                 "gsplat_ms", "gaussians_vs_gsplat", "gsplat_mean_abs_diff_rgb", "pairs_mean_abs_diff_rgb",
                 "pairs_max_abs_diff_asset_mask", "asset_pixels", "points_winner_mismatch_cpu_vs_device"])
    if any("kernel_entries" in r for r in result["speed"]):
        print_table("CUDA tile path on the speed scene: its parts (ms) and the kernel's work (batches composited "
                    "before the early exit, of all)", result["speed"],
                    ["device", "projection_ms", "binning_ms", "inputs_ms", "kernel_ms", "kernel_tile", "kernel_batch",
                     "kernel_entries", "kernel_longest_list", "kernel_batches_done", "kernel_batches_full"])
        print_table("CUDA kernel alone per tile and batch size (ms)",
                    [dict(r, device=s["device"]) for s in result["speed"] for r in s.get("kernel_sweep", [])],
                    ["device", "tile", "batch", "kernel_ms", "default"])
    acc = SIZES["smoke" if args.smoke else "cpu"]["accuracy"]
    print_table(f"error against run time (time: the speed scene; error: {acc[0]:,} points + {acc[1]:,} Gaussians, "
                "car 8 m ahead, against the float64 pair rasterizer)", result["accuracy"],
                ["device", "setting", "frame_ms", "max_abs_err_I", "mean_abs_err_I", "max_abs_err_asset_mask"])
    print_table("compositor choice: the Gaussian pass per method and tile size (ms; max error against the float64 "
                "pair rasterizer; raster_choice.choose's pick and the fastest)", result["choice"],
                ["device", "gaussians", "projected", "method", "tile", "gaussians_ms", "max_abs_err_rgb",
                 "max_abs_err_asset_mask", "instance_differing_pixels", "chosen", "fastest"])
    print_table("ground-truth street (16 frames 518 x 294, CPU)", result["street"],
                ["confidence_percentile", "shift_m", "window", "point_radius_px", "hole_fraction", "psnr_covered_db",
                 "frame_ms"])
    os.makedirs(args.out, exist_ok=True)
    stem = os.path.join(args.out, "render_" + "_".join(args.devices) + ("_smoke" if args.smoke else ""))
    keep_previous_sections(stem + ".json", result, args.sections)
    outputs.write_json(stem + ".json", events.json_safe(result))  # a PSNR of a perfect match (inf) becomes null
    plot(result, stem + ".png")
    print(f"\nwrote {stem}.json and {stem}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
