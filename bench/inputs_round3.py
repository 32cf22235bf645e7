"""Issue 42's inputs from the field, each through the product's entry point, one row per case: what happens.

    .venv/bin/python bench/inputs_round3.py --label before|after [--out DIR] [--json PATH] [--code DIR] [--smoke]

Every input is made here, in a temporary folder, with the truth kept (no network): a losslessly trimmed MP4 (an
edit list, written with PyAV) through ``backend.train.camera_frames`` (the count ``clip.load`` compares with the
predictions, and the frames decoded); SPZ files (the test fixtures' writer: a v3 stream with an extension record
after the attributes; a v4 file declaring RFU, as Niantic's packer stores a car) through
``core.splats.reader.read``; damaged Draco glTFs (the extension's attribute ids swapped; a face index damaged in the
payload) through ``backend.mesh.load.load_mesh``; a Ray dashboard URL in ``--ray`` and in ``RAY_ADDRESS`` through
``python -m backend batch`` (in this process: ``backend.__main__.main``); a car library holding a damaged file, and a
9.2 x 5.8 m cloud, through ``core.variation.library``.

Outcomes: ``correct`` (accepted, values as the truth), ``refused`` (an InputError: exit 2; the detail quotes it),
``silent_wrong`` (accepted, values wrong), ``internal`` (exit 1, "an internal error"), ``traceback`` (an uncaught
exception), ``unsupported`` (the option does not exist). ``expected`` is what the issue asks for, ``names`` what the
refusal must name; ``ok`` whether both were met.

``--code DIR`` imports the product (``scpainter_blender``, ``backend``) from DIR instead of this checkout: the
before table comes from ``mkdir DIR && git archive main scpainter_blender backend | tar -x -C DIR`` (the test
fixtures still come from this checkout). Not a test: prints a table and writes the JSON (default
bench/results/inputs_round3[_before].json).
"""

import argparse
import contextlib
import gzip
import io
import json
import os
import struct
import sys
import tempfile
import time
import traceback

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _setup_path(code: str | None) -> None:
    for p in (os.path.join(ROOT, "tests"), ROOT):
        sys.path.insert(0, p)
    if code:
        sys.path.insert(0, os.path.abspath(code))


def _is_input_error(e) -> bool:
    from scpainter_blender.core import errors

    return isinstance(e, errors.InputError)


# -- the cases: each returns (outcome, detail, text the refusal said) ---------------------------------------------

def mp4_edit_list(tmp):
    """12 coded frames, the edit list plays 2..9 (``ffmpeg -ss -t -c copy``): the count and the frames shown."""
    from backend.train import camera_frames as cf
    from tests.backend.train.test_camera_frames_editlist import trimmed_copy
    from tests.backend.train.test_camera_frames_rotation import write_video

    frames = np.random.default_rng(0).integers(0, 256, (12, 24, 40, 3), dtype=np.uint8)
    write_video(os.path.join(tmp, "full.mp4"), frames)
    trimmed_copy(os.path.join(tmp, "full.mp4"), os.path.join(tmp, "trim.mp4"), head=2, keep=8)
    count, _ = cf.probe_video(os.path.join(tmp, "trim.mp4"), ValueError)
    if count != 8:  # clip.load compares this count with the predictions' 8 frames
        return "refused", f"counted {count} frames where players show 8: a clip of 8 predictions is refused", ""
    got = np.stack([rgb for _, rgb in cf.decode_video(os.path.join(tmp, "trim.mp4"), 8, ValueError)])
    if np.array_equal(got, frames[2:10]):
        return "correct", "8 frames counted, frames 2-9 decoded exactly", ""
    return "silent_wrong", "8 frames counted but not the ones shown", ""


def _spz_cloud():
    from tests.core.splats import splat_fixtures as F

    ply = F.random_ply(N=200, degree=0, seed=3)
    ply.xyz = (np.rint(ply.xyz * np.array([1.8, 1.5, 4.6]) / 6 * 4096) / 4096).astype(np.float32)  # a car, RUB
    return F, ply


def spz_v3_extension(tmp):
    from scpainter_blender.core.splats import reader

    F, ply = _spz_cloud()
    plain, ext = os.path.join(tmp, "plain.spz"), os.path.join(tmp, "ext.spz")
    open(plain, "wb").write(gzip.compress(F.spz_body(ply, 3)))
    orbit = F.spz_extension(0xADBE0002, np.array([-0.5, 0.5, 1.0], "<f4").tobytes())
    open(ext, "wb").write(gzip.compress(F.spz_body(ply, 3, flags=2, extensions=orbit)))
    a, b = reader.read(plain), reader.read(ext)
    ok = np.array_equal(a.xyz, b.xyz) and np.array_equal(a.rot, b.rot)
    return ("correct" if ok else "silent_wrong"), "read as the file without the record" if ok else "values differ", ""


