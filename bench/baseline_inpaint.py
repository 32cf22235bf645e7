"""The inpainting baseline (``backend/generate/baseline.py``) on the ground-truth street: its error against run time.

    .venv/bin/python bench/baseline_inpaint.py [--resolution 518 294] [--frames 16] [--radii 3 8] [--repeats 3]
                                               [--out bench/results] [--smoke]

The street exported as an evaluation clip (``backend.train.street_clip``), each evaluation task's job
(``evaluate.protocol.task_job``: the drive shifted ±2, ±3 m, points of frames t ± 8) rendered through the real
``render`` code, then every method × radius inpaints the same condition frames. Per row, over the four shifts:

* PSNR (dB) of all pixels and of the hole pixels only, against the Cycles renders of the shifted drives;
* the flow-warping error (``evaluate.temporal``; the ground truth's own is the floor);
* ms per frame of ``inpaint_video`` alone, the methods alternated frame by frame (``--repeats`` passes; medians).

The row "naive" is the condition image with black holes (what ``evaluate`` calls naive), for scale. Timings on a
shared 2-core machine are noisy; compare the ratios of one run. Prints a table; writes
bench/results/baseline_inpaint.json (``--out DIR``). ``--smoke``: 2 frames at 64 x 36, radius 3, one pass.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

import bench_cli  # noqa: E402  (bench/, the script's folder)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--resolution", type=int, nargs=2, default=[518, 294], metavar=("W", "H"))
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--radii", type=int, nargs="+", default=[3, 8])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--work", help="folder for the clip and the rendered tasks (default: a temporary one)")
    bench_cli.add_smoke_and_out(ap, "2 frames at 64 x 36, radius 3, one pass")
    args = ap.parse_args(argv)
    if args.smoke:
        args.resolution, args.frames, args.radii, args.repeats = [64, 36], 2, [3], 1
    import torch

    from backend.generate import baseline
    from backend.evaluate import protocol
    from backend.evaluate.image_metrics import psnr
    from backend.evaluate.temporal import warping_error
    from backend.generate.command import load_conditions
    from backend.render import command as render_cmd
    from backend.train import clip as clip_mod
    from backend.train import street_clip
    from backend.train.pairs import load_clip_frames
    from scpainter_blender.core import job as job_mod
    from scpainter_blender.street.dataset import ensure_street

    W, H = args.resolution
    work = args.work or tempfile.mkdtemp(prefix="baseline_inpaint_")
    clip = clip_mod.load(street_clip.export_clip(ensure_street(log=print), os.path.join(work, "clip")))
    s = protocol.EvalSettings(clips=[clip.path], output_dir=work, width=W, height=H, frames=args.frames)
    shifts = [sh for sh in s.shifts if sh in clip.views]
    frames = range(min(s.frames, clip.num_frames))
    tasks = []
    for shift in shifts:
        path = protocol.task_job(clip, s, os.path.join(work, f"nvs_{shift:+g}m"), shift, None)
        job = job_mod.load(path)
        render_cmd.render_job(path, job, "cpu", allow_outside=True)
        image, _, valid = load_conditions(path, job)
        gt = load_clip_frames(clip, W, H, list(frames), view=shift).float() / 255.0
        tasks.append((shift, image.numpy(), 1.0 - valid.numpy(), gt))
    methods = [(m, r) for m in job_mod.INPAINT_METHODS for r in args.radii]
    times = {key: [] for key in methods}
    outputs = {}
    for _ in range(args.repeats):  # alternated frame by frame, so load changes hit every method alike
        for shift, image, hole, _gt in tasks:
            for f in range(len(image)):
                for m, r in methods:
                    t0 = time.perf_counter()
                    out = baseline.inpaint_frame(np.moveaxis(image[f], 0, -1), hole[f, 0], m, r)
                    times[(m, r)].append(time.perf_counter() - t0)
                    outputs[(m, r, shift, f)] = out

    def score(video, gt, hole):
        v = video if torch.is_tensor(video) else torch.from_numpy(video)
        holes = torch.from_numpy(hole > 0.5)
        return {"psnr": float(psnr(v, gt).mean()), "psnr_holes": float(psnr(v, gt, mask=holes).mean()),
                "warping_error": warping_error(v.permute(0, 2, 3, 1).numpy()).mean}

    rows = []
    for name, get in [("naive (holes black)", lambda shift, image: torch.from_numpy(image).clamp(0, 1))] + [
            (f"{m} r={r}", (lambda m, r: lambda shift, image: torch.from_numpy(np.stack(
                [outputs[(m, r, shift, f)] for f in range(len(image))])).permute(0, 3, 1, 2).float() / 255.0)(m, r))
            for m, r in methods]:
        per = [score(get(shift, image), gt, hole) for shift, image, hole, gt in tasks]
        row = {"output": name, **{k: float(np.mean([p[k] for p in per])) for k in per[0]}}
        key = next(((m, r) for m, r in methods if name == f"{m} r={r}"), None)
        row["ms_per_frame"] = 1e3 * float(np.median(times[key])) if key else 0.0
        rows.append(row)
    floor = float(np.mean([warping_error(gt.permute(0, 2, 3, 1).numpy()).mean for *_, gt in tasks]))
    holes = float(np.mean([hole.mean() for _, _, hole, _ in tasks]))
    print(f"\nstreet, {W}x{H}, {len(frames)} frames, shifts {shifts}, hole fraction {holes:.3f}; "
          f"ground truth's own warping error {floor:.5f}")
    print("| output | PSNR dB | PSNR holes dB | warping error | ms/frame |\n|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['output']} | {r['psnr']:.2f} | {r['psnr_holes']:.2f} | {r['warping_error']:.5f} | "
              f"{r['ms_per_frame']:.1f} |")
    from scpainter_blender.core import outputs

    outputs.write_json(bench_cli.json_path(args.out, "baseline_inpaint"), {
        "resolution": [W, H], "frames": len(frames), "shifts": shifts, "hole_fraction": holes,
        "ground_truth_warping_error": floor, "repeats": args.repeats, "rows": rows})
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
