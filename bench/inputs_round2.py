"""Issue 31's input classes, each through the product's stable entry points, one row per case: what happens.

    .venv/bin/python bench/inputs_round2.py --label before|after [--out DIR] [--realdata DIR] [--keep DIR] [--smoke]

Every input is generated here, in a temporary folder, from ground truth the generator keeps (no network):

* glTF mesh cars, through ``python -m backend mesh-asset IN --out OUT.ply --count 2000`` (a subprocess): a box
  whose every face maps, through the case's feature (KHR_texture_transform, texCoord 1, normalized integer UVs,
  KHR_mesh_quantization, KHR_draco_mesh_compression via DracoPy, percent-encoded URI), onto one quadrant of a
  four-colour texture; the truth is that quadrant's colour (read from the output PLY's f_dc with the project's
  reader: rgb = 0.5 + C0 f_dc) and the box's size.
* Gaussian splat files, through ``scpainter_blender.core.splats.reader.load`` in a backend process (a subprocess
  that imports ``backend`` first, as ``python -m backend render`` loads a job's assets): the real PLY
  ``3dgs/loadersgl_train-1000.ply`` converted by PlayCanvas' splat-transform (tools/splat_transform) to .spz, .sog,
  unbundled SOG (meta.json) and .glb (KHR_gaussian_splatting); a GaussianSplats3D .ksplat (compression mode 1,
  8 spatial buckets, written here from the format as splat-transform's reader decodes it, checked by converting it
  back with splat-transform) saved as ``.splat``; an antimatter15 .splat with 80 % invalid records. The truth is
  the source PLY: count, positions and opacities matched by nearest neighbour (for the .glb, the source in the
  glTF's frame stood Z up: ``gltf_truth``).
* Training clips, through ``backend.train.clip.load`` then ``Clip.load_frames`` / ``Clip.K_for`` (a subprocess):
  a phone video with a display rotation (PyAV's display matrix, -90°: "rotate 90" as phones write it); frames whose
  aspect ratio differs from the predictions'; fisheye (Kannala–Brandt) frames with and without
  ``distortion_model``. Frames hold coordinate ramps (R = x, G = y of the undistorted normalised ray) so the pixel
  error of the undistortion is read off the output.

Outcomes: ``correct`` (accepted, values within the stated bound), ``refused`` (a clean error: exit 2, the module's
InputError, or a CleanFailure; the detail says whether the message names the input), ``unsupported`` (a clean
refusal saying the format is not read), ``warned`` (accepted with a ``warning`` event that says why the values are
not the file's), ``silent_wrong`` (accepted, values wrong: how wrong in the detail), ``traceback`` (an
uncaught exception), ``timeout``. ``expected`` is the outcome the issue asks for; ``ok`` whether it was met.
Controls (``control:`` cases) are inputs today's code already reads: they check the harness itself.

Not a test: prints a table and saves bench/results/inputs_round2_before.json (``--label before``) or
inputs_round2.json (in ``--out DIR``; a path ending in .json names the file). The same script on the old and the new
code gives the closing note's before/after table. ``--smoke``: the first glTF case and the first clip case (the
splat conversions need the real data and Node; left out), what tests/bench/test_inputs_round2.py runs.
"""

import argparse
import io
import json
import math
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import traceback

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

C0 = 0.28209479177387814
TIMEOUT_S = 60
SPLAT_TRANSFORM = os.path.join(ROOT, "tools", "splat_transform", "node_modules", ".bin", "splat-transform")
SOURCE_PLY = "3dgs/loadersgl_train-1000.ply"

# -- the probe: the product's entry points, run in a subprocess so a crash or a hang is one row ---------------------

PROBE = r'''
import json, sys, traceback
sys.path.insert(0, sys.argv[1])
kind, src, out = sys.argv[2], sys.argv[3], sys.argv[4]
import numpy as np
def error_fields(e):
    return {"type": type(e).__name__, "message": str(e)[:600], "hint": str(getattr(e, "hint", "") or "")[:300],
            "file": str(getattr(e, "path", "") or "")}
try:
    if kind == "splat":
        import backend  # a backend process, as `python -m backend render` loads a job's assets (SOG's WebP decoder)
        from scpainter_blender.core.splats import reader
        g = reader.load(src)
        np.savez(out + ".npz", means=g.means, opacities=g.opacities, colours=g.base_colors(), scales=g.scales)
        result = {"status": "ok", "count": len(g), "dropped": {k: int(v) for k, v in g.dropped.items()}}
    else:
        from backend.train import clip as clip_mod
        W, H = int(sys.argv[5]), int(sys.argv[6])
        c = clip_mod.load(src)
        K = c.K_for(W, H)
        frames = c.load_frames(W, H)
        result = {"status": "ok"}
        np.savez(out + ".npz", K=K, frames=frames, K_clip=c.K, image_size=np.array(c.image_size))
except BaseException as e:
    clean = False
    try:
        from scpainter_blender.core import errors
        clean = isinstance(e, errors.InputError)
    except Exception:
        pass
    try:
        from backend.errors import CleanFailure
        clean = clean or isinstance(e, CleanFailure)
    except Exception:
        pass
    result = dict(status="error" if clean else "exception", traceback=traceback.format_exc()[-1500:],
                  **error_fields(e))
with open(out, "w") as f:
    json.dump(result, f)
'''

UNSUPPORTED_WORDS = ("not supported", "are not read", "not read", "accepted are", "not gaussian splats",
                     "not a ply file", "unknown format", "unsupported")


def row(cls, case, expected, outcome, detail, **metrics):
    ok = outcome in expected.split("|")
    return {"class": cls, "case": case, "expected": expected, "outcome": outcome, "ok": ok, "detail": detail,
            "metrics": metrics}


def refusal(message, expected_correct):
    low = message.lower()
    if expected_correct and any(w in low for w in UNSUPPORTED_WORDS):
        return "unsupported"
    return "refused"


def names(message, path):
    return os.path.basename(path) in message or os.path.basename(os.path.dirname(path)) in message


