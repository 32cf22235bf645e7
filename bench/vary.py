"""Variations of the street at scale: ``vary`` for N variants (the placement step's variants/s), then their
condition layers rendered at low resolution by ``batch`` on W local workers (static shards, as torchrun would
give them), and each worker's idle time (the wall time it waited for the slowest shard).

    .venv/bin/python bench/vary.py [--variants 1000] [--workers 2] [--resolution 128x72] [--work build/bench_vary]
                                   [--render-variants N (default: all)] [--out bench/results] [--json FILE]
    .venv/bin/python bench/vary.py --smoke --out /tmp/x   # 4 variants, 2 rendered at 32 x 18 by one worker

Prints a table and saves it as JSON. Not a test. The base job is the street's recorded drive (its true metric
cameras), the library two procedural cars saved as Amodal3R saves them.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))
sys.path.insert(0, os.path.join(ROOT, "bench"))

from scpainter_blender.core import outputs  # noqa: E402
from scpainter_blender.core.batch_items import DATA_ROOT_DIRECTIVE  # noqa: E402
from scpainter_blender.core.output_layout import VariationLayout  # noqa: E402
from scpainter_blender.core.variation import spec as spec_mod, variants  # noqa: E402
from scpainter_blender.street.dataset import ensure_street  # noqa: E402
from tests_support import street_base_job  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)
import render_scene  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variants", type=int, default=1000)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--resolution", default="128x72")
    p.add_argument("--render-variants", type=int, default=None, help="render only the first N placed variants")
    p.add_argument("--work", help="the library, variants and worker logs (default build/bench_vary, with --smoke a "
                                  "temporary folder)")
    p.add_argument("--json", help="the JSON file (default: vary.json in --out)")
    bench_cli.add_smoke_and_out(p, "4 variants, 2 of them rendered at 32 x 18 by one worker")
    args = p.parse_args(argv)
    if args.smoke:
        args.variants, args.workers, args.resolution, args.render_variants = 4, 1, "32x18", 2
    args.json = args.json or bench_cli.json_path(args.out, "vary")
    temporary = args.work is None and args.smoke
    out = tempfile.mkdtemp(prefix="bench_vary_") if temporary else \
        os.path.abspath(args.work or os.path.join(ROOT, "build", "bench_vary"))
    try:
        return measure(args, out)
    finally:
        if temporary:
            shutil.rmtree(out, ignore_errors=True)


def measure(args, out: str) -> int:
    """``vary`` then the batch render in ``out``; prints the table, writes ``args.json``."""
    W, H = (int(v) for v in args.resolution.split("x"))
    shutil.rmtree(os.path.join(out, "variants"), ignore_errors=True)  # this bench's own folder: nothing reused
    street = ensure_street()
    lib = render_scene.car_library(os.path.join(out, "cars"), 20000)
    base = os.path.join(out, "base", "job.json")
    street_base_job(street, base)
    spec = spec_mod.VariationSpec(variants=args.variants, seed=0, library=lib, resolution=(W, H),
                                  shifts_m=(-3.0, -2.0, 0.0, 2.0, 3.0), lane_change_probability=0.2)
    t0 = time.perf_counter()
    manifest = variants.make_variants(base, spec, os.path.join(out, "variants"),
                                      data_roots=(street.root,))   # the recording the base reads: trusted
    t_vary = time.perf_counter() - t0
    layout = VariationLayout(os.path.join(out, "variants"))
    with open(layout.list) as f:
        lines = f.read().splitlines()
    if args.render_variants is not None:  # the data roots, then the first N jobs
        head = [x for x in lines if not x.strip() or x.startswith("#") or x.startswith(DATA_ROOT_DIRECTIVE)]
        jobs = [x for x in lines if x not in head][:args.render_variants]
        lines = head + jobs
    lst = os.path.join(out, "render_list.txt")
    with open(lst, "w") as f:
        f.write("\n".join(l if not l or l.startswith(("#", DATA_ROOT_DIRECTIVE)) or os.path.isabs(l)
                          else os.path.join(layout.root, l) for l in lines) + "\n")
    n_jobs = sum(1 for x in lines if x.strip() and not x.startswith(("#", DATA_ROOT_DIRECTIVE)))

    env = dict(os.environ, OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    # each worker's streams into files: a pipe read only after another worker ends would fill and stall it
    logs = [(open(os.path.join(out, f"worker{k}.out"), "w+"), open(os.path.join(out, f"worker{k}.err"), "w+"))
            for k in range(args.workers)]
    t0 = time.perf_counter()
    procs = [subprocess.Popen([sys.executable, "-m", "backend", "batch", "--list", lst, "--command", "render",
                               "--device", "cpu", "--shard", f"{k}/{args.workers}"],
                              cwd=ROOT, env=env, stdout=logs[k][0], stderr=logs[k][1], text=True)
             for k in range(args.workers)]
    ends = {}
    while len(ends) < len(procs):  # when each worker ends, polled (a bounded wait per worker)
        for k, proc in enumerate(procs):
            if k not in ends:
                try:
                    proc.wait(timeout=0.2)
                    ends[k] = time.perf_counter() - t0
                except subprocess.TimeoutExpired:
                    pass
    workers = []
    for k, proc in enumerate(procs):
        ended = ends[k]
        for f in logs[k]:
            f.seek(0)
        stdout, stderr = (f.read() for f in logs[k])
        done = [json.loads(x) for x in stdout.splitlines() if x.startswith("{") and '"done"' in x]
        if not done:
            raise SystemExit(f"worker {k} ended without a summary:\n{stdout[-2000:]}\n{stderr[-2000:]}")
        done = done[-1]
        busy = sum(item["seconds"] for item in done["items"])
        workers.append({"worker": k, "jobs": len(done["items"]), "failed": done.get("failed", 0),
                        "busy_s": busy, "ended_s": ended})
    wall = time.perf_counter() - t0
    for w in workers:
        w["idle_s"] = wall - w["busy_s"]
        w["idle_fraction"] = w["idle_s"] / wall
    s = manifest["summary"]
    result = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
              "variants": args.variants, "placed": s["placed"], "unplaced": s["unplaced"], "cars": s["cars"],
              "rejections": s["rejections"], "vary_s": t_vary, "timings": manifest["timings"],
              "render": {"jobs": n_jobs, "frames_per_job": 16, "resolution": [W, H], "workers": workers,
                         "wall_s": wall, "jobs_per_s": n_jobs / wall}}
    print(f"\nvary: {args.variants} variants in {t_vary:.1f} s (road {manifest['timings']['road_s']:.2f} s, "
          f"library {manifest['timings']['library_s']:.2f} s, placement {manifest['timings']['placement_s']:.1f} s "
          f"= {manifest['timings']['variants_per_s']:.1f} variants/s); placed {s['placed']}, unplaced "
          f"{s['unplaced']}, {s['cars']} cars")
    print(f"render: {n_jobs} jobs x 16 frames at {W}x{H} on {args.workers} workers in {wall:.0f} s "
          f"({n_jobs / wall:.2f} jobs/s)")
    print(f"{'worker':>6} {'jobs':>5} {'failed':>6} {'busy s':>8} {'ended s':>8} {'idle s':>7} {'idle %':>6}")
    for w in workers:
        print(f"{w['worker']:>6} {w['jobs']:>5} {w['failed']:>6} {w['busy_s']:>8.1f} {w['ended_s']:>8.1f} "
              f"{w['idle_s']:>7.1f} {100 * w['idle_fraction']:>6.1f}")
    os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
    outputs.write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
