"""One dataset from a variation run: the single-job exports of today (one process per job and format) against one
merged export (``export --list … --format kitti,coco,openlabel --out DATASET``: one process for every job and
format, backend/export/dataset.py).

    .venv/bin/python bench/export_dataset.py [--variants 100] [--frames 16] [--resolution 128x72]
                                             [--before-calls N (default: every variant)] [--work build/bench_export]
                                             [--out bench/results] [--json FILE] [--label TEXT]
    .venv/bin/python bench/export_dataset.py --smoke --out /tmp/x   # 2 variants x 2 frames at 32 x 18, 1 call

The variants are real: ``vary`` on the street's recorded drive (the street's ground truth, cached; each variant's
first ``--frames`` frames, ``--resolution`` small), rendered on the CPU by one ``batch --list variants.txt --command render``
(the renderer writes the labels, the instance layer and the previews the exports read; rendering them rather than
building labels by hand keeps the exports' inputs exactly what a user's run gives). That build is timed but is not
what is compared. Then, both starting from rendered variants (so each export's own render pass renders nothing, as
after a batch render):

- before: ``--before-calls`` single-job exports, ``python -m backend export vNNNN/job.json --format F --out …``, one
  process each, the format cycling kitti, coco, openlabel; the cost of every variant in all three formats is
  estimated as (the mean seconds of a call) x variants x 3;
- after: one merged export of every variant in all three formats.

Prints a table and saves it as JSON. Not a test (tests/bench/test_export_dataset.py runs it with ``--smoke``). The street is one
recording, so the whole run is one drive: no ``--split`` (the split is a sort of the drives, no measurable time).
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

from scpainter_blender.core import job as job_mod, outputs  # noqa: E402
from scpainter_blender.core.backend_protocol import EXPORT_FORMAT_NAMES  # noqa: E402
from scpainter_blender.core.batch_items import DATA_ROOT_DIRECTIVE, read_job_list  # noqa: E402
from scpainter_blender.core.output_layout import VariationLayout  # noqa: E402
from scpainter_blender.core.variation import spec as spec_mod, variants  # noqa: E402
from scpainter_blender.street.dataset import ensure_street  # noqa: E402
from tests_support import street_base_job  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)
import render_scene  # noqa: E402


def backend(*args: str) -> tuple:
    """(seconds, done event) of ``python -m backend *args`` (one process, as a user runs it); SystemExit when it
    fails."""
    env = dict(os.environ, OMP_NUM_THREADS="1")
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "backend", *args], cwd=ROOT, capture_output=True, text=True, env=env)
    seconds = time.perf_counter() - t0
    events = [json.loads(x) for x in p.stdout.splitlines() if x.startswith("{")]
    if p.returncode != 0 or not events or events[-1].get("event") != "done":
        raise SystemExit(f"python -m backend {' '.join(args)} exited {p.returncode}:\n{p.stdout[-2000:]}\n"
                         f"{p.stderr[-3000:]}")
    return seconds, events[-1]


def build(out: str, count: int, frames: int, W: int, H: int) -> tuple:
    """(variants.txt as ``batch_items.JobList``, vary seconds, render seconds): the variants of the street's drive,
    rendered."""
    street = ensure_street()
    lib = render_scene.car_library(os.path.join(out, "cars"), 8000)
    base = os.path.join(out, "base", "job.json")
    street_base_job(street, base, recorded_cars=True)
    # a few more drawn than wanted: some find no place (reported by vary); the first ``count`` placed are kept
    spec = spec_mod.VariationSpec(variants=count + count // 10 + 2, seed=0, library=lib, resolution=(W, H),
                                  shifts_m=(-2.0, 0.0, 2.0), lane_change_probability=0.2, car_count=(1, 3))
    t0 = time.perf_counter()
    variants.make_variants(base, spec, os.path.join(out, "variants"),
                           data_roots=(street.root,))   # the recording the base reads: trusted
    t_vary = time.perf_counter() - t0
    layout = VariationLayout(os.path.join(out, "variants"))
    listed = read_job_list(layout.list)
    paths = listed.paths[:count]
    with open(layout.list, "w") as f:   # the list of the kept ones, as vary writes it: data-root: lines, then jobs
        f.writelines([f"{DATA_ROOT_DIRECTIVE} {r}\n" for r in listed.data_roots] + [f"{p}\n" for p in paths])
    for path in paths:  # fewer frames: the variants' first N (the road is found under the whole drive)
        job = job_mod.load(path)
        if frames < len(job.frames):
            job.frames = job.frames[:frames]
            job_mod.save(path, job)
    t_render, _ = backend("batch", "--list", layout.list, "--command", "render", "--device", "cpu")
    return read_job_list(layout.list), t_vary, t_render


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--variants", type=int, default=100)
    p.add_argument("--frames", type=int, default=16, help="each variant's first N frames (the street has 16)")
    p.add_argument("--resolution", default="128x72")
    p.add_argument("--before-calls", type=int, default=None, help="single-job exports to time (default: one per "
                                                                  "variant)")
    p.add_argument("--work", help="the variants and exports (emptied first; default build/bench_export, with "
                                  "--smoke a temporary folder)")
    p.add_argument("--json", help="the JSON file (default: export_dataset.json in --out)")
    p.add_argument("--label", default="")
    bench_cli.add_smoke_and_out(p, "2 variants x 2 frames at 32 x 18, one single-job export")
    args = p.parse_args(argv)
    if args.smoke:
        args.variants, args.frames, args.resolution, args.before_calls = 2, 2, "32x18", 1
        args.label = args.label or "smoke"
    args.json = args.json or bench_cli.json_path(args.out, "export_dataset")
    W, H = (int(v) for v in args.resolution.split("x"))
    temporary = args.work is None and args.smoke
    out = tempfile.mkdtemp(prefix="bench_export_") if temporary else \
        os.path.abspath(args.work or os.path.join(ROOT, "build", "bench_export"))
    shutil.rmtree(out, ignore_errors=True)  # this bench's own folder: nothing reused
    os.makedirs(out)
    try:
        return measure(args, out, W, H)
    finally:
        if temporary:
            shutil.rmtree(out, ignore_errors=True)


def measure(args, out: str, W: int, H: int) -> int:
    """The build, the single-job exports and the merged one in ``out``; prints the table, writes ``args.json``."""
    listed, t_vary, t_render = build(out, args.variants, args.frames, W, H)
    lst, jobs = listed.path, listed.paths
    roots = [a for r in listed.data_roots for a in ("--data-root", r)]   # the list's data-root: lines
    frames = sum(len(job_mod.load(j).frames) for j in jobs)
    # the three dataset formats (kitti-tracking, a sequence per job, is a fourth the bench leaves out)
    formats = [f for f in EXPORT_FORMAT_NAMES if f in ("kitti", "coco", "openlabel")]

    calls = len(jobs) if args.before_calls is None else min(args.before_calls, len(jobs))
    before = {f: [] for f in formats}
    for k in range(calls):
        fmt = formats[k % len(formats)]
        seconds, _ = backend("export", jobs[k], "--format", fmt, "--out", os.path.join(out, "single", f"{k}_{fmt}"),
                             "--device", "cpu", *roots)
        before[fmt].append(seconds)
    measured = [s for f in formats for s in before[f]]
    per_call = sum(measured) / len(measured)
    after_s, done = backend("export", "--list", lst, "--format", ",".join(formats), "--out",
                            os.path.join(out, "dataset"), "--device", "cpu")
    objects = {f: sum(c["objects"] for c in done["counts"][f].values()) for f in formats}
    result = {"label": args.label, "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
              "variants": len(jobs), "frames": frames, "resolution": [W, H], "formats": formats,
              "build": {"vary_s": t_vary, "render_s": t_render},
              "before": {"calls": calls, "seconds": sum(measured), "per_call_s": per_call,
                         "per_format_s": {f: (sum(v) / len(v) if v else None) for f, v in before.items()},
                         "estimated_all_formats_s": per_call * len(jobs) * len(formats)},
              "after": {"seconds": after_s, "rendered": done["rendered"], "frames": done["frames"],
                        "objects": objects, "seconds_in_process": done["seconds"]}}
    est = result["before"]["estimated_all_formats_s"]
    print(f"\n{len(jobs)} variants x {frames // max(1, len(jobs))} frames at {W}x{H} (built: vary {t_vary:.1f} s, "
          f"render {t_render:.0f} s)")
    print(f"{'export':<44} {'processes':>9} {'seconds':>9} {'s / job':>8}")
    print(f"{'before: single job, one format (measured)':<44} {calls:>9} {sum(measured):>9.1f} {per_call:>8.2f}")
    print(f"{'before: every job x 3 formats (estimated)':<44} {len(jobs) * 3:>9} {est:>9.1f} {est / len(jobs):>8.2f}")
    print(f"{'after: one dataset, 3 formats (measured)':<44} {1:>9} {after_s:>9.1f} {after_s / len(jobs):>8.2f}")
    print(f"speed-up {est / after_s:.1f}x; objects written: "
          + ", ".join(f"{f} {n}" for f, n in objects.items()))
    os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
    outputs.write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