def run_probe(kind, src, work, *extra):
    out = os.path.join(work, f"probe_{abs(hash((kind, src)))}.json")
    for p in (out, out + ".npz"):
        if os.path.exists(p):
            os.remove(p)
    env = dict(os.environ, PYTHONPATH=ROOT)
    try:
        p = subprocess.run([sys.executable, "-c", PROBE, ROOT, kind, src, out, *map(str, extra)], cwd=ROOT, env=env,
                           capture_output=True, text=True, timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return {"status": "timeout"}, None
    if not os.path.exists(out):
        return {"status": "exception", "type": f"exit {p.returncode}", "message": p.stderr[-600:],
                "traceback": p.stderr[-1500:]}, None
    with open(out) as f:
        result = json.load(f)
    arrays = None
    if result["status"] == "ok":
        with np.load(out + ".npz") as z:
            arrays = {k: z[k] for k in z.files}
    return result, arrays


def probe_outcome(result, path, expected_correct):
    """(outcome, detail) for a probe that did not succeed."""
    if result["status"] == "timeout":
        return "timeout", f"no answer in {TIMEOUT_S} s"
    msg = result.get("message", "")
    if result["status"] == "error":
        o = refusal(msg, expected_correct)
        return o, f"{result['type']} ({'names' if names(msg, path) else 'does NOT name'} the file): {msg[:240]}"
    last = result.get("traceback", "").strip().splitlines()[-1:] or [msg]
    return "traceback", f"{result.get('type')}: {last[0][:240]}"


# -- glTF mesh cars -------------------------------------------------------------------------------------------------

QUADRANTS = {"TL": (220, 40, 40), "TR": (40, 190, 70), "BL": (50, 70, 210), "BR": (230, 200, 40)}
BOX = np.array([1.9, 1.5, 4.5])   # glTF (Y up): width x, height y, length z
BOX_ZUP = np.array([1.9, 4.5, 1.5])  # the same box as mesh-asset writes it (Z up: x, -z, y)


def quadrant_png():
    from PIL import Image

    img = np.zeros((64, 64, 3), np.uint8)
    img[:32, :32], img[:32, 32:] = QUADRANTS["TL"], QUADRANTS["TR"]  # glTF UV: v = 0 is the image's top row
    img[32:, :32], img[32:, 32:] = QUADRANTS["BL"], QUADRANTS["BR"]
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, "PNG")
    return buf.getvalue()


