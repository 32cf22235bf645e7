"""Every input kind of issue 13 through the add-on's real import operators, one row each: what happens.

    .venv/bin/python bench/input_kinds.py [--out bench/results] [--realdata DIR] [--smoke]

Synthetic files are written here with numpy alone (the VGGT cases on an analytic scene, so ``world_points`` is
the truth), real ones are read from ``../shared/realdata`` (PROVENANCE.md there; skipped when absent). The same
script run on an older checkout gives the "before" column of the closing note. Not a test: it prints a table and
saves a JSON (``--out DIR``, or a path ending in .json). ``--smoke``: the synthetic files alone, the mesh car
converted to 5,000 Gaussians. It imports bpy with a private user folder: run it in a process of its own.
"""

import argparse
import os
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))

from scpainter_blender.core import outputs  # noqa: E402
import bench_cli  # noqa: E402  (bench/, the script's folder)
from scpainter_blender.scene import keys, kinds  # noqa: E402
from tools import blender_env  # noqa: E402


def analytic_clip(S=3, H=48, W=64, seed=0):
    """A road plane and a wall seen by a camera driving forward: VGGT-layout arrays with exact world_points."""
    from scpainter_blender.core.geometry import cameras, unproject
    from scpainter_blender.core.vggt import predictions as vggt

    rng = np.random.default_rng(seed)
    K = np.array([[50.0, 0, W / 2], [0, 50.0, H / 2], [0, 0, 1]])
    w2c = np.tile(np.eye(4), (S, 1, 1))
    for i in range(S):
        w2c[i, :3, :3] = cameras.quaternion_to_rotation(np.array([1.0, 0.0, 0.02 * i, 0.0]))
        w2c[i, :3, 3] = -w2c[i, :3, :3] @ np.array([0.05 * i, 0.0, 0.4 * i])
    depth = np.empty((S, H, W))
    rows, cols = np.mgrid[0:H, 0:W]
    for i in range(S):  # ray/plane: road y = 1 (OpenCV y down) and a wall z = 8
        R, t = w2c[i, :3, :3], w2c[i, :3, 3]
        c = -R.T @ t
        rays = np.stack([(cols - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones_like(cols, float)], -1)
        d_world = rays @ R  # R^T applied to row vectors
        s_road = np.where(d_world[..., 1] > 1e-6, (1.0 - c[1]) / np.maximum(d_world[..., 1], 1e-6), np.inf)
        s_wall = (8.0 - c[2]) / d_world[..., 2]
        depth[i] = np.minimum(s_road, s_wall)
    Kv = vggt.ours_K_to_vggt(np.tile(K, (S, 1, 1)))
    wp = unproject.unproject_depth(depth, np.tile(K, (S, 1, 1)), w2c)
    images = rng.uniform(0.2, 0.8, (S, 3, H, W)).astype(np.float32)
    conf = (1.0 + rng.exponential(3.0, (S, H, W))).astype(np.float32)
    return dict(images=images, depth=depth, depth_conf=conf, extrinsic=w2c[:, :3], intrinsic_vggt=Kv,
                world_points=wp, world_points_conf=conf)


def write_vggt_cases(d):
    from scpainter_blender.core.geometry import cameras
    from scpainter_blender.core.vggt import npz as vggt_io

    base = analytic_clip()
    out = {}
    vggt_io.save_predictions(os.path.join(d, "vggt_ok.npz"), **base)
    out["VGGT demo file (world-to-camera)"] = "vggt_ok.npz"
    c2w = dict(base, extrinsic=cameras.rigid_inverse(cameras.as_matrix4(base["extrinsic"]))[:, :3])
    vggt_io.save_predictions(os.path.join(d, "vggt_c2w.npz"), **c2w)
    out["VGGT camera-to-world under 'extrinsic'"] = "vggt_c2w.npz"
    nan = dict(base, depth=base["depth"].copy())
    nan["depth"][1, 3:5, 7:9] = np.nan
    nan["depth"][2, 10, 10] = np.inf
    vggt_io.save_predictions(os.path.join(d, "vggt_nan.npz"), **nan)
    out["VGGT with 5 NaN/inf depth pixels"] = "vggt_nan.npz"
    one = {k: np.asarray(v[0], np.float32) for k, v in base.items()}
    np.savez(os.path.join(d, "vggt_one.npz"), images=one["images"], depth=one["depth"],
             depth_conf=one["depth_conf"], extrinsic=one["extrinsic"], intrinsic=one["intrinsic_vggt"])
    out["VGGT one frame, size-1 axes squeezed"] = "vggt_one.npz"
    pad = {k: np.array(v) for k, v in base.items()}
    H, W = pad["depth"].shape[1:]
    p = (W - H) // 2  # VGGT's "pad" mode: white bands to a square
    img = np.ones((3, 3, W, W), np.float32)
    img[:, :, p:p + H] = pad["images"]
    dep = np.full((3, W, W), 0.5)
    dep[:, p:p + H] = pad["depth"]
    cnf = np.full((3, W, W), 1.2, np.float32)
    cnf[:, p:p + H] = pad["depth_conf"]
    Kp = pad["intrinsic_vggt"].copy()
    Kp[:, 1, 2] += p
    vggt_io.save_predictions(os.path.join(d, "vggt_padded.npz"), img, dep, cnf, pad["extrinsic"], Kp)
    out["VGGT padded to a square (white bands)"] = "vggt_padded.npz"
    return out


def write_splat_cases(d):
    from scpainter_blender.core import shapes
    from scpainter_blender.core.splats import gaussians as splats, inria as splats_inria, reader as splats_io

    out = {}
    g = shapes.procedural_car_gaussians(count=3000, seed=4)
    path = os.path.join(d, "trellis_edge.ply")
    shapes.save_as_amodal3r(path, g)
    raw = splats_io.read_ply(path)
    raw.xyz *= np.float32(0.504 / np.abs(raw.xyz).max())
    splats_inria.write_ply(path, raw)
    out["TRELLIS car reaching ±0.504"] = "trellis_edge.ply"
    # .splat (antimatter15): position, linear scale (float32), RGBA, quaternion (uint8, w first)
    rgba = np.clip(np.concatenate([g.base_colors(), g.opacities[:, None]], 1) * 255, 0, 255).round().astype(np.uint8)
    q = np.clip(g.quats * 128 + 128, 0, 255).round().astype(np.uint8)
    rec = np.zeros(len(g), [("p", "<f4", 3), ("s", "<f4", 3), ("c", "u1", 4), ("q", "u1", 4)])
    rec["p"], rec["s"], rec["c"], rec["q"] = g.means, g.scales, rgba, q
    rec.tofile(os.path.join(d, "car.splat"))
    out[".splat (antimatter15)"] = "car.splat"
    # half floats in ushort slots, every float property
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3"]
    e = splats.encode(g)
    cols = np.concatenate([e.xyz, e.f_dc, e.opacity[:, None], e.scale, e.rot], 1).astype(np.float16)
    header = "ply\nformat binary_little_endian 1.0\nelement vertex %d\n%send_header\n" % (
        len(g), "".join(f"property ushort {n}\n" for n in names))
    with open(os.path.join(d, "half.ply"), "wb") as f:
        f.write(header.encode() + cols.view("<u2").tobytes())
    out["half floats in ushort slots"] = "half.ply"
    mixed = header.replace("property ushort x\n", "property float x\n")
    data = np.zeros(len(g), [("x", "<f4")] + [(n, "<u2") for n in names[1:]])
    with open(os.path.join(d, "mixed.ply"), "wb") as f:
        f.write(mixed.encode() + data.tobytes())
    out["ushort properties mixed with float"] = "mixed.ply"
    return out


def write_mesh_cases(d):
    import trimesh

    box = trimesh.creation.box(extents=(1.9, 4.5, 1.5))  # width x, length y, height z (Z up)
    box.visual.vertex_colors = np.tile([200, 30, 30, 255], (len(box.vertices), 1)).astype(np.uint8)
    box.apply_transform([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])  # OBJ files are Y up
    box.export(os.path.join(d, "cad_car.obj"))
    return {"OBJ car (vertex colours)": "cad_car.obj"}


REAL = {"INRIA PLY SH 3 (loaders.gl)": "3dgs/loadersgl_train-1000.ply",
        "INRIA PLY SH 0 (Mip-Splatting donut)": "3dgs/gshairlod_donut_fused.ply",
        "INRIA PLY SH 3 + extra property (SuperSplat)": "3dgs/supersplat_fruit_drops_minimal.ply",
        "SuperSplat compressed PLY": "compressed/olgelta_longheadpiece_scene.compressed.ply",
        "TRELLIS GLB (uanu2002)": "trellis/uanu2002_trellis_sample.glb",
        "TRELLIS GLB (harishreddy17)": "trellis/harishreddy17_trellis_sample.glb",
        "TRELLIS mesh PLY (T.ply)": "trellis/trellis_assets_T_mesh.ply"}


def run(op, path, **kw):
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    try:
        r = op(filepath=path, **kw)
    except RuntimeError as e:
        return "refused", str(e).strip().splitlines()[-1][:300]
    objs = [o for o in bpy.context.scene.objects if kinds.kind_of(o) is not None]
    facts = []
    for o in objs:
        k = kinds.kind_of(o)
        if k == kinds.POINTS:
            facts.append(f"{len(o.data.vertices):,} points")
        elif k == kinds.RECORDED_CAMERA:
            facts.append(f"camera {bpy.context.scene.render.resolution_x}x{bpy.context.scene.render.resolution_y}")
        elif k == kinds.GAUSSIAN_ASSET:
            s = np.array(o[keys.SIZE]) * np.array(o.scale)
            facts.append(f"{len(o.data.vertices):,} Gaussians, axes {o[keys.AXES]}, "
                         f"size {s[0]:.2f}x{s[1]:.2f}x{s[2]:.2f} (x y z)")
    return ("imported" if r == {"FINISHED"} else str(r)), "; ".join(facts)


def point_error(path):
    """How far the imported points (depth unprojected with 'extrinsic' as stored) are from world_points, median."""
    from scpainter_blender.core.geometry import unproject
    from scpainter_blender.core.vggt import npz as vggt_io

    try:
        with np.load(path, allow_pickle=False) as z:
            if "world_points" not in z.files:
                return None
            wp = z["world_points"].reshape(-1, 3).astype(np.float64)
        pred = vggt_io.load_predictions(path)
        ours = unproject.unproject_depth(pred.depth, pred.K, pred.world_to_camera).reshape(-1, 3)
        ok = np.isfinite(ours).all(1) & np.isfinite(wp).all(1)
        return float(np.median(np.linalg.norm(ours[ok] - wp[ok], axis=1)))
    except Exception:
        return None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realdata", default=os.path.join(ROOT, "..", "shared", "realdata"))
    bench_cli.add_smoke_and_out(ap, "the synthetic files alone, a mesh car of 5,000 Gaussians")
    args = ap.parse_args(argv)
    args.out = bench_cli.json_path(args.out, "input_kinds")
    work = tempfile.mkdtemp(prefix="scpainter-kinds-")
    blender_env.install_for_script(work)
    import bpy

    d = os.path.join(work, "inputs")
    os.makedirs(d)
    rows = []
    for kind, name in write_vggt_cases(d).items():
        status, facts = run(bpy.ops.scpainter.import_vggt, os.path.join(d, name), scale_mode="FACTOR")
        err = point_error(os.path.join(d, name))
        if status == "imported" and err is not None:
            facts += f"; depth points vs world_points: median {err:.3g} units"
        rows.append({"kind": kind, "status": status, "what": facts})
    cases = {**write_splat_cases(d), **write_mesh_cases(d)}
    cases.update({k: os.path.join(args.realdata, v) for k, v in REAL.items()
                  if not args.smoke and os.path.isfile(os.path.join(args.realdata, v))})
    for kind, name in cases.items():   # (--smoke: a mesh car of 5,000 Gaussians, not the default 200,000)
        status, facts = run(bpy.ops.scpainter.import_gaussians, os.path.join(d, name),
                            **({"mesh_count": 5000} if args.smoke else {}))
        rows.append({"kind": kind, "status": status, "what": facts})
    w = max(len(r["kind"]) for r in rows)
    for r in rows:
        print(f"{r['kind']:<{w}}  {r['status']:<9} {r['what']}")
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    outputs.write_json(args.out, {"checkout": ROOT, "rows": rows})


if __name__ == "__main__":
    main()
