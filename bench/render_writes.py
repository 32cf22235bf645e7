"""A frame's whole cost, writing included: the ``render`` command's wall time per frame against ``render_frame``
alone, before (every file written inline, the preview at zlib level 6) and after issue 29 (the files written on
``backend.render.writer`` threads while the next frame renders, the preview at ``png.LEVEL``), side by side.

    SCPAINTER_CACHE_DIR=... .venv/bin/python bench/render_writes.py [--baseline ebbfdbb] [--rounds 3]
                                                                   [--frames 16] [--car 100000]
                                                                   [--render-threads N] [--out DIR]
    .venv/bin/python bench/render_writes.py --smoke --out /tmp/x   # the working tree alone, 2 frames at 128 x 72

The jobs: the ground-truth street's recorded drive (its cache, or bpy to make it: ``tests_support.street_base_job``)
with a procedural car of ``--car`` Gaussians parked beside the road, at 518 × 294 (the street's own size) and at
576 × 1024 (K scaled), ``--frames`` frames. Each arm runs in a process of its own on its own source tree (the
working tree, and ``--baseline`` extracted with ``git archive``), arms interleaved for ``--rounds`` rounds. A worker
loads the scene, renders one frame to warm up, then twice in turn (so both see the machine's load of the moment):

frame alone   ``frames.render_frame`` + ``frames.amodal_pixels`` (what the command computes per frame), each frame
              once, the mean (frames differ 20-fold: the car in view and many points, or neither)
render        ``command.render_job(force=True)`` from the moment the scene is loaded (its "render ...: N of M
              frames" log line) to its return (every file on disk), divided by the frames; also the process's CPU
              time per frame (every thread)

and, in the working tree's worker, each write alone (median over the frames): the EXR (``channels.write``), the
preview at level 6 and at ``png.LEVEL``, the labels (labelled preview + labels JSON); and how long a Python thread
is kept waiting while each encoder runs on another (a call that holds the GIL keeps it waiting for the whole
call; one that releases it, for a few ms of switching).

Prints a table (medians and minima over rounds; this machine is shared, the minima are the least disturbed) and writes bench/results/render_writes.json. The ratio render / frame alone
is the number to read: 1.0 would be writing for free. ``--baseline ''`` leaves the before arm out; ``--smoke``: the
working tree's arm alone, one round, 2 frames at 128 x 72 with a 2,000-Gaussian car.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

RESOLUTIONS = {"518x294": (518, 294), "576x1024": (1024, 576)}


# ---------------------------------------------------------------------------------------------------- jobs

def make_jobs(folder: str, frames: int, car: int, resolutions: dict = RESOLUTIONS) -> dict:
    """{resolution name: job path}: the street's drive with a parked car, at each of ``resolutions``."""
    sys.path.insert(0, os.path.join(ROOT, "tests"))
    sys.path.insert(0, ROOT)
    import numpy as np

    from scpainter_blender.core import job as J
    from scpainter_blender.core import shapes
    from scpainter_blender.street.dataset import ensure_street
    from tests_support import street_base_job

    street = ensure_street()
    shapes_file = os.path.join(folder, "car.ply")
    to_file = shapes.save_as_amodal3r(shapes_file, shapes.procedural_car_gaussians(count=car, seed=7,
                                                                                   paint=(0.1, 0.3, 0.8)))
    place = np.eye(4)
    place[:3, 3] = (-3.5, 9.0, 0.0)  # beside the road, in view of the first frames (tests' street_with_car)
    out = {}
    for name, (W, H) in resolutions.items():
        path = os.path.join(folder, name, "job.json")
        job = street_base_job(street, path)
        sx, sy = W / job.resolution[0], H / job.resolution[1]
        d = job.to_dict()
        d["resolution"] = [W, H]
        d["frames"] = d["frames"][:frames]
        for fr in d["frames"]:
            fr["K"] = (np.diag([sx, sy, 1.0]) @ np.asarray(fr["K"])).tolist()
        d["assets"] = [{"name": "car", "ply": os.path.relpath(shapes_file, os.path.dirname(path)),
                        "object_to_world": {str(fr["frame"]): (place @ np.linalg.inv(to_file)).tolist()
                                            for fr in d["frames"]}}]
        d["output_dir"] = "out"
        J.save(path, d)
        out[name] = path
    return out