def spz_v4_coordinate_system(tmp):
    """The car stored declaring RFU (value 12) as Niantic's packer stores it: (x, y, z) -> (x, -z, y)."""
    from scpainter_blender.core.splats import reader

    F, ply = _spz_cloud()
    plain, rfu = os.path.join(tmp, "plain4.spz"), os.path.join(tmp, "rfu.spz")
    open(plain, "wb").write(F.spz_v4(ply))
    turned = F.random_ply(N=len(ply), degree=0)
    turned.xyz = np.stack([ply.xyz[:, 0], -ply.xyz[:, 2], ply.xyz[:, 1]], 1)
    turned.rot, turned.scale, turned.opacity, turned.f_dc = ply.rot, ply.scale, ply.opacity, ply.f_dc
    open(rfu, "wb").write(F.spz_v4(turned, flags=2, extensions=F.spz_coordinate_system(12)))
    a, b = reader.read(plain), reader.read(rfu)
    if np.array_equal(a.xyz, b.xyz):
        return "correct", "the same car as the undeclared file", ""
    extent = b.xyz.max(0) - b.xyz.min(0)
    return "silent_wrong", f"turned: extent (x, y, z) {np.round(extent, 2).tolist()} m, the car's length on y", ""


def _draco_quad(tmp):
    from tests.backend.mesh.test_gltf import quad_gltf

    path = quad_gltf(tmp, "quad.gltf", draco=True)
    with open(path) as f:
        return path, json.load(f)


def draco_ids_swapped(tmp):
    from backend.mesh import load

    path, tree = _draco_quad(tmp)
    ext = tree["meshes"][0]["primitives"][0]["extensions"]["KHR_draco_mesh_compression"]
    ids = ext["attributes"]
    ext["attributes"] = {"POSITION": ids["TEXCOORD_0"], "TEXCOORD_0": ids["POSITION"]}
    with open(path, "w") as f:
        json.dump(tree, f)
    load.load_mesh(path)
    return "silent_wrong", "loaded", ""


def draco_face_index(tmp):
    from backend.mesh import load
    from tests.backend.mesh.test_gltf import QUAD_FACES

    path, tree = _draco_quad(tmp)
    view = tree["bufferViews"][tree["meshes"][0]["primitives"][0]["extensions"]["KHR_draco_mesh_compression"]
                               ["bufferView"]]
    data = bytearray(open(os.path.join(tmp, "quad.bin"), "rb").read())
    payload = data[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]
    data[view["byteOffset"] + payload.find(QUAD_FACES.astype(np.uint8).tobytes()) + 5] = 0xFF
    open(os.path.join(tmp, "quad.bin"), "wb").write(bytes(data))
    load.load_mesh(path)
    return "silent_wrong", "loaded", ""


def _batch(tmp, *args, env=None):
    """``python -m backend batch JOB *args`` in this process: (exit code, last event)."""
    from backend.__main__ import main
    from tests_support import small_job

    job = small_job(os.path.join(tmp, "job"))
    out = io.StringIO()
    old = {k: os.environ.get(k) for k in (env or {})}
    os.environ.update(env or {})
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
            code = main(["batch", job, "--command", "render", "--device", "cpu", *args])
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    events = [json.loads(line) for line in out.getvalue().splitlines() if line.strip().startswith("{")]
    return code, (events[-1] if events else {})


def _batch_outcome(code, last):
    text = f"{last.get('field', '')}: {last.get('message', '')} ({last.get('hint', '')})"[:300]
    if code == 2:
        return "refused", text, text
    if code == 1:
        return "internal", text, text
    return "correct", f"exit {code}", ""


def ray_dashboard_option(tmp):
    os.environ.pop("RAY_ADDRESS", None)
    return _batch_outcome(*_batch(tmp, "--ray", "http://127.0.0.1:8265"))


def ray_dashboard_environment(tmp):
    return _batch_outcome(*_batch(tmp, "--ray", env={"RAY_ADDRESS": "http://127.0.0.1:8265"}))


