"""What the labels cost a CPU frame and a variant batch, before and after (issue 44 item 6), measured side by side.

    .venv/bin/python bench/labels_cost.py [--before REV | --before-tree DIR] [--rounds 5] [--variants 40] [--out bench/results]
    .venv/bin/python bench/labels_cost.py --smoke --out DIR        # seconds: the current tree alone, tiny sizes
    python bench/labels_cost.py --device cuda --variants 0 --before-tree MAIN --out DIR   # the frame on a GPU

Two parts, each timed in two source trees, the requests interleaved (before, after, after, before, ...):

* **Frame** (``render_scene.scene_arrays``: 1 M points of the box street and three procedural cars, 100 k
  Gaussians in all, one partly behind another, at 1024 x 576, saved as a job with three PLY files): per frame,
  what ``render`` computes: ``render_frame`` (with its instance pass), the amodal counts (the tree's way: a
  render per car (``frames.amodal_pixels``) before, the frame's own kernel walk (``frames.frame_amodal``) after),
  and the frame's files as the tree's ``render`` writes them (``command._write_frame``: the condition EXR, its
  preview, the labelled preview, the labels JSON; ``labels`` times ``write_files``, the labels' part, apart).
  Against it the render alone: the same frame with the three cars as one asset (no instance work, no amodal, no
  labels) and its EXR and preview. ``labels %`` = (frame - alone) / frame; ``ratio`` = frame / alone.
  The after tree's amodal counts must equal the before tree's (printed).
* **Batch**: ``--variants`` variants of the ground-truth street (``core.variation``, two library cars, 128 x 72,
  16 frames each) rendered by ``python -m backend batch --shard 0/1`` (one process, one thread, as ``bench/vary.py``
  runs its workers) from each tree, in ``--chunks`` chunks alternating trees (each tree renders its own copy of the
  variants); per variant seconds (the batch's own ``seconds`` per job) and the wall time of each process.

The before tree: ``--before-tree DIR``, else ``git archive`` of ``--before REV`` (default: the merge base of
``main`` and HEAD, i.e. a branch's changes alone) into a temporary folder; a revision whose code is HEAD's (on
``main`` itself, or once the branch is merged, the merge base is HEAD) is refused, since the run would compare the
code with itself. ``--smoke``: the
current tree only, in this process, at tiny sizes, its "before" being the second render that ``amodal_pixels``
still does (the same code as main's); no batch. ``--device cuda``: the frame part on the GPU, where both trees
still count amodal pixels with ``amodal_pixels``' render per car (the Triton kernel counts nothing), so it measures
what that costs there. Prints a table and saves ``labels_cost.json`` in ``--out``.
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

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HERE = os.path.dirname(os.path.abspath(__file__))


# -- the frame part (runs inside either tree: only the API both share, plus frame_amodal where it exists) ----------

def make_frame_inputs(folder: str, n_points: int, n_gaussians: int, width: int, height: int) -> tuple[str, str]:
    """(job.json, points.npz) in ``folder``: ``render_scene.scene_arrays(cars=3)``'s cars saved as Amodal3R PLYs and
    placed by a job with one frame (its camera, no scene: the points come from the .npz, as ``render_scene``'s)."""
    sys.path.insert(0, HERE)
    import render_scene

    from scpainter_blender.core import job as J
    from scpainter_blender.core import shapes
    from scpainter_blender.core.splats import gaussians as splats

    a = render_scene.scene_arrays(n_points, n_gaussians, width, height, cars=3)
    assets = []
    for c in range(3):
        sel = a["g_car"] == c
        g = splats.Gaussians(means=a["g_means"][sel], scales=a["g_scales"][sel], quats=a["g_quats"][sel],
                             opacities=a["g_opacities"][sel], sh=a["g_sh"][sel])
        car_to_file = shapes.save_as_amodal3r(os.path.join(folder, f"car{c}.ply"), g)
        place = np.asarray(a["object_to_world"][c], np.float64) @ np.linalg.inv(car_to_file)
        assets.append({"name": f"car{c}", "ply": f"car{c}.ply", "object_to_world": {"0": place.tolist()}})
    job = {"schema": J.SCHEMA, "resolution": [width, height], "fps": 10.0, "output_dir": "out", "assets": assets,
           "frames": [{"frame": 0, "K": np.asarray(a["K"]).tolist(),
                       "world_to_camera": np.asarray(a["world_to_camera"]).tolist()}]}
    job_path = os.path.join(folder, "job.json")
    J.save(job_path, job)
    npz = os.path.join(folder, "points.npz")
    np.savez(npz, xyz=a["xyz"], rgb=a["rgb"], frame=a["frame"])
    return job_path, npz


class FrameWork:
    """One frame of the job at ``job_path`` with the points of ``npz``, as ``render`` computes it, in whichever
    ``backend`` is first on sys.path. ``amodal``: "tree" (``frame_amodal`` where the tree has it, else the render
    per car) or "second_render" (``amodal_pixels`` always)."""

    def __init__(self, job_path: str, npz: str, amodal: str = "tree", device: str = "cpu"):
        import torch

        from backend import png
        from backend.render import channels, command, frames as fr, labelled
        from scpainter_blender.core import job as J

        self.torch, self.png, self.channels, self.fr, self.labelled = torch, png, channels, fr, labelled
        self.job = J.load(job_path)
        self.scene = fr.load_scene(self.job, job_path, device, points=False)
        with np.load(npz, allow_pickle=False) as z:
            xyz, rgb, frame = z["xyz"], z["rgb"], z["frame"]
        for s in (self.scene,):
            s.xyz, s.rgb = torch.as_tensor(xyz, device=device), torch.as_tensor(rgb, device=device)
            s.frame = torch.as_tensor(frame, device=device)
            s.frames_present = frozenset(np.unique(frame).tolist())
            s.frame_slices, s.frame_boxes = fr.frame_index(frame, xyz)
        self.entry = self.job.frames[0]
        self.W, self.H = self.job.resolution
        # the render alone: the same Gaussians as one asset placed in the world (no instance work, no labels)
        one = fr.Scene(origin=self.scene.origin, device=self.scene.device, xyz=self.scene.xyz, rgb=self.scene.rgb,
                       frame=self.scene.frame, frames_present=self.scene.frames_present,
                       frame_slices=self.scene.frame_slices, frame_boxes=self.scene.frame_boxes)
        parts = []
        for a in self.scene.assets:
            A = torch.as_tensor(np.asarray(a.object_to_world[self.entry.frame], np.float64), device=device)
            parts.append((a.means @ A[:3, :3].T + A[:3, 3], A[:3, :3] @ a.factors, a.opacities, a.sh))
        means, factors, opac, sh = (torch.cat(x) for x in zip(*parts))
        merged = fr.Asset("cars", means, factors, opac, sh, {self.entry.frame: np.eye(4)})
        one.assets = [merged]
        self.alone_scene = one
        from scpainter_blender.core.output_layout import OutputLayout

        self.command = command
        self.tmp = tempfile.mkdtemp(prefix="labels_cost_")
        layout = OutputLayout(self.tmp)
        os.makedirs(os.path.join(self.tmp, OutputLayout.CONDITIONS))
        self.labelling = command._Labelling(self.job, layout, command.asset_boxes(self.job, self.scene,
                                                                                 lambda *_: None),
                                            ["0" * 64] * len(self.job.assets), {0: "layers"}, {0: "labels"})
        self.amodal_mode = amodal if hasattr(fr, "frame_amodal") else "second_render"

    def _files(self, layers) -> None:
        self.channels.write(os.path.join(self.tmp, "c.exr"), layers)
        self.png.write_png(os.path.join(self.tmp, "c.png"), np.stack([layers[c] for c in self.channels.IMAGE], -1))

    def frame(self) -> dict:
        """ms of each part of one frame as ``render`` computes it: render (``render_frame``), amodal, writes (the
        command's own ``_write_frame``: EXR, preview, labelled preview, labels JSON); labels (``write_files``
        alone, timed apart: the labels' share of the writes) and the amodal counts."""
        out, t = {}, time.perf_counter()
        kept = {}
        layers = self.fr.render_frame(self.scene, self.entry, self.W, self.H, keep=kept)
        out["render_ms"] = 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        if self.amodal_mode == "tree":
            amodal = self.fr.frame_amodal(self.scene, self.entry, self.W, self.H, kept)
        else:
            amodal = self.fr.amodal_pixels(self.scene, self.entry, self.W, self.H, projection=kept["projection"])
        out["amodal_ms"] = 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        self.command._write_frame(self.labelling, 0, layers, amodal, False, os.path.join(self.tmp, "f.exr"),
                                  os.path.join(self.tmp, "f.png"))
        out["writes_ms"] = 1e3 * (time.perf_counter() - t)
        t = time.perf_counter()
        self.labelling.write_files(0, layers, amodal)
        out["labels_ms"] = 1e3 * (time.perf_counter() - t)
        out["total_ms"] = out["render_ms"] + out["amodal_ms"] + out["writes_ms"]
        out["amodal"] = [int(v) for v in amodal]
        return out

    def alone(self) -> dict:
        """ms of the render alone (one asset, no labels) and its files."""
        t = time.perf_counter()
        layers = self.fr.render_frame(self.alone_scene, self.entry, self.W, self.H)
        out = {"render_ms": 1e3 * (time.perf_counter() - t)}
        t = time.perf_counter()
        self._files(layers)
        out["files_ms"] = 1e3 * (time.perf_counter() - t)
        out["total_ms"] = out["render_ms"] + out["files_ms"]
        return out

    def close(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)


def worker_main(argv) -> int:
    """``--worker --tree DIR --job J --data NPZ``: imports ``backend`` from DIR, then answers one JSON line per
    request line: {"task": "frame" | "alone"} -> that method's dict; {"task": "quit"} ends."""
    p = argparse.ArgumentParser()
    p.add_argument("--worker", action="store_true")
    p.add_argument("--tree", required=True)
    p.add_argument("--job", required=True)
    p.add_argument("--data", required=True)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--device", default="cpu")
    args = p.parse_args(argv)
    reply = os.fdopen(os.dup(1), "w")  # standard output is the reply channel; anything printed goes to stderr
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    sys.path[:] = [os.path.abspath(args.tree)] + [q for q in sys.path if os.path.abspath(q or ".") != HERE]
    import backend  # noqa: F401  (the tree's own package first)
    import numba
    import torch

    torch.set_num_threads(args.threads)
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    work = FrameWork(args.job, args.data, device=args.device)
    work.frame()  # the kernels loaded (or compiled) before any timing
    work.alone()
    reply.write(json.dumps({"ready": True, "tree": os.path.abspath(backend.__file__),
                            "amodal": work.amodal_mode}) + "\n")
    reply.flush()
    for line in sys.stdin:
        task = json.loads(line)["task"]
        if task == "quit":
            break
        reply.write(json.dumps(work.frame() if task == "frame" else work.alone()) + "\n")
        reply.flush()
    work.close()
    return 0


class Worker:
    def __init__(self, tree: str, job: str, data: str, threads: int, device: str = "cpu"):
        self.proc = subprocess.Popen([sys.executable, os.path.abspath(__file__), "--worker", "--tree", tree,
                                      "--job", job, "--data", data, "--threads", str(threads), "--device", device],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=tree)
        self.hello = json.loads(self.proc.stdout.readline())

    def ask(self, task: str) -> dict:
        self.proc.stdin.write(json.dumps({"task": task}) + "\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())

    def close(self) -> None:
        self.proc.stdin.write(json.dumps({"task": "quit"}) + "\n")
        self.proc.stdin.flush()
        self.proc.wait(timeout=60)


def summarise(frames: list, alones: list) -> dict:
    """Medians of each part over the rounds, the labels' share and the ratio frame / alone."""
    med = lambda rows, k: statistics.median(r[k] for r in rows)  # noqa: E731
    out = {k: med(frames, k) for k in ("render_ms", "amodal_ms", "writes_ms", "labels_ms", "total_ms")}
    out.update(alone_render_ms=med(alones, "render_ms"), alone_files_ms=med(alones, "files_ms"),
               alone_total_ms=med(alones, "total_ms"))
    out["labels_share"] = (out["total_ms"] - out["alone_total_ms"]) / out["total_ms"]
    out["ratio_to_alone"] = out["total_ms"] / out["alone_total_ms"]
    out["amodal"] = frames[-1]["amodal"]
    return out


def frame_part(trees: dict, job: str, data: str, rounds: int, threads: int, device: str = "cpu") -> dict:
    """Both trees' workers, their requests interleaved round by round (the order alternating)."""
    workers = {name: Worker(tree, job, data, threads, device) for name, tree in trees.items()}
    rows = {name: {"frame": [], "alone": []} for name in trees}
    try:
        names = list(trees)
        for r in range(rounds):
            for name in (names if r % 2 == 0 else names[::-1]):
                rows[name]["frame"].append(workers[name].ask("frame"))
                rows[name]["alone"].append(workers[name].ask("alone"))
    finally:
        for w in workers.values():
            w.close()
    return {name: {**summarise(v["frame"], v["alone"]), "amodal_method": workers[name].hello["amodal"]}
            for name, v in rows.items()}


# -- the batch part --------------------------------------------------------------------------------------------

def make_variants(folder: str, n: int) -> str:
    """``n`` variants of the street at 128 x 72 in ``folder`` (bench/vary.py's spec); their batch list's path."""
    sys.path.insert(0, os.path.join(ROOT, "tests"))
    import render_scene
    from scpainter_blender.core.output_layout import VariationLayout
    from scpainter_blender.core.variation import spec as spec_mod, variants
    from scpainter_blender.street.dataset import ensure_street
    from tests_support import street_base_job

    street = ensure_street()
    lib = render_scene.car_library(os.path.join(folder, "cars"), 20000)
    base = os.path.join(folder, "base", "job.json")
    street_base_job(street, base)
    spec = spec_mod.VariationSpec(variants=n, seed=0, library=lib, resolution=(128, 72),
                                  shifts_m=(-3.0, -2.0, 0.0, 2.0, 3.0), lane_change_probability=0.2)
    variants.make_variants(base, spec, os.path.join(folder, "variants"), data_roots=(street.root,))
    return os.path.join(folder, "variants", VariationLayout.LIST)


def chunk_lists(listing: str, chunks: int) -> list:
    """The list split into ``chunks`` lists (each keeping the data-root lines, the jobs as absolute paths)."""
    root = os.path.dirname(listing)
    with open(listing) as f:
        lines = f.read().splitlines()
    head = [x for x in lines if not x.strip() or x.startswith(("#", "data-root:"))]
    head = [x if not x.startswith("data-root:") else
            "data-root: " + os.path.normpath(os.path.join(root, x.split(":", 1)[1].strip())) for x in head]
    jobs = [os.path.join(root, x) for x in lines if x.strip() and not x.startswith(("#", "data-root:"))]
    out = []
    for k in range(chunks):
        part = jobs[k * len(jobs) // chunks:(k + 1) * len(jobs) // chunks]
        path = os.path.join(root, f"chunk{k}.txt")
        with open(path, "w") as f:
            f.write("\n".join(head + part) + "\n")
        out.append(path)
    return out


def run_batch(tree: str, listing: str) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    t = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "backend", "batch", "--list", listing, "--command", "render",
                           "--device", "cpu", "--shard", "0/1"], cwd=tree, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    done = [json.loads(x) for x in proc.stdout.splitlines() if x.startswith("{") and '"done"' in x]
    if not done:
        raise SystemExit(f"batch in {tree} ended without a summary:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")
    items = done[-1]["items"]
    failed = [i for i in items if i["status"] != "ok"]
    if failed:
        raise SystemExit(f"batch in {tree}: {len(failed)} jobs failed: {failed[0]}")
    return {"wall_s": wall, "seconds": [i["seconds"] for i in items]}


def batch_part(trees: dict, n: int, chunks: int, folder: str) -> dict:
    lists = {name: chunk_lists(make_variants(os.path.join(folder, name), n), chunks) for name in trees}
    runs = {name: [] for name in trees}
    names = list(trees)
    for k in range(chunks):
        for name in (names if k % 2 == 0 else names[::-1]):
            runs[name].append(run_batch(trees[name], lists[name][k]))
    out = {}
    for name, rs in runs.items():
        secs = [s for r in rs for s in r["seconds"]]
        q = statistics.quantiles(secs, n=4) if len(secs) > 1 else [secs[0]] * 3
        out[name] = {"variants": len(secs), "per_variant_s": statistics.mean(secs),
                     "median_s": q[1], "q1_s": q[0], "q3_s": q[2], "first_s": [r["seconds"][0] for r in rs],
                     "busy_s": sum(secs), "wall_s": sum(r["wall_s"] for r in rs), "chunks": len(rs)}
    return out


# -- main ------------------------------------------------------------------------------------------------------

def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", ROOT, *args], capture_output=True, text=True)


def before_revision(rev: str | None) -> tuple[str | None, str]:
    """(the commit of ``rev``, None for a problem; the problem or ""): ``rev`` None is where this branch left
    ``main`` (their merge base: this branch's changes alone, not what ``main`` merged since). A revision git does
    not know, or whose tree is HEAD's (``main`` itself, or a branch already merged: its merge base is HEAD), is a
    problem: the run would compare the code with itself."""
    what = f"--before {rev}" if rev else "the default before (git merge-base main HEAD)"
    got = _git("rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}") if rev else _git("merge-base", "main", "HEAD")
    commit = got.stdout.strip()
    if got.returncode or not commit:
        return None, f"{what}: git finds no such commit here ({got.stderr.strip() or 'no output'})"
    trees = [_git("rev-parse", f"{c}^{{tree}}").stdout.strip() for c in (commit, "HEAD")]
    if trees[0] == trees[1]:
        return None, (f"{what} is {commit[:12]}, whose code is HEAD's: the run would compare the code with itself; "
                      "name the code to compare with: --before REV (e.g. the commit before the change measured) "
                      "or --before-tree DIR")
    return commit, ""


def before_tree(folder: str, commit: str) -> str:
    """A copy (``git archive``) of ``commit`` (``before_revision``'s) in ``folder``/before."""
    dest = os.path.join(folder, "before")
    os.makedirs(dest, exist_ok=True)
    archive = subprocess.run(["git", "-C", ROOT, "archive", commit], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", dest], input=archive, check=True)
    return dest


def smoke(out_dir: str) -> dict:
    """The frame part in this process at tiny sizes: "before" = the render per car, "after" = the kernel's walk."""
    sys.path.insert(0, ROOT)
    with tempfile.TemporaryDirectory() as tmp:
        job, data = make_frame_inputs(tmp, 20_000, 3_000, 128, 72)
        res = {}
        for name, mode in (("before", "second_render"), ("after", "tree")):
            work = FrameWork(job, data, amodal=mode)
            work.frame()
            work.alone()
            res[name] = {**summarise([work.frame() for _ in range(2)], [work.alone() for _ in range(2)]),
                         "amodal_method": work.amodal_mode}
            work.close()
    return {"frame": res, "batch": None, "size": [128, 72], "points": 20_000, "gaussians": 3_000}


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--worker" in argv:
        return worker_main(argv)
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--smoke", action="store_true")
    p.add_argument("--out", default=os.path.join(ROOT, "bench", "results"))
    before = p.add_mutually_exclusive_group()
    before.add_argument("--before-tree", default=None, help="the tree to compare with (a folder)")
    before.add_argument("--before", default=None, metavar="REV",
                        help="the git revision to compare with (default: merge-base main HEAD; refused when its "
                             "code is HEAD's)")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--points", type=int, default=1_000_000)
    p.add_argument("--gaussians", type=int, default=100_000)
    p.add_argument("--resolution", default="1024x576")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--device", default="cpu", help="the frame part's device (cuda: amodal_pixels renders each car "
                                                   "again there, the kernel's count is the CPU's)")
    p.add_argument("--variants", type=int, default=40, help="variants per tree (0: no batch part)")
    p.add_argument("--chunks", type=int, default=2, help="batch processes per tree, alternating trees")
    args = p.parse_args(argv)
    commit = None
    if not args.smoke and not args.before_tree:
        commit, problem = before_revision(args.before)
        if problem:
            p.error(problem)
    if args.smoke:
        result = smoke(args.out)
    else:
        W, H = (int(v) for v in args.resolution.split("x"))
        work = tempfile.mkdtemp(prefix="labels_cost_")
        try:
            trees = {"before": os.path.abspath(args.before_tree or before_tree(work, commit)), "after": ROOT}
            sys.path.insert(0, ROOT)
            job, data = make_frame_inputs(work, args.points, args.gaussians, W, H)
            result = {"frame": frame_part(trees, job, data, args.rounds, args.threads, args.device),
                      "device": args.device, "size": [W, H],
                      "points": args.points, "gaussians": args.gaussians, "rounds": args.rounds}
            result["batch"] = (batch_part(trees, args.variants, args.chunks, work) if args.variants else None)
            result["trees"] = trees
            result["before_commit"] = commit
        finally:
            shutil.rmtree(work, ignore_errors=True)
    result["machine"] = {"cpus": os.cpu_count(), "python": platform.python_version()}
    f, b = result["frame"], result.get("batch")
    result["amodal_equal"] = f["before"]["amodal"] == f["after"]["amodal"]
    result["targets"] = {"labels_share_le_0.10": f["after"]["labels_share"] <= 0.10,
                         "ratio_to_alone_le_1.3": f["after"]["ratio_to_alone"] <= 1.3}
    if b:
        result["batch_speedup"] = b["before"]["per_variant_s"] / b["after"]["per_variant_s"]
        result["batch_wall_speedup"] = b["before"]["wall_s"] / b["after"]["wall_s"]
        result["batch_median_speedup"] = b["before"]["median_s"] / b["after"]["median_s"]
        result["targets"]["batch_speedup_ge_1.5"] = result["batch_speedup"] >= 1.5
    W, H = result["size"]
    print(f"\nframe: {result['points']:,} points, 3 cars ({result['gaussians']:,} Gaussians), {W}x{H} "
          f"(ms, medians)")
    cols = ("render_ms", "amodal_ms", "writes_ms", "labels_ms", "total_ms", "alone_total_ms")
    print(f"{'tree':>7} " + " ".join(f"{c[:-3]:>9}" for c in cols) + f" {'labels %':>9} {'ratio':>6}  amodal")
    for name in ("before", "after"):
        r = f[name]
        print(f"{name:>7} " + " ".join(f"{r[c]:>9.1f}" for c in cols)
              + f" {100 * r['labels_share']:>9.1f} {r['ratio_to_alone']:>6.2f}  {r['amodal']} ({r['amodal_method']})")
    print(f"amodal counts equal before/after: {result['amodal_equal']}")
    if b:
        print(f"\nbatch: {b['after']['variants']} variants x 16 frames at 128x72 per tree, one process per chunk")
        print(f"{'tree':>7} {'s/variant':>10} {'median':>7} {'q1':>6} {'q3':>6} {'busy s':>8} {'wall s':>8}")
        for name in ("before", "after"):
            r = b[name]
            print(f"{name:>7} {r['per_variant_s']:>10.3f} {r['median_s']:>7.3f} {r['q1_s']:>6.3f} {r['q3_s']:>6.3f} "
                  f"{r['busy_s']:>8.1f} {r['wall_s']:>8.1f}")
        print(f"speed-up per variant {result['batch_speedup']:.2f}x (medians {result['batch_median_speedup']:.2f}x), "
              f"wall {result['batch_wall_speedup']:.2f}x")
    print("targets:", ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in result["targets"].items()))
    os.makedirs(args.out, exist_ok=True)
    from scpainter_blender.core import outputs

    outputs.write_json(os.path.join(args.out, "labels_cost.json"), result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