def baseline_tree(rev: str, folder: str) -> tuple[str, str]:
    sha = subprocess.run(["git", "-C", ROOT, "rev-parse", "--verify", rev + "^{commit}"], capture_output=True,
                         text=True, check=True).stdout.strip()
    tar = subprocess.run(["git", "-C", ROOT, "archive", "--format=tar", sha, "backend", "scpainter_blender"],
                         capture_output=True, check=True).stdout
    with tarfile.open(fileobj=io.BytesIO(tar)) as t:
        t.extractall(folder, filter="data")
    return folder, sha


# -------------------------------------------------------------------------------------------------- worker

def worker(tree: str, job_path: str, components: bool, repeats: int = 2) -> dict:
    """Timings of one arm (module docstring) in the tree ``tree``; events go to /dev/null."""
    sys.path.insert(0, tree)
    import backend  # noqa: F401  (first, as python -m backend: its thread settings before torch loads)
    import numpy as np
    import torch

    from backend.render import command, frames as fr
    from scpainter_blender.core import job as J

    job = J.load(job_path)
    W, H = job.resolution
    events_out = sys.stdout
    sys.stdout = open(os.devnull, "w")
    try:
        scene = fr.load_scene(job, job_path, "cpu")
        out = {"frame_alone_s": [], "render_per_frame_s": [], "render_cpu_per_frame_s": [],
               "torch_threads": torch.get_num_threads()}
        for rep in range(repeats):  # alone and the command in turn: both see the machine's load of the moment
            alone = []
            for i, entry in enumerate(([job.frames[0]] if rep == 0 else []) + list(job.frames)):
                t = time.perf_counter()
                kept = {}
                layers = fr.render_frame(scene, entry, W, H, keep=kept)
                fr.amodal_pixels(scene, entry, W, H, projection=kept["projection"])
                if i or rep:  # the very first is the warm-up
                    alone.append(time.perf_counter() - t)
            marks = {}

            def log(line):
                if line.startswith("render ") and "frames" in line and "t0" not in marks:
                    marks["t0"], marks["cpu0"] = time.perf_counter(), time.process_time()

            result = command.render_job(job_path, job, "cpu", force=True, log=log, allow_outside=True)
            out["frame_alone_s"].append(sum(alone) / len(alone))  # the mean, as the command's figure is
            out["render_per_frame_s"].append((time.perf_counter() - marks["t0"]) / result["rendered"])
            out["render_cpu_per_frame_s"].append((time.process_time() - marks["cpu0"]) / result["rendered"])
        if components:
            out.update(write_components(job, job_path, scene, layers))
    finally:
        sys.stdout.close()
        sys.stdout = events_out
    return out


def write_components(job, job_path, scene, layers) -> dict:
    """Each write of one frame alone, and how long each encoder keeps a Python thread waiting (module docstring)."""
    import threading
    import zlib

    import numpy as np

    from backend import png
    from backend.render import channels, command
    from scpainter_blender.core.output_layout import OutputLayout

    tmp = tempfile.mkdtemp()
    entry = job.frames[-1]
    W, H = job.resolution
    rgb = np.stack([layers[c] for c in channels.IMAGE], -1)
    a8 = (np.clip(rgb, 0, 1) * 255 + 0.5).astype(np.uint8)
    raw = np.concatenate([np.zeros((H, 1), np.uint8), a8.reshape(H, W * 3)], axis=1).tobytes()
    layout = OutputLayout(os.path.join(os.path.dirname(job_path), "out"))
    labelling = command._Labelling(job, layout, command.asset_boxes(job, scene, lambda _: None),
                                   ["0" * 64] * len(job.assets), {e.frame: "k" for e in job.frames},
                                   {e.frame: "l" for e in job.frames})
    amodal = np.zeros(len(job.assets), np.int64)
    calls = {
        "exr": lambda: channels.write(os.path.join(tmp, "f.exr"), layers,
                                      camera=channels.camera_attributes(entry.K, entry.world_to_camera, W, H)),
        "png_level6": lambda: zlib.compress(raw, 6),
        "png": lambda: png.write_png(os.path.join(tmp, "p.png"), rgb),
        "labels": lambda: labelling.write_files(len(job.frames) - 1, layers, amodal),
    }
    out = {}
    for name, fn in calls.items():
        fn()
        ts = []
        for _ in range(5):
            t = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t)
        out[f"{name}_s"] = statistics.median(ts)
    sizes = {"png_level6_bytes": len(zlib.compress(raw, 6)), "png_bytes": len(zlib.compress(raw, png.LEVEL))}
    for name in ("exr", "png", "labels"):
        out[f"{name}_gil_wait_s"] = gil_wait(calls[name])
    out["gil_wait_control_s"] = gil_wait(lambda: sum(range(3_000_000)))  # pure Python: holds the GIL
    out.update(sizes)
    return out


