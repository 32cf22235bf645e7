"""The artist's loop through the real operators (bpy, background mode): a baseline revision and the working tree,
side by side in one run, on the street at 518 x 294, 16 frames, a parked car and a camera path 2 m left.

    .venv/bin/python bench/artist_loop.py [--baseline ebbfdbb] [--work build/bench_artist_loop]
                                          [--out bench/results] [--json FILE] [--smoke]

Each arm runs in its own process (its own add-on, built from its tree and installed in a private Blender user
folder; the baseline's tree extracted with ``git archive``). The clicks, in order, each *Render Conditions*
(``bpy.ops.scpainter.render_conditions``, blocking as in background mode; the working tree's runs go through its
warm backend when it has one):

    cold        the first render of the session
    unchanged   nothing changed: the click until "up to date" (or until the backend found nothing to do)
    moved       the parked car moved 0.3 m: the frames re-rendered (EXR times), the click's cost beyond their
                render time (the backend log's per-frame seconds)
    moved back  again, the car moved back

and for each click the time from the click to the start of the first frame rendered (its labels file's time, the
frame's last write, minus its logged render and write seconds).

Prints a table and saves JSON. Not a test. Targets (issue 29): unchanged <= 0.5 s; moved: only the frames it
touches, overhead <= 1.5 s; moved back: first frame <= 1 s after the click. ``--baseline ''`` leaves the baseline
arm out; ``--smoke``: the working tree alone on two synthetic 64 x 48 frames (not the street: its first click
alone takes ~45 s), a 2,000-Gaussian car, in a temporary work folder. It imports bpy with a private user folder: run it in a process of its own.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FRAMES = 16
CAR_AT = (-3.5, 9.0, 0.0)


def tree_of(rev: str) -> tuple[str, str]:
    """(folder, commit): the whole repository at ``rev`` extracted with ``git archive`` into a temp folder."""
    sha = subprocess.run(["git", "-C", ROOT, "rev-parse", "--verify", rev + "^{commit}"], capture_output=True,
                         text=True, check=True).stdout.strip()
    folder = os.path.join(tempfile.gettempdir(), f"scpainter-artist-{sha[:12]}")
    if not os.path.exists(os.path.join(folder, ".complete")):
        tar = subprocess.run(["git", "-C", ROOT, "archive", "--format=tar", sha], capture_output=True,
                             check=True).stdout
        with tarfile.open(fileobj=io.BytesIO(tar)) as t:
            t.extractall(folder, filter="data")
        open(os.path.join(folder, ".complete"), "w").close()
    return folder, sha


def _frame_seconds(log_path: str, offset: int) -> dict:
    """{frame: (render seconds, seconds until its last file)} of the frames the backend log records after byte
    ``offset``: "frame N: X s, ..." (X: the whole frame) or "frame N: X s rendering, Y s writing" (written beside
    the next frame's render: X, X + Y)."""
    with open(log_path, encoding="utf-8", errors="replace") as f:
        f.seek(offset)
        text = f.read()
    out = {}
    for m in re.finditer(r"\bframe (\d+): ([0-9.]+) s(?: rendering, ([0-9.]+) s writing)?", text):
        x = float(m.group(2))
        out[int(m.group(1))] = (x, x + float(m.group(3) or 0.0))
    return out


def worker(tree: str, work: str, out_json: str, smoke: bool = False) -> None:
    """One arm: the scenario in this process, with the add-on of ``tree`` (``smoke``: two synthetic frames, a
    2,000-Gaussian car)."""
    frames, count = (2, 2000) if smoke else (FRAMES, 20000)
    sys.path.insert(0, tree)
    sys.path.insert(0, os.path.join(tree, "tests"))
    from tools import blender_env

    pkg = blender_env.install_for_script(work)
    import bpy

    from scpainter_blender.core import shapes
    from scpainter_blender.core.output_layout import OutputLayout
    from scpainter_blender.street.dataset import ensure_street

    bpy.ops.wm.read_homefile(use_empty=True)
    if smoke:  # two synthetic frames (bench_import's): the street's first click costs ~45 s on 2 cores
        sys.path.insert(0, os.path.join(ROOT, "bench"))
        from bench_import import make_predictions

        make_predictions(os.path.join(work, "pred.npz"), 2, H=48, W=64)
        assert bpy.ops.scpainter.import_vggt(filepath=os.path.join(work, "pred.npz"),
                                             scale_mode="FACTOR") == {"FINISHED"}
    else:
        street = ensure_street()
        bpy.ops.scpainter.import_vggt(filepath=street.predictions_path, scale_mode="TRAJECTORY",
                                      trajectory_path=os.path.join(street.root, "metric.npz"))
    ply = os.path.join(work, "car.ply")
    shapes.save_as_amodal3r(ply, shapes.procedural_car_gaussians(count=count, seed=7, paint=(0.1, 0.3, 0.8)))
    scene = bpy.context.scene
    scene.cursor.location = CAR_AT
    bpy.ops.scpainter.import_gaussians(filepath=ply)
    car = bpy.context.active_object
    bpy.ops.scpainter.new_camera_path(shift=2.0)
    scene.frame_start, scene.frame_end = 1, frames
    scene.render.resolution_percentage = 100
    scene.scpainter_output_dir = os.path.join(work, "out")
    prefs = bpy.context.preferences.addons[pkg].preferences
    prefs.backend_python, prefs.device = sys.executable, "CPU"
    layout = OutputLayout(os.path.join(work, "out", bpy.path.clean_name(scene.camera.name)))

    def click():
        log_at = os.path.getsize(layout.log) if os.path.isfile(layout.log) else 0
        exr = {f: os.stat(layout.condition_exr(f)).st_mtime_ns if os.path.isfile(layout.condition_exr(f)) else 0
               for f in range(1, frames + 1)}
        t0 = time.time()
        assert bpy.ops.scpainter.render_conditions() == {"FINISHED"}
        seconds = time.time() - t0
        redone = sorted(f for f in exr if os.stat(layout.condition_exr(f)).st_mtime_ns != exr[f])
        per_frame = _frame_seconds(layout.log, log_at) if os.path.isfile(layout.log) else {}
        render_s = sum(per_frame.get(f, (0.0, 0.0))[0] for f in redone)
        first = None
        if redone:
            f = min(redone, key=lambda f: os.stat(layout.frame_labels(f)).st_mtime_ns)
            first = os.stat(layout.frame_labels(f)).st_mtime_ns / 1e9 - per_frame.get(f, (0.0, 0.0))[1] - t0
        return {"seconds": seconds, "frames_rendered": len(redone), "render_s": render_s,
                "overhead_s": seconds - render_s, "first_frame_start_s": first}

    rows = {"cold": click(), "unchanged": click()}
    car.location.x += 0.3
    rows["moved"] = click()
    car.location.x -= 0.3
    rows["moved back"] = click()
    with open(out_json, "w") as f:
        json.dump(rows, f)
    # a warm backend (when the tree has one) ends with the session: unregistering the add-on stops it
    bpy.ops.preferences.addon_disable(module=pkg)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--baseline", default="ebbfdbb", help="git revision of the baseline arm ('' leaves it out)")
    p.add_argument("--work", help="the arms' folders (default build/bench_artist_loop; with --smoke a temporary one)")
    p.add_argument("--json", help="the JSON file (default: artist_loop.json in --out)")
    p.add_argument("--worker", nargs=3, metavar=("TREE", "WORK", "OUT_JSON"), help=argparse.SUPPRESS)
    sys.path.insert(0, os.path.join(ROOT, "bench"))
    import bench_cli  # bench/, the script's folder

    bench_cli.add_smoke_and_out(p, "the working tree alone, two synthetic frames, a 2,000-Gaussian car")
    args = p.parse_args(argv)
    if args.worker:
        worker(*args.worker, smoke=args.smoke)
        return 0
    import shutil

    temporary = args.smoke and not args.work
    if args.smoke:
        args.baseline = ""
        args.work = args.work or tempfile.mkdtemp(prefix="bench_artist_loop_")
    args.work = os.path.abspath(args.work or os.path.join(ROOT, "build", "bench_artist_loop"))
    args.json = args.json or bench_cli.json_path(args.out, "artist_loop")
    arms = {"now": ROOT}
    if args.baseline:
        base_tree, sha = tree_of(args.baseline)
        arms = {f"baseline {sha[:7]}": base_tree, "now": ROOT}
    results = {}
    for name, tree in arms.items():
        work = os.path.join(args.work, name.split()[0])
        shutil.rmtree(work, ignore_errors=True)
        os.makedirs(work)
        out_json = os.path.join(work, "rows.json")
        env = {**os.environ, "PYTHONPATH": tree}
        subprocess.run([sys.executable, os.path.abspath(__file__), "--worker", tree, work, out_json,
                        *(["--smoke"] if args.smoke else [])], check=True, env=env, cwd=tree)
        with open(out_json) as f:
            results[name] = json.load(f)
    header = f"{'click':<12}" + "".join(f"{arm:>44}" for arm in results)
    print(header)
    print(f"{'':<12}" + "".join(f"{'seconds  frames  overhead  first frame':>44}" for _ in results))
    for click in ("cold", "unchanged", "moved", "moved back"):
        cells = []
        for arm in results:
            r = results[arm][click]
            first = "-" if r["first_frame_start_s"] is None else f"{r['first_frame_start_s']:.2f}"
            cells.append(f"{r['seconds']:>11.2f}{r['frames_rendered']:>8d}{r['overhead_s']:>10.2f}{first:>13}")
        print(f"{click:<12}" + "".join(f"{c:>44}" for c in cells))
    sys.path.insert(0, ROOT)
    from tools import blender_env

    blender_env.use_private_user_resources(os.path.join(args.work, "blender-user"))
    blender_env.write_bench_json(args.json, [{"arm": arm, "click": click, **r} for arm, rows in results.items()
                                             for click, r in rows.items()])
    print(f"saved {args.json}")
    if temporary:
        shutil.rmtree(args.work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