def box_mesh():
    """24 vertices (4 per face, outward winding), 12 triangles, and per-face UVs spanning [0, 1]²."""
    h = BOX / 2
    pos, uv, tri = [], [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            a, b = [k for k in range(3) if k != axis]
            quad = []
            for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.zeros(3)
                p[axis], p[a], p[b] = sign * h[axis], su * h[a], sv * h[b]
                quad.append(p)
            corners_uv = [(0, 0), (1, 0), (1, 1), (0, 1)]
            n = np.cross(quad[1] - quad[0], quad[3] - quad[0])
            if n[axis] * sign < 0:
                quad, corners_uv = quad[::-1], corners_uv[::-1]
            base = len(pos)
            pos += quad
            uv += corners_uv
            tri += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return np.array(pos, np.float32), np.array(uv, np.float32), np.array(tri, np.uint32)


def into_quadrant(uv, q):
    """UVs of [0, 1]² squeezed into quadrant q, 0.05 clear of its edges (bilinear taps stay inside)."""
    off = {"TL": (0.05, 0.05), "TR": (0.55, 0.05), "BL": (0.05, 0.55), "BR": (0.55, 0.55)}[q]
    return (np.asarray(off) + 0.4 * uv).astype(np.float32)


class Gltf:
    """A glTF 2.0 document written by hand (so every accessor detail is ours): views, accessors, one mesh."""

    def __init__(self):
        self.blob = bytearray()
        self.doc = {"asset": {"version": "2.0", "generator": "bench/inputs_round2.py"}, "scene": 0,
                    "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}], "bufferViews": [], "accessors": []}

    def view(self, data: bytes, stride=None, target=None):
        self.blob += b"\0" * (-len(self.blob) % 4)
        v = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        if stride:
            v["byteStride"] = stride
        if target:
            v["target"] = target
        self.blob += data
        self.doc["bufferViews"].append(v)
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, array, ctype, typ, normalized=False, stride=None, minmax=False):
        a = np.ascontiguousarray(array)
        n, comps = len(a), (a.shape[1] if a.ndim == 2 else 1)
        if stride and stride > a.itemsize * comps:  # pad every element to the stride (glTF's 4-byte alignment)
            rows = np.zeros((n, stride), np.uint8)
            rows[:, :a.itemsize * comps] = a.reshape(n, -1).view(np.uint8).reshape(n, -1)
            data = rows.tobytes()
        else:
            data, stride = a.tobytes(), None
        acc = {"bufferView": self.view(data, stride, 34963 if typ == "SCALAR" else 34962), "componentType": ctype,
               "count": n, "type": typ}
        if normalized:
            acc["normalized"] = True
        if minmax:
            acc["min"], acc["max"] = a.min(0).tolist(), a.max(0).tolist()
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def image_in_buffer(self, png):
        self.doc["images"] = [{"bufferView": self.view(png), "mimeType": "image/png"}]

    def material(self, texinfo=None, factor=None):
        pbr = {}
        if texinfo is not None:
            pbr["baseColorTexture"] = texinfo
            self.doc["textures"] = [{"source": 0}]
        if factor is not None:
            pbr["baseColorFactor"] = factor
        self.doc["materials"] = [{"pbrMetallicRoughness": pbr}]

    def save(self, path, bin_uri=None):
        doc = dict(self.doc)
        if path.endswith(".glb"):
            doc["buffers"] = [{"byteLength": len(self.blob)}]
            text = json.dumps(doc).encode()
            text += b" " * (-len(text) % 4)
            blob = bytes(self.blob) + b"\0" * (-len(self.blob) % 4)
            body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
            with open(path, "wb") as f:
                f.write(b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body)
        else:
            doc["buffers"] = [{"uri": bin_uri, "byteLength": len(self.blob)}]
            with open(os.path.join(os.path.dirname(path), bin_uri), "wb") as f:
                f.write(self.blob)
            with open(path, "w") as f:
                json.dump(doc, f, indent=1)
        return path


def gltf_box(path, *, uv0=None, uv1=None, texinfo=None, positions=None, ext_used=(), ext_required=(),
             node=None, image_uri=None, bin_uri="box.bin"):
    pos, uv, tri = box_mesh()
    g = Gltf()
    attrs = {}
    if positions is None:
        attrs["POSITION"] = g.accessor(pos, 5126, "VEC3", minmax=True)
    else:
        attrs["POSITION"] = positions(g)
    if uv0 is not None:
        attrs["TEXCOORD_0"] = uv0(g) if callable(uv0) else g.accessor(uv0, 5126, "VEC2")
    if uv1 is not None:
        attrs["TEXCOORD_1"] = g.accessor(uv1, 5126, "VEC2")
    prim = {"attributes": attrs, "indices": g.accessor(tri.reshape(-1), 5125, "SCALAR"), "material": 0}
    g.doc["meshes"] = [{"primitives": [prim]}]
    g.material(texinfo if texinfo is not None else {"index": 0})
    if image_uri is None:
        g.image_in_buffer(quadrant_png())
    else:
        g.doc["images"] = [{"uri": image_uri}]
    if node:
        g.doc["nodes"][0].update(node)
    if ext_used:
        g.doc["extensionsUsed"] = list(ext_used)
    if ext_required:
        g.doc["extensionsRequired"] = list(ext_required)
    return g.save(path, bin_uri)


def draco_box(path):
    """The textured box as a GLB whose primitive is KHR_draco_mesh_compression (DracoPy's encoder)."""
    import DracoPy

    pos, uv, tri = box_mesh()
    uvq = into_quadrant(uv, "TR")
    data = DracoPy.encode(pos.astype(np.float64), tri, quantization_bits=14, tex_coord=uvq.astype(np.float64),
                          preserve_order=True)
    decoded = DracoPy.decode(data)  # the unique ids the encoder gave each attribute (glTF names them)
    ids = {a["attribute_type"]: a["unique_id"] for a in decoded.attributes}
    g = Gltf()
    bv = g.view(data)
    g.doc["accessors"] = [{"componentType": 5126, "count": len(pos), "type": "VEC3", "min": pos.min(0).tolist(),
                           "max": pos.max(0).tolist()},
                          {"componentType": 5126, "count": len(pos), "type": "VEC2"},
                          {"componentType": 5125, "count": tri.size, "type": "SCALAR"}]
    prim = {"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0,
            "extensions": {"KHR_draco_mesh_compression": {"bufferView": bv,
                                                          "attributes": {"POSITION": ids[0], "TEXCOORD_0": ids[3]}}}}
    g.doc["meshes"] = [{"primitives": [prim]}]
    g.material({"index": 0})
    g.image_in_buffer(quadrant_png())
    g.doc["extensionsUsed"] = g.doc["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    return g.save(path)


def gltf_cases(d):
    """(case, path, expected, truth) for the glTF class: truth = expected quadrant colour (and the box size)."""
    _, uv, _ = box_mesh()
    tr = into_quadrant(uv, "TR")
    cases = []

    def add(case, name, expected, **kw):
        path = os.path.join(d, name)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        cases.append((case, gltf_box(path, **kw), expected))

    add("control: float UVs into one quadrant", "control/box.glb", "correct", uv0=tr)
    add("KHR_texture_transform offset+scale", "tt/box.glb", "correct", uv0=uv,
        texinfo={"index": 0, "extensions": {"KHR_texture_transform": {"offset": [0.55, 0.05], "scale": [0.4, 0.4]}}},
        ext_used=["KHR_texture_transform"])
    add("KHR_texture_transform offset+scale+rotation", "ttr/box.glb", "correct", uv0=uv,
        texinfo={"index": 0, "extensions": {"KHR_texture_transform": {"offset": [0.55, 0.45], "rotation": math.pi / 2,
                                                                      "scale": [0.4, 0.4]}}},
        ext_used=["KHR_texture_transform"])
    add("textureInfo texCoord=1", "tc1/box.glb", "correct", uv0=into_quadrant(uv, "BL"), uv1=tr,
        texinfo={"index": 0, "texCoord": 1})
    add("normalized UNSIGNED_BYTE texcoords", "u8/box.glb", "correct",
        uv0=lambda g: g.accessor(np.round(tr * 255).astype(np.uint8), 5121, "VEC2", normalized=True, stride=4))
    add("normalized UNSIGNED_SHORT texcoords", "u16/box.glb", "correct",
        uv0=lambda g: g.accessor(np.round(tr * 65535).astype(np.uint16), 5123, "VEC2", normalized=True))
    h = BOX / 2
    add("KHR_mesh_quantization (SHORT positions, node scale)", "quant/box.glb", "correct", uv0=tr,
        positions=lambda g: g.accessor(np.round(box_mesh()[0] / h * 32767).astype(np.int16), 5122, "VEC3",
                                       normalized=True, stride=8, minmax=True),
        node={"scale": h.tolist()}, ext_used=["KHR_mesh_quantization"], ext_required=["KHR_mesh_quantization"])
    os.makedirs(os.path.join(d, "draco"))
    cases.append(("KHR_draco_mesh_compression (DracoPy 2.2.0)", draco_box(os.path.join(d, "draco", "box.glb")),
                  "correct"))
    add(".gltf whose external texture is missing", "missing/box.gltf", "refused|warned", uv0=tr,
        image_uri="paint.png")
    add(".gltf with a percent-encoded image URI", "pct/box.gltf", "correct", uv0=tr, image_uri="car%20paint.png")
    with open(os.path.join(d, "pct", "car paint.png"), "wb") as f:
        f.write(quadrant_png())
    return cases


def run_mesh(case, path, expected, work):
    out = path[:-len(os.path.splitext(path)[1])] + "_out.ply"
    try:
        p = subprocess.run([sys.executable, "-m", "backend", "mesh-asset", path, "--out", out, "--count", "2000"],
                           cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT_S,
                           env=dict(os.environ, PYTHONPATH=ROOT))
    except subprocess.TimeoutExpired:
        return row("glTF", case, expected, "timeout", f"no answer in {TIMEOUT_S} s")
    events = []
    for line in p.stdout.splitlines():
        try:
            events.append(json.loads(line))
        except ValueError:
            pass
    errors_ = [e for e in events if e.get("event") == "error"]
    warnings = [e for e in events if e.get("event") == "warning"]
    done = next((e for e in events if e.get("event") == "done"), None)
    if p.returncode != 0:
        if "Traceback" in p.stderr or not errors_ and p.returncode not in (1, 2):
            last = p.stderr.strip().splitlines()[-1:] or [""]
            return row("glTF", case, expected, "traceback", f"exit {p.returncode}: {last[0][:240]}")
        msg = errors_[0]["message"] if errors_ else p.stderr.strip()[-240:]
        o = refusal(msg, expected == "correct")
        return row("glTF", case, expected, o, f"exit {p.returncode} ({'names' if names(msg, path) else 'does NOT name'}"
                                              f" the file): {msg[:240]}")
    from scpainter_blender.core.splats import reader

    g = reader.load(out)
    rgb = 0.5 + C0 * g.sh[:, 0].astype(np.float64)
    want = np.array(QUADRANTS["TR"]) / 255.0
    err = np.abs(rgb - want).max(1)
    ext = g.means.max(0) - g.means.min(0)
    size_err = float(np.abs(ext / BOX_ZUP - 1).max())
    source = (done or {}).get("result", {}).get("colour_source")
    mean_rgb = np.round(rgb.mean(0) * 255).astype(int).tolist()
    detail = (f"colour_source {source}; mean colour {mean_rgb} vs {list(QUADRANTS['TR'])}: mean |err| "
              f"{err.mean():.3f}, {np.mean(err < 0.05):.0%} within 0.05; size {[round(float(v), 3) for v in ext]} vs "
              f"{BOX_ZUP.tolist()} (err {size_err:.1%})")
    good = err.mean() < 0.03 and np.mean(err < 0.05) >= 0.95 and size_err < 0.01
    if good:
        outcome = "correct"
    elif warnings:
        outcome = "warned"
        detail = f"warning {warnings[0].get('code')}: {warnings[0].get('message', '')[:160]}; " + detail
    else:
        outcome = "silent_wrong"
    return row("glTF", case, expected, outcome, detail, colour_err=float(err.mean()), size_err=size_err,
               colour_source=source)


# -- Gaussian splat files -------------------------------------------------------------------------------------------

def splat_transform(src, dst):
    p = subprocess.run([SPLAT_TRANSFORM, "-q", "-w", "-g", "cpu", src, dst], capture_output=True, text=True,
                       timeout=TIMEOUT_S)
    if p.returncode != 0:
        raise RuntimeError(f"splat-transform {os.path.basename(src)} -> {os.path.basename(dst)}: {p.stderr[-300:]}")
    return dst


def half(a):
    return np.asarray(a, np.float32).astype(np.float16).view(np.uint16)


def write_ksplat(path, g, buckets=8):
    """GaussianSplats3D .ksplat, compression mode 1, SH degree 0, one section of ``buckets`` full buckets (the
    layout splat-transform's reader decodes: 4096-byte header, 1024-byte section header, bucket centres, then 24
    bytes per splat: 3 uint16 positions about the bucket centre, 3 half scales (σ), 4 half quaternion w x y z,
    RGBA uint8)."""
    N = len(g)
    assert N % buckets == 0
    cap = N // buckets
    order = np.lexsort((g.means[:, 2], g.means[:, 1], g.means[:, 0]))  # spatially coherent buckets
    means = g.means[order].astype(np.float64)
    centres = np.stack([(means[i * cap:(i + 1) * cap].min(0) + means[i * cap:(i + 1) * cap].max(0)) / 2
                        for i in range(buckets)])
    reach = max(np.abs(means[i * cap:(i + 1) * cap] - centres[i]).max() for i in range(buckets))
    block = 2.0 * reach * 1.001
    qrange = 32767
    step = block / 2.0 / qrange
    q = np.round((means - np.repeat(centres, cap, 0)) / step + qrange).astype(np.uint16)
    rec = np.zeros(N, [("p", "<u2", 3), ("s", "<u2", 3), ("r", "<u2", 4), ("c", "u1", 4)])
    rec["p"] = q
    rec["s"] = half(g.scales[order])
    rec["r"] = half(g.quats[order])
    rgba = np.concatenate([0.5 + C0 * g.sh[order, 0].astype(np.float64), g.opacities[order, None]], 1)
    rec["c"] = np.clip(np.round(rgba * 255), 0, 255).astype(np.uint8)
    header = bytearray(4096)
    header[0], header[1] = 0, 1
    struct.pack_into("<IIII", header, 4, 1, 1, N, N)
    struct.pack_into("<H", header, 20, 1)
    struct.pack_into("<3f", header, 24, *means.mean(0))
    section = bytearray(1024)
    struct.pack_into("<IIIIf", section, 0, N, N, cap, buckets, block)
    struct.pack_into("<H", section, 20, 12)
    struct.pack_into("<IIII", section, 24, qrange, N * rec.itemsize, buckets, 0)
    struct.pack_into("<H", section, 40, 0)
    with open(path, "wb") as f:
        f.write(bytes(header) + bytes(section) + centres.astype("<f4").tobytes() + rec.tobytes())
    return path


def write_splat(path, g, invalid=None):
    """antimatter15 .splat records of decoded Gaussians; ``invalid``: (nan rows, huge rows) index arrays."""
    rec = np.zeros(len(g), [("p", "<f4", 3), ("s", "<f4", 3), ("c", "u1", 4), ("q", "u1", 4)])
    rec["p"], rec["s"] = g.means, g.scales
    rgba = np.concatenate([0.5 + C0 * g.sh[:, 0].astype(np.float64), g.opacities[:, None]], 1)
    rec["c"] = np.clip(np.round(rgba * 255), 0, 255).astype(np.uint8)
    rec["q"] = np.clip(np.round(g.quats * 128 + 128), 0, 255).astype(np.uint8)
    if invalid is not None:
        nan, huge = invalid
        rec["p"][nan] = np.nan
        rec["s"][huge] = 1e38
    rec.tofile(path)
    return path


def compare_splats(arrays, count, truth):
    """Metrics of read Gaussians against the source's (matched by nearest neighbour)."""
    from scipy.spatial import cKDTree

    extent = float(np.linalg.norm(truth.means.max(0) - truth.means.min(0)))
    m = {"count": count, "of": len(truth), "extent": extent}
    means = arrays["means"].astype(np.float64)
    finite = np.isfinite(means).all(1)
    if count == 0 or not finite.any():
        return m
    dist, idx = cKDTree(truth.means.astype(np.float64)).query(means[finite])
    m["pos_median_rel"] = float(np.median(dist) / extent)
    m["pos_p99_rel"] = float(np.percentile(dist, 99) / extent)
    m["opacity_max_err"] = float(np.abs(arrays["opacities"][finite] - truth.opacities[idx]).max())
    m["colour_median_err"] = float(np.median(np.abs(arrays["colours"][finite] - truth.base_colors()[idx])))
    m["max_scale"] = float(np.nanmax(arrays["scales"])) if len(arrays["scales"]) else 0.0
    m["truth_max_scale"] = float(truth.scales.max())
    return m


#: Bounds for "read within the format's quantisation": splat-transform's own read-back of its .spz, .sog and
#: meta.json of the source measured position errors p99 <= 1.4e-5 of the scene's diagonal, opacity <= 0.004,
#: colour median <= 0.002 (it does not read .glb); the bounds leave a factor of 2.5 to 70 over that.
POS_MEDIAN_BOUND, POS_P99_BOUND, OPACITY_BOUND, COLOUR_BOUND = 1e-4, 1e-3, 0.01, 0.01


def splat_verdict(m):
    ok = (m["count"] == m["of"] and m.get("pos_median_rel", 1) <= POS_MEDIAN_BOUND
          and m.get("pos_p99_rel", 1) <= POS_P99_BOUND and m.get("opacity_max_err", 1) <= OPACITY_BOUND
          and m.get("colour_median_err", 1) <= COLOUR_BOUND
          and m.get("max_scale", 1e9) <= 2 * m["truth_max_scale"])
    nan = float("nan")
    detail = (f"read {m['count']:,} of {m['of']:,}; position error median {m.get('pos_median_rel', nan):.2g}, "
              f"p99 {m.get('pos_p99_rel', nan):.2g} of the diagonal; opacity max err "
              f"{m.get('opacity_max_err', nan):.3f}; colour median err {m.get('colour_median_err', nan):.3f}; "
              f"largest σ {m.get('max_scale', nan):.3g} (source {m.get('truth_max_scale', nan):.3g})")
    return ok, detail


def splat_cases(d, realdata):
    """(case, path, expected, note) for the splat class; None when the source PLY or splat-transform is absent."""
    src = os.path.join(realdata, SOURCE_PLY)
    if not os.path.isfile(src):
        return None, f"{SOURCE_PLY} not in {realdata}: class skipped"
    from scpainter_blender.core.splats import reader

    truth = reader.load(src)
    cases = [("control: the source INRIA PLY", src, "correct", "")]
    cases.append(("control: antimatter15 .splat", write_splat(os.path.join(d, "control.splat"), truth), "correct",
                  ""))
    have_st = os.path.isfile(SPLAT_TRANSFORM) and shutil.which("node")
    if have_st:
        os.makedirs(os.path.join(d, "sog_unbundled"))
        for case, name in (("SPZ (splat-transform)", "train.spz"), ("SOG bundle (splat-transform)", "train.sog"),
                           ("SOG unbundled meta.json (splat-transform)", "sog_unbundled/meta.json"),
                           ("glTF KHR_gaussian_splatting .glb (splat-transform)", "train.glb")):
            try:
                cases.append((case, splat_transform(src, os.path.join(d, name)), "correct", ""))
            except Exception as e:  # noqa: BLE001  the writer failing is a note, not a product outcome
                cases.append((case, None, "correct", f"not generated: {e}"))
    ks = write_ksplat(os.path.join(d, "train_ksplat.splat"), truth)
    note = ""
    if have_st:  # the writer checked by splat-transform's own .ksplat reader
        try:
            shutil.copy(ks, os.path.join(d, "check.ksplat"))
            back = reader.load(splat_transform(os.path.join(d, "check.ksplat"), os.path.join(d, "check.ply")))
            m = compare_splats({"means": back.means, "opacities": back.opacities, "colours": back.base_colors(),
                                "scales": back.scales}, len(back), truth)
            note = (f"[writer check: splat-transform reads it back: {splat_verdict(m)[1]}] ")
        except Exception as e:  # noqa: BLE001
            note = f"[writer check failed: {str(e)[:120]}] "
    cases.append((".ksplat (GaussianSplats3D, mode 1) saved as .splat", ks, "correct", note))
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(truth))
    cases.append((".splat with 80 % invalid records (600 NaN, 200 σ = 1e38)",
                  write_splat(os.path.join(d, "mostly_invalid.splat"), truth, (perm[:600], perm[600:800])),
                  "refused", ""))
    if not have_st:
        cases.append(("splat-transform formats", None, "correct", "splat-transform or node absent: not generated"))
    return (cases, truth), ""


#: splat-transform writes the PLY's (x, y, z) as glTF (-x, -y, z) (read off its .glb: the POSITION accessor of the
#: source's rows), and a glTF is Y up: the product stands it up as Blender's glTF importer does, (x, y, z) ->
#: (x, -z, y). The truth of the .glb case is the source turned by both.
PLY_TO_GLTF = np.diag([-1.0, -1.0, 1.0])
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def gltf_truth(truth):
    """The source Gaussians where a reader that stands glTF files up must put them (positions only are compared)."""
    import dataclasses

    return dataclasses.replace(truth, means=(truth.means @ (Y_UP_TO_Z_UP @ PLY_TO_GLTF).T).astype(np.float32))


def run_splat(case, path, expected, note, truth, work):
    if path is None:
        return row("splats", case, expected, "skipped", note)
    result, arrays = run_probe("splat", path, work)
    if result["status"] != "ok":
        o, detail = probe_outcome(result, path, expected == "correct")
        return row("splats", case, expected, o, note + detail)
    m = compare_splats(arrays, result["count"], truth)
    ok, detail = splat_verdict(m)
    if result.get("dropped"):
        detail += f"; dropped {result['dropped']}"
    return row("splats", case, expected, "correct" if ok else "silent_wrong", note + detail, **m)


# -- training clips -------------------------------------------------------------------------------------------------

def ours_to_vggt(K):
    from scpainter_blender.core.vggt import predictions as vggt

    return vggt.ours_K_to_vggt(K)


def write_predictions(path, S, w, h):
    """VGGT demo-layout predictions of S frames at w x h (a plane 5 units ahead), and their K (ours)."""
    from scpainter_blender.core.vggt import npz as vggt_io

    K = np.array([[0.9 * w, 0, w / 2], [0, 0.9 * w, h / 2], [0, 0, 1.0]])
    Ks = np.tile(K, (S, 1, 1))
    ext = np.tile(np.eye(4)[:3], (S, 1, 1))
    ext[:, 2, 3] = -0.2 * np.arange(S)
    rng = np.random.default_rng(1)
    vggt_io.save_predictions(path, rng.uniform(0.2, 0.8, (S, 3, h, w)).astype(np.float32),
                             np.full((S, h, w), 5.0, np.float32), np.full((S, h, w), 2.0, np.float32), ext,
                             ours_to_vggt(Ks))
    return K


def pattern(S, w, h):
    """(S, h, w, 3) uint8: asymmetric, smooth enough that a resize of the right image changes little."""
    yy, xx = np.mgrid[0:h, 0:w]
    out = np.empty((S, h, w, 3), np.uint8)
    for t in range(S):
        out[t, ..., 0] = (255 * xx / (w - 1)).astype(np.uint8)
        out[t, ..., 1] = (255 * yy / (h - 1)).astype(np.uint8)
        out[t, ..., 2] = (60 * t + 40 * ((xx // 8 + yy // 8) % 2) + 60 * (xx < w // 4)).astype(np.uint8)
    return out


def write_video(path, coded, rotation=0):
    import av

    with av.open(path, "w", format="mp4") as container:
        stream = container.add_stream("libx264rgb", rate=10)
        stream.width, stream.height, stream.pix_fmt = coded.shape[2], coded.shape[1], "rgb24"
        stream.options = {"crf": "0"}
        if rotation:
            stream.set_display_rotation(rotation)
        for f in coded:
            for packet in stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    with av.open(path) as container:  # check it reads back as written: the coded size and the display rotation
        frame = next(container.decode(video=0))
        return frame.rotation, (frame.width, frame.height)


def clip_json(folder, **fields):
    data = {"schema": "scpainter.clip/1", "predictions": "predictions.npz", "fps": 10, **fields}
    with open(os.path.join(folder, "clip.json"), "w") as f:
        json.dump(data, f)
    return os.path.join(folder, "clip.json")


def save_frames(folder, frames):
    from PIL import Image

    os.makedirs(os.path.join(folder, "frames"), exist_ok=True)
    for t, f in enumerate(frames):
        Image.fromarray(f).save(os.path.join(folder, "frames", f"frame_{t:06d}.png"))
    return "frames/frame_{:06d}.png"


# Lens models on normalised coordinates (x, y) = (X/Z, Y/Z) -> distorted normalised coordinates.
def distort_fisheye(x, y, k):
    r = np.hypot(x, y)
    th = np.arctan(r)
    thd = th * (1 + k[0] * th ** 2 + k[1] * th ** 4 + k[2] * th ** 6 + k[3] * th ** 8)
    s = np.where(r > 1e-12, thd / np.maximum(r, 1e-12), 1.0)
    return x * s, y * s


def distort_opencv(x, y, k):
    k1, k2, p1, p2, k3 = (list(k) + [0.0] * 5)[:5]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
            y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)


def undistort(xd, yd, model, k):
    """Newton's inverse of ``model`` (finite-difference Jacobian), checked by distorting back."""
    x, y = xd.copy(), yd.copy()
    e = 1e-7
    for _ in range(50):
        fx, fy = model(x, y, k)
        rx, ry = fx - xd, fy - yd
        ax, ay = model(x + e, y, k)
        bx, by = model(x, y + e, k)
        j11, j21, j12, j22 = (ax - fx) / e, (ay - fy) / e, (bx - fx) / e, (by - fy) / e
        det = j11 * j22 - j12 * j21
        x, y = x - (j22 * rx - j12 * ry) / det, y - (-j21 * rx + j11 * ry) / det
    fx, fy = model(x, y, k)
    assert np.abs(np.hypot(fx - xd, fy - yd)).max() < 1e-9
    return x, y


RAMP = 0.8  # the coordinate ramps span normalised x, y in [-RAMP, RAMP]


def ramp_frames(S, W, H, K, model, k):
    """Recorded (distorted) frames: R, G = the undistorted normalised ray's x, y on [-RAMP, RAMP] -> 0..255,
    B = 200 (0 where an undistortion finds no source pixel)."""
    v, u = np.mgrid[0:H, 0:W] + 0.5  # ours: pixel centres at +0.5
    xd, yd = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    x, y = undistort(xd, yd, model, k)
    img = np.empty((H, W, 3), np.uint8)
    img[..., 0] = np.clip(np.round((x + RAMP) / (2 * RAMP) * 255), 0, 255)
    img[..., 1] = np.clip(np.round((y + RAMP) / (2 * RAMP) * 255), 0, 255)
    img[..., 2] = 200
    return np.repeat(img[None], S, 0)


def ramp_error(frames, Ks, f_recorded):
    """Displacement (px of the recorded frames) between where each output pixel's K says its ray is and the ray its
    colour encodes, over pixels with data inside the ramps' unclipped range."""
    errs, nodata, total = [], 0, 0
    for img, K in zip(frames, Ks):
        H, W = img.shape[:2]
        v, u = np.mgrid[0:H, 0:W] + 0.5
        y = (v - K[1, 2]) / K[1, 1]
        x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
        im = img.astype(np.float64)
        has = im[..., 2] > 100
        inside = (np.abs(x) < RAMP * 0.95) & (np.abs(y) < RAMP * 0.95)
        nodata += int(np.count_nonzero(inside & ~has))
        total += int(np.count_nonzero(inside))
        sel = inside & has
        xm = im[..., 0][sel] / 255 * 2 * RAMP - RAMP
        ym = im[..., 1][sel] / 255 * 2 * RAMP - RAMP
        errs.append(np.hypot(xm - x[sel], ym - y[sel]) * f_recorded)
    e = np.concatenate(errs) if errs else np.zeros(0)
    return e, nodata / max(total, 1)


FISHEYE_K = [0.05, -0.02, 0.004, -0.0005]   # Kannala–Brandt k1..k4 (OpenCV cv2.fisheye's order)
OPENCV_D = [-0.12, 0.03, 1e-3, -1e-3, 0.0]  # a pinhole lens' k1 k2 p1 p2 k3 (the control)
#: "correct" for an undistortion: the median displacement and the 95th percentile within these (px of the recorded
#: frames; the ramps' 8-bit steps are 0.6 px there), no more than 2 % of the judged pixels without data.
UNDIST_MEDIAN_BOUND, UNDIST_P95_BOUND = 0.5, 1.0


def clip_cases(d):
    """(case, clip.json, expected, judge, (W, H) asked of load_frames, note)."""
    cases = []
    S = 3

    # display rotation: the portrait frames players show are coded landscape with "rotate 90" (matrix -90°)
    def video_case(name, rotation, case, expected):
        folder = os.path.join(d, name)
        os.makedirs(folder)
        shown = pattern(S, 48, 64) if rotation else pattern(S, 64, 48)
        h, w = shown.shape[1:3]
        K = write_predictions(os.path.join(folder, "predictions.npz"), S, w, h)
        coded = np.stack([np.rot90(f, k=-rotation // 90) for f in shown]) if rotation else shown
        got_rot, coded_size = write_video(os.path.join(folder, "drive.mp4"), coded, rotation)
        note = f"[video coded {coded_size[0]}x{coded_size[1]}, reads back rotation {got_rot}°] "

        def judge(arrays):
            frames, Kc, Kclip = arrays["frames"], arrays["K"], arrays["K_clip"]
            err = np.abs(frames.astype(int) - shown.astype(int))
            kerr = float(max(np.abs(Kc[:, 0, 0] / K[0, 0] - 1).max(), np.abs(Kc[:, 1, 1] / K[1, 1] - 1).max(),
                             np.abs(Kc[:, 0, 2] - K[0, 2]).max() / w, np.abs(Kc[:, 1, 2] - K[1, 2]).max() / h))
            size = arrays["image_size"].tolist()
            ok = err.max() <= 2 and kerr < 1e-3 and size == [w, h]
            return ok, (f"clip image_size {size[0]}x{size[1]} (shown {w}x{h}), its K fx {Kclip[0, 0, 0]:.1f} fy "
                        f"{Kclip[0, 1, 1]:.1f} (true {K[0, 0]:.1f}); frames at {w}x{h} vs the shown ones: mean |err| "
                        f"{err.mean():.1f}, max {err.max()} (of 255)"), \
                {"frame_mean_err": float(err.mean()), "K_err": kerr, "image_size": size}
        cases.append((case, clip_json(folder, frames="drive.mp4"), expected, judge, (w, h), note))

    video_case("video_plain", 0, "control: landscape video, no rotation", "correct")
    video_case("video_rot90", -90, "phone video, display rotation 90° (portrait predictions)", "correct")

    # aspect ratio of the frames against the predictions'
    def aspect_case(name, case, expected, frame_size, pred_size):
        folder = os.path.join(d, name)
        os.makedirs(folder)
        (W, H), (w, h) = frame_size, pred_size
        K = write_predictions(os.path.join(folder, "predictions.npz"), S, w, h)
        frames = pattern(S, W, H)

        def judge(arrays):
            Kc = arrays["K_clip"]
            stretch = float((Kc[0, 0, 0] / Kc[0, 1, 1]) / (K[0, 0] / K[1, 1]))
            ok = abs(stretch - 1) < 0.02
            return ok, (f"frames {W}x{H} ({W / H:.3f}), predictions {w}x{h} ({w / h:.3f}): the clip's K "
                        f"fx/fy {Kc[0, 0, 0] / Kc[0, 1, 1]:.3f} vs the predictions' {K[0, 0] / K[1, 1]:.3f} "
                        f"(stretch {stretch:.3f})"), {"stretch": stretch}
        cases.append((case, clip_json(folder, frames=save_frames(folder, frames)), expected, judge, (W, H), ""))

    aspect_case("aspect_bad", "frames 16:9 (128x72), predictions 4:3 (64x48)", "refused", (128, 72), (64, 48))
    aspect_case("aspect_ok", "control: frames 16:9 (960x540), VGGT's 518x294 (rounding)", "correct", (960, 540),
                (518, 294))

    # lens models: the frames are distorted ramps, the poses hold the calibrated K
    W, H = 160, 120
    K_rec = np.array([[100.0, 0, 81.3], [0, 100.0, 59.2], [0, 0, 1]])

    def lens_case(name, case, expected, model, coeffs, extra):
        folder = os.path.join(d, name)
        os.makedirs(folder)
        write_predictions(os.path.join(folder, "predictions.npz"), S, 40, 30)
        w2c = np.tile(np.eye(4), (S, 1, 1))
        w2c[:, 2, 3] = -0.2 * np.arange(S)
        np.savez(os.path.join(folder, "poses.npz"), world_to_camera=w2c, K=np.tile(K_rec, (S, 1, 1)),
                 vggt_to_world=np.eye(4))
        frames = ramp_frames(S, W, H, K_rec, model, coeffs)

        def judge(arrays):
            e, nodata = ramp_error(arrays["frames"], arrays["K"], K_rec[0, 0])
            if not len(e):
                return False, "no judged pixel has data", {}
            med, p95, mx = float(np.median(e)), float(np.percentile(e, 95)), float(e.max())
            ok = med <= UNDIST_MEDIAN_BOUND and p95 <= UNDIST_P95_BOUND and nodata <= 0.02
            return ok, (f"undistorted pixel vs its K: median {med:.2f} px, p95 {p95:.2f}, max {mx:.1f} px; "
                        f"{np.mean(e > 1):.0%} off by > 1 px; {nodata:.0%} without data"), \
                {"median_px": med, "p95_px": p95, "max_px": mx, "frac_over_1px": float(np.mean(e > 1))}
        cases.append((case, clip_json(folder, frames=save_frames(folder, frames), poses="poses.npz", **extra),
                      expected, judge, (W, H), ""))

    lens_case("opencv", "control: pinhole lens, 5 OpenCV coefficients", "correct", distort_opencv, OPENCV_D,
              {"distortion": OPENCV_D})
    lens_case("fisheye_model", "fisheye, 4 Kannala-Brandt coefficients + distortion_model: fisheye", "correct",
              distort_fisheye, FISHEYE_K, {"distortion": FISHEYE_K, "distortion_model": "fisheye"})
    lens_case("fisheye_nomodel", "the same 4 fisheye numbers, no distortion_model", "refused", distort_fisheye,
              FISHEYE_K, {"distortion": FISHEYE_K})
    return cases


def run_clip(case, path, expected, judge, size, note, work):
    result, arrays = run_probe("clip", path, work, *size)
    if result["status"] != "ok":
        o, detail = probe_outcome(result, path, expected == "correct")
        return row("clips", case, expected, o, note + detail)
    try:
        ok, detail, metrics = judge(arrays)
    except Exception as e:  # noqa: BLE001  a judge failing on odd arrays is the product's output being odd
        return row("clips", case, expected, "silent_wrong", note + f"output not judgeable: {e}")
    return row("clips", case, expected, "correct" if ok else "silent_wrong", note + detail, **metrics)


# -- main -----------------------------------------------------------------------------------------------------------

def guarded(cls, case, expected, fn, *a):
    """One case, whatever happens in the harness: a failure of the harness itself is its own row."""
    try:
        return fn(*a)
    except Exception as e:  # noqa: BLE001
        where = [ln.strip() for ln in traceback.format_exc().splitlines() if ln.strip().startswith("File ")]
        return row(cls, case, expected, "harness_error", f"{type(e).__name__}: {str(e)[:200]} "
                                                         f"({where[-1][:160] if where else ''})")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", default="after", help="'before' writes inputs_round2_before.json")
    ap.add_argument("--realdata", default=os.path.join(ROOT, "..", "shared", "realdata"))
    if not os.path.isdir(os.path.join(ROOT, "..", "shared", "realdata")) and os.path.isdir("/work/shared/realdata"):
        ap.set_defaults(realdata="/work/shared/realdata")
    ap.add_argument("--keep", default=None, help="write the inputs here (kept) instead of a temporary folder")
    sys.path.insert(0, os.path.join(ROOT, "bench"))
    import bench_cli  # bench/, the script's folder

    bench_cli.add_smoke_and_out(ap, "the first glTF case and the first clip case")
    args = ap.parse_args(argv)
    out = bench_cli.json_path(args.out, "inputs_round2_before" if args.label == "before" else "inputs_round2")
    first = (lambda cases: list(cases)[:1]) if args.smoke else list
    work = args.keep or tempfile.mkdtemp(prefix="scpainter-round2-")
    os.makedirs(work, exist_ok=True)
    t0 = time.time()
    rows = []
    d = os.path.join(work, "gltf")
    os.makedirs(d, exist_ok=True)
    for case, path, expected in first(gltf_cases(d)):
        rows.append(guarded("glTF", case, expected, run_mesh, case, path, expected, work))
    d = os.path.join(work, "splats")
    os.makedirs(d, exist_ok=True)
    made, why = (None, "--smoke leaves the splat conversions out") if args.smoke else splat_cases(d, args.realdata)
    if made is None:
        rows.append(row("splats", "(all)", "correct", "skipped", why))
    else:
        cases, truth = made
        for case, path, expected, note in cases:
            case_truth = gltf_truth(truth) if path is not None and path.endswith(".glb") else truth
            rows.append(guarded("splats", case, expected, run_splat, case, path, expected, note, case_truth, work))
    d = os.path.join(work, "clips")
    os.makedirs(d, exist_ok=True)
    for case, path, expected, judge, size, note in first(clip_cases(d)):
        rows.append(guarded("clips", case, expected, run_clip, case, path, expected, judge, size, note, work))
    for r in rows:  # the temporary folder's name would make every run's JSON differ
        r["detail"] = r["detail"].replace(os.path.realpath(work), "<tmp>").replace(work, "<tmp>")
    wc = max(len(r["case"]) for r in rows)
    print(f"{'class':<7} {'case':<{wc}}  {'expected':<15} {'outcome':<13} ok  detail")
    for r in rows:
        print(f"{r['class']:<7} {r['case']:<{wc}}  {r['expected']:<15} {r['outcome']:<13} "
              f"{'yes' if r['ok'] else 'NO ':<3} {r['detail']}")
    git = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    versions = {}
    for mod in ("numpy", "trimesh", "DracoPy", "av", "cv2", "PIL"):
        try:
            versions[mod] = str(getattr(__import__(mod), "__version__", "?"))
        except Exception:  # noqa: BLE001  absent: the row says what that changes
            versions[mod] = None
    summary = {o: sum(r["outcome"] == o for r in rows) for o in sorted({r["outcome"] for r in rows})}
    print(f"{sum(r['ok'] for r in rows)} of {len(rows)} as the issue asks; {summary}; {time.time() - t0:.0f} s")
    from scpainter_blender.core import outputs

    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    outputs.write_json(out, {"label": args.label, "commit": git.strip(), "seconds": round(time.time() - t0, 1),
                             "versions": versions,
                             "bounds": {"gltf_colour_mean_err": 0.03, "gltf_size_err": 0.01,
                                        "splat_pos_median_rel": POS_MEDIAN_BOUND, "splat_pos_p99_rel": POS_P99_BOUND,
                                        "splat_opacity_max_err": OPACITY_BOUND,
                                        "splat_colour_median_err": COLOUR_BOUND,
                                        "undistort_median_px": UNDIST_MEDIAN_BOUND,
                                        "undistort_p95_px": UNDIST_P95_BOUND,
                                        "video_frame_max_err": 2, "aspect_stretch": 0.02},
                             "summary": summary, "rows": rows})
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