def gil_wait(fn, reps: int = 5) -> float:
    """The longest a Python loop on this thread waits between two steps while ``fn`` runs ``reps`` times on
    another: about ``fn``'s duration if it holds the GIL throughout, the interpreter's switch interval (5 ms) plus
    the OS's scheduling if it releases it."""
    import threading

    finished = threading.Event()

    def run():
        for _ in range(reps):
            fn()
        finished.set()

    th = threading.Thread(target=run)
    last, longest = time.perf_counter(), 0.0
    th.start()
    while not finished.is_set():
        now = time.perf_counter()
        longest, last = max(longest, now - last), now
    th.join()
    return longest


# ---------------------------------------------------------------------------------------------------- main

def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--baseline", default="ebbfdbb", help="git revision of the 'before' arm (inline writes)")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--frames", type=int, default=16)
    p.add_argument("--car", type=int, default=100_000, help="Gaussians of the parked car")
    p.add_argument("--worker", nargs=3, metavar=("TREE", "JOB", "COMPONENTS"), help=argparse.SUPPRESS)
    p.add_argument("--render-threads", type=int, default=0,
                   help="threads the renderer may use (numba, torch, OpenMP; 0: all the CPUs): with fewer than the "
                        "CPUs, the writers have a core of their own, as on a machine with cores to spare")
    sys.path.insert(0, os.path.join(ROOT, "bench"))
    import bench_cli  # bench/, the script's folder

    bench_cli.add_smoke_and_out(p, "the working tree alone, one round, 2 frames at 128 x 72, a 2,000-Gaussian car")
    args = p.parse_args(argv)
    resolutions = RESOLUTIONS
    if args.smoke:
        args.baseline, args.rounds, args.frames, args.car = "", 1, 2, 2000
        resolutions = {"128x72": (128, 72)}
    if args.worker:
        tree, job_path, components = args.worker
        print(json.dumps(worker(tree, job_path, components == "1")))
        return

    env = dict(os.environ)
    if args.render_threads:
        env.update({k: str(args.render_threads) for k in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")})
    with tempfile.TemporaryDirectory() as tmp:
        jobs = make_jobs(tmp, args.frames, args.car, resolutions)
        trees, sha = {"after": ROOT}, None
        if args.baseline:
            before_tree, sha = baseline_tree(args.baseline, os.path.join(tmp, "baseline"))
            trees = {"before": before_tree, "after": ROOT}
        runs = {(res, arm): [] for res in jobs for arm in trees}
        for r in range(args.rounds):
            for res, job_path in jobs.items():
                for arm in [a for a in (("before", "after") if r % 2 == 0 else ("after", "before")) if a in trees]:
                    components = "1" if arm == "after" else "0"
                    got = subprocess.run([sys.executable, os.path.abspath(__file__), "--worker", trees[arm], job_path,
                                          components], capture_output=True, text=True, cwd=trees[arm], env=env)
                    if got.returncode:
                        sys.exit(f"{arm} worker failed:\n{got.stderr[-3000:]}")
                    runs[res, arm].append(json.loads(got.stdout.strip().splitlines()[-1]))
                    print(f"round {r + 1} {res} {arm}: "
                          f"{[round(v * 1e3) for v in runs[res, arm][-1]['render_per_frame_s']]} ms/frame", flush=True)

    def values(res, arm, key):
        return [v for x in runs[res, arm] for v in (x[key] if isinstance(x[key], list) else [x[key]])]

    def med(res, arm, key):
        vals = values(res, arm, key) if key in runs[res, arm][0] else []
        return statistics.median(vals) if vals else float("nan")

    rows = []
    for res in jobs:
        for arm in trees:
            alone, whole = values(res, arm, "frame_alone_s"), values(res, arm, "render_per_frame_s")
            ratios = [b / a for a, b in zip(alone, whole)]
            rows.append({"resolution": res, "arm": arm, "frame_alone_ms": statistics.median(alone) * 1e3,
                         "frame_alone_min_ms": min(alone) * 1e3, "render_ms": statistics.median(whole) * 1e3,
                         "render_min_ms": min(whole) * 1e3,
                         "render_cpu_ms": statistics.median(values(res, arm, "render_cpu_per_frame_s")) * 1e3,
                         "render_over_alone": statistics.median(ratios), "ratio_min": min(ratios),
                         "ratio_max": max(ratios), "min_over_min": min(whole) / min(alone)})
    print(f"\nper frame, {len(ratios)} samples per row ({args.rounds} rounds x 2; {args.frames} frames, car "
          f"{args.car:,} Gaussians, {os.cpu_count()} CPUs, render threads {args.render_threads or 'all'}, load "
          f"average {os.getloadavg()[0]:.1f}); "
          f"before = {sha[:10] if sha else '(left out)'}")
    print(f"{'resolution':10s} {'arm':7s} {'alone ms':>9s} {'(min)':>6s} {'render ms':>10s} {'(min)':>6s} "
          f"{'CPU ms':>7s} {'render/alone':>13s} {'(range)':>10s} {'min/min':>8s}")
    for row in rows:
        print(f"{row['resolution']:10s} {row['arm']:7s} {row['frame_alone_ms']:9.0f} {row['frame_alone_min_ms']:6.0f} "
              f"{row['render_ms']:10.0f} {row['render_min_ms']:6.0f} {row['render_cpu_ms']:7.0f} "
              f"{row['render_over_alone']:13.2f} {row['ratio_min']:5.2f}-{row['ratio_max']:4.2f} "
              f"{row['min_over_min']:8.2f}")
    comps = {}
    print(f"\nwrites of one frame alone (working tree), ms; GIL wait = longest a Python thread waits meanwhile")
    print(f"{'resolution':10s} {'EXR':>6s} {'PNG lvl6':>9s} {'PNG now':>8s} {'labels':>7s} "
          f"{'GIL wait EXR/PNG/labels':>24s} {'(pure Python)':>14s} {'PNG KB 6/now':>13s}")
    for res in jobs:
        c = {k: med(res, "after", k) for k in runs[res, "after"][0] if k.endswith(("_s", "_bytes"))}
        comps[res] = c
        print(f"{res:10s} {c['exr_s'] * 1e3:6.0f} {c['png_level6_s'] * 1e3:9.0f} {c['png_s'] * 1e3:8.0f} "
              f"{c['labels_s'] * 1e3:7.0f} {c['exr_gil_wait_s'] * 1e3:10.0f}/{c['png_gil_wait_s'] * 1e3:.0f}/"
              f"{c['labels_gil_wait_s'] * 1e3:.0f} {c['gil_wait_control_s'] * 1e3:14.0f} "
              f"{c['png_level6_bytes'] / 1e3:6.0f}/{c['png_bytes'] / 1e3:.0f}")
    sys.path.insert(0, ROOT)
    from scpainter_blender.core import outputs

    args.out = bench_cli.json_path(args.out, "render_writes")
    outputs.write_json(args.out, {"baseline": sha, "rounds": args.rounds, "frames": args.frames, "car": args.car,
                                  "render_threads": args.render_threads or os.cpu_count(),
                                  "cpus": os.cpu_count(), "load_average": os.getloadavg()[0], "rows": rows,
                                  "components": comps,
                                  "runs": {f"{res} {arm}": v for (res, arm), v in runs.items()}})
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
