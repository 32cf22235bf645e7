"""Loading a 1 M-Gaussian INRIA PLY: our reader against INRIA's own loader (plyfile) and Open3D, side by side.

    .venv/bin/python bench/ply_load.py [--gaussians 1000000] [--rounds 5] [--baseline ebbfdbb] [--out bench/results]
    .venv/bin/python bench/ply_load.py --smoke --out /tmp/x    # 2,000 Gaussians, one round, no baseline

The file: ``--gaussians`` random Gaussians of SH degree 3 with normals, as INRIA's ``save_ply`` writes them (62
float properties, ~250 MB), generated in a temp folder and read from the page cache (a warm-up read first). Each
round times every loader once, in an order that rotates between rounds; the table gives the median and the best
of ``--rounds`` rounds:

ours read            ``core.splats.reader.read``: the raw float32 values (``GaussianPly``)
ours load            ``core.splats.reader.load`` = decode(read): what the backend and the import use
ours load (before)   the same call in the tree of git revision ``--baseline`` (extracted with ``git archive``,
                     timed in a process of its own on the same file; leave out with ``--baseline ''``)
plyfile INRIA        graphdeco-inria/gaussian-splatting ``GaussianModel.load_ply`` without its torch tensors:
                     ``PlyData.read`` and each property copied into float64 arrays (raw values, not activated)
plyfile + decode     the same, then the activations ``load`` applies (exp, sigmoid, normalised quaternions, SH
                     coefficient-major): the values ``load`` returns
open3d t.io          ``open3d.t.io.read_point_cloud``: every property as a tensor attribute (raw values; Open3D's
                     legacy ``io.read_point_cloud`` reads only positions, normals and colours, so it is not compared)

It also checks the values agree: plyfile's and Open3D's raw values equal ``read``'s, and plyfile + decode equals
``load`` within float32 rounding (it activates in float64 without the row checks). plyfile is a benchmark-only
dependency (``.venv/bin/pip install --no-deps 'plyfile==1.0.3'``: 1.1 needs numpy 2, the project pins 1.26);
without it those rows are left out. Prints a table and writes bench/results/ply_load.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

import numpy as np  # noqa: E402

from scpainter_blender.core import outputs  # noqa: E402
from scpainter_blender.core.splats import gaussians as G  # noqa: E402
from scpainter_blender.core.splats import inria, reader  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)


def make_file(path: str, n: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    ply = G.GaussianPly(xyz=rng.normal(0, 5, (n, 3)).astype(np.float32),
                        f_dc=rng.normal(0, 1, (n, 3)).astype(np.float32),
                        f_rest=rng.normal(0, 0.1, (n, 3, 15)).astype(np.float32),
                        opacity=rng.normal(0, 2, n).astype(np.float32),
                        scale=rng.normal(-4, 1, (n, 3)).astype(np.float32),
                        rot=rng.normal(0, 1, (n, 4)).astype(np.float32),
                        extra={k: np.zeros(n, np.float32) for k in ("nx", "ny", "nz")})
    inria.write_ply(path, ply)


def plyfile_inria(path):
    """INRIA's ``GaussianModel.load_ply`` (gaussian-splatting ``scene/gaussian_model.py``) up to its numpy arrays."""
    from plyfile import PlyData

    plydata = PlyData.read(path)
    v = plydata.elements[0]
    xyz = np.stack((np.asarray(v["x"]), np.asarray(v["y"]), np.asarray(v["z"])), axis=1)
    opacities = np.asarray(v["opacity"])[..., np.newaxis]
    features_dc = np.zeros((xyz.shape[0], 3, 1))
    for i in range(3):
        features_dc[:, i, 0] = np.asarray(v[f"f_dc_{i}"])
    extra = sorted([p.name for p in v.properties if p.name.startswith("f_rest_")], key=lambda x: int(x.split("_")[-1]))
    features_extra = np.zeros((xyz.shape[0], len(extra)))
    for i, name in enumerate(extra):
        features_extra[:, i] = np.asarray(v[name])
    features_extra = features_extra.reshape((xyz.shape[0], 3, len(extra) // 3))
    names = sorted([p.name for p in v.properties if p.name.startswith("scale_")], key=lambda x: int(x.split("_")[-1]))
    scales = np.zeros((xyz.shape[0], len(names)))
    for i, name in enumerate(names):
        scales[:, i] = np.asarray(v[name])
    names = sorted([p.name for p in v.properties if p.name.startswith("rot")], key=lambda x: int(x.split("_")[-1]))
    rots = np.zeros((xyz.shape[0], len(names)))
    for i, name in enumerate(names):
        rots[:, i] = np.asarray(v[name])
    return xyz, features_dc, features_extra, opacities, scales, rots


def plyfile_decoded(path):
    """``plyfile_inria`` and the activations ``core.splats.gaussians.decode`` applies (INRIA's own getters)."""
    xyz, dc, rest, op, sc, rot = plyfile_inria(path)
    return {"means": xyz, "scales": np.exp(sc), "opacities": 1.0 / (1.0 + np.exp(-op[:, 0])),
            "quats": rot / np.linalg.norm(rot, axis=1, keepdims=True),
            "sh": np.concatenate([dc.transpose(0, 2, 1), rest.transpose(0, 2, 1)], axis=1)}


def open3d_t(path):
    import open3d as o3d

    return o3d.t.io.read_point_cloud(path)


def check_values(path) -> dict:
    """Whether the other loaders' values agree with ours (see the module docstring)."""
    raw, g = reader.read(path), reader.load(path)
    out = {}
    try:
        xyz, dc, rest, op, sc, rot = plyfile_inria(path)
        out["plyfile raw == read"] = bool(
            np.array_equal(xyz, raw.xyz) and np.array_equal(dc[:, :, 0], raw.f_dc) and np.array_equal(rest, raw.f_rest)
            and np.array_equal(op[:, 0], raw.opacity) and np.array_equal(sc, raw.scale) and np.array_equal(rot, raw.rot))
        d = plyfile_decoded(path)
        out["plyfile + decode ~ load (max abs diff)"] = max(
            float(np.abs(d[k].astype(np.float32) - getattr(g, k)).max()) for k in d)
    except ImportError:
        pass
    pc = open3d_t(path)
    out["open3d raw == read"] = bool(
        np.array_equal(pc.point["positions"].numpy(), raw.xyz)
        and all(np.array_equal(pc.point[f"f_rest_{i}"].numpy()[:, 0], raw.f_rest.reshape(len(raw), -1)[:, i])
                for i in range(45))
        and np.array_equal(pc.point["opacity"].numpy()[:, 0], raw.opacity))
    return out


BEFORE_WORKER = r"""
import json, statistics, sys, time
sys.path.insert(0, sys.argv[1])
from scpainter_blender.core.splats import reader
path, rounds = sys.argv[2], int(sys.argv[3])
reader.load(path)
ts = []
for _ in range(rounds):
    t = time.perf_counter(); reader.load(path); ts.append(time.perf_counter() - t)
print(json.dumps(ts))
"""


def before_times(rev: str, path: str, rounds: int):
    """``reader.load`` timed in git revision ``rev``'s tree (a process of its own); (times, commit)."""
    import io
    import tarfile

    sha = subprocess.run(["git", "-C", ROOT, "rev-parse", "--verify", rev + "^{commit}"], capture_output=True,
                         text=True, check=True).stdout.strip()
    with tempfile.TemporaryDirectory() as tree:
        tar = subprocess.run(["git", "-C", ROOT, "archive", "--format=tar", sha, "scpainter_blender"],
                             capture_output=True, check=True).stdout
        with tarfile.open(fileobj=io.BytesIO(tar)) as t:
            t.extractall(tree, filter="data")
        out = subprocess.run([sys.executable, "-c", BEFORE_WORKER, tree, path, str(rounds)], capture_output=True,
                             text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1]), sha


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--gaussians", type=int, default=1_000_000)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--baseline", default="ebbfdbb", help="git revision of 'ours load (before)' ('' leaves it out)")
    bench_cli.add_smoke_and_out(p, "2,000 Gaussians, one round, no baseline")
    args = p.parse_args(argv)
    if args.smoke:
        args.gaussians, args.rounds, args.baseline = 2000, 1, ""
    args.out = bench_cli.json_path(args.out, "ply_load")

    loaders = {"ours read": reader.read, "ours load": reader.load}
    try:
        import plyfile  # noqa: F401

        loaders.update({"plyfile INRIA": plyfile_inria, "plyfile + decode": plyfile_decoded})
    except ImportError:
        print("plyfile is not installed: its rows are left out (see the docstring)")
    loaders["open3d t.io"] = open3d_t

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "gaussians.ply")
        make_file(path, args.gaussians)
        size = os.path.getsize(path)
        checks = check_values(path)  # also the warm-up read of every loader
        times = {k: [] for k in loaders}
        names = list(loaders)
        for r in range(args.rounds):
            for k in names[r % len(names):] + names[:r % len(names)]:
                t = time.perf_counter()
                loaders[k](path)
                times[k].append(time.perf_counter() - t)
        before = None
        if args.baseline:
            times["ours load (before)"], before = before_times(args.baseline, path, args.rounds)

    rows = {k: {"median_s": statistics.median(v), "best_s": min(v), "times_s": v} for k, v in times.items()}
    others = [k for k in rows if not k.startswith("ours")]
    fastest = min(others, key=lambda k: rows[k]["median_s"])
    ratio = rows["ours load"]["median_s"] / rows[fastest]["median_s"]
    print(f"\n{args.gaussians:,} Gaussians, SH degree 3, {size / 2**20:.0f} MiB, {os.cpu_count()} CPUs, "
          f"numpy {np.__version__}")
    print(f"{'loader':22s} {'median ms':>10s} {'best ms':>9s} {'x fastest other':>16s}")
    for k, v in rows.items():
        print(f"{k:22s} {v['median_s'] * 1e3:10.0f} {v['best_s'] * 1e3:9.0f} "
              f"{v['median_s'] / rows[fastest]['median_s']:16.2f}")
    print(f"ours load / {fastest}: {ratio:.2f}x (target <= 1.2)")
    for k, v in checks.items():
        print(f"{k}: {v}")
    result = {"gaussians": args.gaussians, "sh_degree": 3, "file_bytes": size, "rounds": args.rounds,
              "cpus": os.cpu_count(), "machine": platform.processor() or platform.machine(), "numpy": np.__version__,
              "baseline": before, "loaders": rows, "fastest_other": fastest, "ours_load_over_fastest": ratio,
              "checks": checks}
    outputs.write_json(args.out, result)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