def _library(tmp):
    from scpainter_blender.core import shapes
    from scpainter_blender.core.splats import gaussians as splats, inria

    lib = os.path.join(tmp, "cars")
    os.makedirs(lib)
    shapes.save_as_amodal3r(os.path.join(lib, "blue.ply"), shapes.procedural_car_gaussians(count=2000, seed=7))
    open(os.path.join(lib, "broken.spz"), "wb").write(b"\x1f\x8b" + bytes(40))
    g = shapes.procedural_car_gaussians(count=2000, seed=1)
    k = (np.array([5.8, 9.2, 1.5]) / (g.means.max(0) - g.means.min(0))).astype(np.float32)
    inria.write_ply(os.path.join(tmp, "wide.ply"), splats.encode(splats.Gaussians(g.means * k, g.scales, g.quats,
                                                                                  g.opacities, g.sh)))
    return lib


def vary_bad_file(tmp):
    from scpainter_blender.core.variation import library

    library.load_library(_library(tmp), os.path.join(tmp, "cache"))
    return "silent_wrong", "a damaged file loaded", ""


def vary_skip_bad(tmp):
    from scpainter_blender.core.variation import library

    skipped = []
    try:
        cars = library.load_library(_library(tmp), os.path.join(tmp, "cache"), skipped=skipped)
    except TypeError as e:
        return "unsupported", f"no --skip-bad ({e})", ""
    names = [c.name for c in cars]
    ok = names == ["blue.ply"] and [os.path.basename(s["file"]) for s in skipped] == ["broken.spz"]
    return ("correct" if ok else "silent_wrong"), f"cars {names}, skipped {[s['reason'][:80] for s in skipped]}", ""


def vary_wide_cloud(tmp):
    from scpainter_blender.core.variation import library

    _library(tmp)
    a = library.load_asset(os.path.join(tmp, "wide.ply"), os.path.join(tmp, "cache"))
    return "silent_wrong", f"accepted as a car of {np.round(a.size_m, 2).tolist()} m (width, length, height)", ""


#: (name, function, expected outcome, what the refusal must name)
CASES = (
    ("mp4 trimmed losslessly (edit list: 12 coded, 8 shown)", mp4_edit_list, "correct", None),
    ("spz v3 with an extension record after the attributes", spz_v3_extension, "correct", None),
    ("spz v4 declaring its coordinate system (RFU)", spz_v4_coordinate_system, "correct", None),
    ("glTF Draco: the extension's attribute ids swapped", draco_ids_swapped, "refused", "KHR_draco_mesh_compression"),
    ("glTF Draco: a face index damaged in the payload", draco_face_index, "refused", "KHR_draco_mesh_compression"),
    ("batch --ray http://127.0.0.1:8265 (the dashboard)", ray_dashboard_option, "refused", "--ray"),
    ("batch --ray, RAY_ADDRESS=http://127.0.0.1:8265", ray_dashboard_environment, "refused", "RAY_ADDRESS"),
    ("vary library holding a damaged file, no --skip-bad", vary_bad_file, "refused", "--skip-bad"),
    ("vary library holding a damaged file, --skip-bad", vary_skip_bad, "correct", None),
    ("vary library: a 9.2 x 5.8 m splat cloud", vary_wide_cloud, "refused", "wide"),
)


def run_case(name, fn, expected, must_name) -> dict:
    t = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        try:
            outcome, detail, said = fn(tmp)
        except Exception as e:  # the product's refusal (InputError) or a bug
            said = f"{e} ({getattr(e, 'hint', '') or ''})"
            outcome = "refused" if _is_input_error(e) else "traceback"
            detail = said[:300] if outcome == "refused" else traceback.format_exc()[-300:]
    names = must_name is None or must_name in said
    return {"case": name, "expected": expected, "names": must_name, "outcome": outcome,
            "ok": outcome == expected and names, "detail": detail, "seconds": round(time.perf_counter() - t, 3)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--label", default="after", help="before|after (names the default JSON)")
    p.add_argument("--json", help="where to write the rows (default inputs_round3[_before].json in --out)")
    p.add_argument("--code", help="import the product from this folder (the before table)")
    sys.path.insert(0, os.path.join(ROOT, "bench"))
    import bench_cli  # bench/, the script's folder (argparse only: the product is imported after --code)

    bench_cli.add_smoke_and_out(p, "the same ten cases: they take seconds")
    args = p.parse_args(argv)
    _setup_path(args.code)
    rows = [run_case(*case) for case in CASES]
    for r in rows:
        print(f"{'ok ' if r['ok'] else 'NO '} {r['outcome']:<12} (want {r['expected']:<8}) {r['case']}: "
              f"{r['detail'][:150]}")
    print(f"{sum(r['ok'] for r in rows)} of {len(rows)} cases as the issue asks ({args.label})")
    out = args.json or os.path.join(args.out, f"inputs_round3{'_before' if args.label == 'before' else ''}.json")
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    with open(out, "w") as f:
        json.dump({"label": args.label, "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
