"""Seeded fuzz cases for the surfaces added after issue 14 (issue 30), run by ``tests/fuzz_inputs.py``'s harness
(its worker processes, timeouts, folder snapshots and outcome classes).

Kinds (``CASES`` says how many of each; a case is reproducible from (kind, index, seed)):

* ``mesh``: ``python -mbackend mesh-asset <mesh> --out job/out/asset.ply --count 300`` on a textured car-like mesh
  as GLB, glTF (+ .bin buffers + a PNG texture), OBJ (+ MTL + PNG), OFF and binary PLY, each changed one way:
  face indices out of range, counts (accessor, OFF, PLY) beyond the data, truncation, NaN positions and texture
  coordinates, issue 31's glTF paths (KHR_texture_transform, texCoord, normalized accessors, Draco), the files a mesh names (missing, a folder, a FIFO, a link outside, garbage, a decompression bomb,
  another file of the same base name), JSON damage, content-preserving rewrites.
* ``splat``: the job's asset as a SuperSplat compressed PLY or an antimatter15 ``.splat`` (``render``): sizes,
  chunk tables, packed words, header damage, non-finite values, all Gaussians invalid, content-preserving rewrites.
* ``splat2``: issue 31's formats (SPZ 2/3, .ksplat 0-2, SOG, KHR_gaussian_splatting GLB), ``render``: the
  mutations and expectations are in ``tests/fuzz_splat_formats.py``.
* ``exr``: ``generate job.json`` (the baseline, no checkpoint) after a finished ``render``, with a condition EXR
  replaced: another size, missing or renamed channels, other compressions, tiles, truncation, a folder, a FIFO,
  a link, garbage, non-finite values.
* ``clip``: a training clip (``backend.train.clip.load`` then ``Clip.load_frames``, in-process; an InputError
  counts as exit 2, any other exception as a traceback): poses.npz, frames (PNG), the video, clip.json.
* ``kill``: SIGKILL / SIGTERM of ``generate`` (the baseline), ``render`` and ``mesh-asset`` before a seeded one of
  their atomic renames (``_gate_renames``: the child waits at each until let on, so the kill lands at the same point
  however busy the machine is), and two runs at once on one output folder; then the next run, and the folder
  checked. The backend processes are forked from ``ForkServer`` (imports done, no kernel run: numba's OpenMP layer
  stops a process forked after it ran), each running ``backend.__main__.main``.

Outcome classes are those of ``fuzz_inputs`` (accepted, clean, unclear, traceback, hang, escape, misread); what
``misread`` means here, per kind:

* ``mesh``: (a) a content-preserving rewrite (CRLF, comments, re-serialised JSON, ASCII PLY, ...) accepted with
  other Gaussians than the original file gives; (b) a case marked *refuse* (out-of-range or negative indices,
  counts beyond the data, a truncated binary file or OFF, a file the mesh names that is missing, unreadable, a
  folder, outside its folder, or replaced by another file of the same base name) accepted without a ``warning``
  event; (c) any acceptance whose PLY holds fewer Gaussians than ``--count`` without a ``warning`` event.
* ``splat``: (a) a rewrite accepted with other raw values (``core.splats.reader.read``) than the original;
  (b) a file whose Gaussians are all invalid (NaN chunk ranges, zero quaternions or scales, NaN positions)
  rendered without a ``warning`` event.
* ``exr``: (a) an EXR of another size than the job's resolution accepted (it must be refused); (b) a lossless
  rewrite (other lossless compression, tiles, channel order, Blender's prefix, the former flat names) accepted
  with generated frames other than the original EXRs give.
* ``clip``: (a) a rewrite (PNG re-encoded, npz deflated) loaded with other frames or poses; (b) a case marked
  *refuse* (a K no camera has: focal length or principal point beyond 10^6 px, a video with another number of
  frames) loaded; a clean refusal of a poses.npz case must name poses.npz (else ``unclear``).
* ``kill``: after the next run, (a) a frame in ``generated/`` or ``conditions/`` other than the finished run's
  reference (mixed frames kept as up to date), (b) a temporary file (``.<name>.<random>.tmp``) left in the output
  folder, (c) a second concurrent run that wrote into a folder the first one held (both finishing with frames
  of different settings mixed). A run that exits 1 naming a busy output folder is the lock respected (clean).

One case by hand: ``.venv/bin/python -m tests.fuzz_inputs --kind mesh --index 17 [--keep]``.
"""

from __future__ import annotations

import copy
import io
import json
import os
import random
import shutil
import signal
import struct
import sys
import time
from dataclasses import dataclass

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
for _p in (os.path.dirname(HERE), HERE):  # the fixtures of tests/core, tests/backend: as tests.core.splats...
    if _p not in sys.path:
        sys.path.insert(0, _p)

KINDS = ("mesh", "splat", "splat2", "exr", "clip", "kill")
#: The kinds tests/backend/test_fuzz_inputs.py runs: all of them.
CI_KINDS = KINDS
CASES = {"mesh": 220, "splat": 110, "splat2": 300, "exr": 90, "clip": 90, "kill": 36}
#: Each backend process of a kill case must end within this (a busy 2-core machine; they take ~0.1-1 s).
KILL_TIMEOUT_S = 30.0
MESH_COUNT = 300
KILL_FRAMES = 10
FORMATS = ("glb", "gltf", "obj", "off", "ply")
BIG = 1 << 31


@dataclass
class Case:
    """One case; ``apply(c)`` changes the case folder ``c``. ``expect``: None (accepted or clean, either is fine),
    "refuse" (acceptance without a warning is a misread), "same" (content-preserving: acceptance with other
    results is a misread). ``fmt``: the mesh / splat format. ``must_name``: a clean refusal must name this file."""

    kind: str
    index: int
    seed: int
    description: str
    apply: object
    expect: str | None = None
    fmt: str = ""
    must_name: str = ""

    @property
    def family(self) -> str:
        return self.description.split(":")[0]


class Draw(random.Random):
    turn = 0

    def cycle(self, options):
        order = random.Random(len(options)).sample(range(len(options)), len(options))
        return options[order[self.turn % len(options)]]


# ---------------------------------------------------------------------------------------------- valid inputs

class Surfaces:
    """The valid files of the new kinds (built once per worker beside ``fuzz_inputs.Base``): meshes in five
    formats, the asset as compressed PLY and .splat, a clip folder (PNG frames, poses, a video), a longer job for
    the kill cases; and the references the misread checks compare with (filled by ``warm_up``)."""

    def __init__(self, base):
        import trimesh
        from PIL import Image

        from tests.backend.mesh import mesh_fixtures as MF
        from tests.core.splats import splat_fixtures as SF
        from scpainter_blender.core.splats import compressed, reader as splats_io

        self.base = base
        self.folder = os.path.join(base.folder, "surfaces")
        os.makedirs(self.folder, exist_ok=True)
        # meshes: the car-like object, one texture cell per face (so missing textures change the colours)
        m = MF.car_like_zup()
        V, Fc = MF.split_triangles(m.vertices, m.faces)
        img, uv_in = MF.cell_texture(np.array([[200, 30, 30], [30, 200, 30], [30, 30, 200], [200, 200, 30],
                                               [30, 200, 200], [200, 30, 200]], np.uint8))
        uv = np.zeros((len(V), 2))
        for f in range(len(Fc)):
            uv[Fc[f]] = uv_in(f % 6, 3)
        Vy = V @ MF.R_GLTF  # Y-up file coordinates (p_zup = R p_file)
        tex = trimesh.Trimesh(Vy, Fc, visual=trimesh.visual.TextureVisuals(uv=uv, image=img), process=False)
        buf = io.BytesIO()
        img.save(buf, format="PNG")
        self.texture = buf.getvalue()
        self.meshes = {}   # fmt -> {relative name: bytes}; the first name is the mesh
        self.meshes["glb"] = {"car.glb": trimesh.exchange.gltf.export_glb(trimesh.Scene(tex))}
        files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(tex))
        gl = json.loads(files.pop("model.gltf"))
        image_view = gl["images"][0].pop("bufferView")     # the texture as its own file, as exporters often do
        gl["images"][0] = {"uri": "tex.png", "mimeType": "image/png"}
        gl["bufferViews"][image_view]["byteLength"] = gl["bufferViews"][image_view]["byteLength"]  # (kept)
        self.meshes["gltf"] = {"car.gltf": json.dumps(gl).encode(), "tex.png": self.texture,
                               **{k: v for k, v in files.items()}}
        obj, extra = trimesh.exchange.obj.export_obj(tex, include_texture=True, return_texture=True)
        self.meshes["obj"] = {"car.obj": obj.encode(), **extra}
        off = trimesh.exchange.off.export_off(trimesh.Trimesh(V, Fc, process=False))  # unmerged: V rows as counted
        self.meshes["off"] = {"car.off": off.encode()}
        cols = np.tile(np.array([[180, 40, 40, 255]], np.uint8), (len(V), 1))
        self.meshes["ply"] = {"car.ply": trimesh.exchange.ply.export_ply(
            trimesh.Trimesh(V, Fc, vertex_colors=cols, process=False), encoding="binary")}
        self.mesh_faces, self.mesh_vertices = len(Fc), len(V)
        # Gaussian formats of the job's asset
        p = os.path.join(self.folder, "car.compressed.ply")
        g = base.gaussians
        SF.write_compressed_ply(p, g.xyz, g.scale, g.rot, g.f_dc, g.opacity)
        with open(p, "rb") as f:
            self.compressed = f.read()
        self.compressed_raw = splats_io.read(p)
        p = os.path.join(self.folder, "car.splat")
        compressed.write_splat(p, g)
        with open(p, "rb") as f:
            self.splat = f.read()
        self.splat_raw = splats_io.read(p)
        # a clip: S = 2 frames of 32 x 24 PNG, poses, the base predictions, and the same frames as a video
        from backend.generate.video import write_mp4

        rng = np.random.default_rng(9)
        self.clip_frames = [rng.integers(0, 255, (24, 32, 3), np.uint8) for _ in range(2)]
        self.clip_pngs = []
        for fr in self.clip_frames:
            b = io.BytesIO()
            Image.fromarray(fr).save(b, format="PNG")
            self.clip_pngs.append(b.getvalue())
        mp4 = os.path.join(self.folder, "drive.mp4")
        write_mp4(mp4, np.stack(self.clip_frames), 10.0)
        with open(mp4, "rb") as f:
            self.clip_video = f.read()
        mp4 = os.path.join(self.folder, "drive3.mp4")
        write_mp4(mp4, np.stack(self.clip_frames + self.clip_frames[:1]), 10.0)
        with open(mp4, "rb") as f:
            self.clip_video3 = f.read()
        job = base.job
        K = np.array([f["K"] for f in job["frames"]]) * np.array([[2.0], [2.0], [1.0]])  # 32 x 24 frames
        self.poses = {"world_to_camera": np.array([f["world_to_camera"] for f in job["frames"]]), "K": K,
                      "vggt_to_world": np.array(job["scene"]["vggt_to_world"], np.float64)}
        self.clip_json = {"schema": "scpainter.clip/1", "predictions": "predictions.npz",
                          "frames": "frames/frame_{:06d}.png", "poses": "poses.npz", "fps": 10}
        self.refs = {}     # what warm_up measured on the valid inputs
        self._splat2 = None

    @property
    def splat2(self):
        """The issue-31 formats' valid files and raw values (``fuzz_splat_formats.Bases``), built on first use."""
        if self._splat2 is None:
            import fuzz_splat_formats
            self._splat2 = fuzz_splat_formats.Bases(self.base, os.path.join(self.folder, "splat2"))
        return self._splat2


_SURFACES = {}


def surfaces(base) -> Surfaces:
    if base.folder not in _SURFACES:
        _SURFACES[base.folder] = Surfaces(base)
    return _SURFACES[base.folder]


def _npz(arrays, deflate=False) -> bytes:
    b = io.BytesIO()
    (np.savez_compressed if deflate else np.savez)(b, **arrays)
    return b.getvalue()


# ---------------------------------------------------------------------------------------------- mesh mutations

def _mesh_main(fmt):
    return {"glb": "car.glb", "gltf": "car.gltf", "obj": "car.obj", "off": "car.off", "ply": "car.ply"}[fmt]


def _m(c):
    return os.path.join("job", _mesh_main(c.fmt))


def _text_lines(c, rel):
    return c.read(rel).decode().split("\n")


def _gltf(c):
    return json.loads(c.read(_m(c)))


def _put_gltf(c, gl, raw=None):
    c.write(_m(c), raw if raw is not None else json.dumps(gl))


def _glb_split(data: bytes):
    """(json dict, bin bytes) of a GLB."""
    n = struct.unpack_from("<I", data, 12)[0]
    js = json.loads(data[20:20 + n])
    binlen = struct.unpack_from("<I", data, 20 + n)[0]
    return js, data[28 + n:28 + n + binlen]


def _glb_join(js: dict, binary: bytes) -> bytes:
    """A GLB of a glTF JSON dict and its BIN chunk (``splat_fixtures.glb``, the tests' one GLB writer)."""
    from tests.core.splats import splat_fixtures as SF

    return SF.glb(js, binary)


def _gltf_doc(c):
    """(json, bin getter, setter) for either glTF flavour."""
    if c.fmt == "glb":
        return _glb_split(c.read(_m(c)))
    return _gltf(c), None


def _gltf_save(c, js, binary=None):
    if c.fmt == "glb":
        c.write(_m(c), _glb_join(js, binary if binary is not None else _glb_split(c.read(_m(c)))[1]))
    else:
        _put_gltf(c, js)


def _index_accessor(js):
    return js["meshes"][0]["primitives"][0]["indices"]


def _set_index(c, value):
    """Face index number 0 of the first primitive (in the data) set to ``value`` (wrapped to the stored type)."""
    js, binary = _gltf_doc(c)
    acc = js["accessors"][_index_accessor(js)]
    view = js["bufferViews"][acc["bufferView"]]
    fmt = {5121: "<B", 5123: "<H", 5125: "<I"}[acc["componentType"]]
    off = view.get("byteOffset", 0) + acc.get("byteOffset", 0) + 3 * struct.calcsize(fmt)
    v = value % (1 << (8 * struct.calcsize(fmt)))
    if c.fmt == "glb":
        binary = bytearray(binary)
        struct.pack_into(fmt, binary, off, v)
        _gltf_save(c, js, bytes(binary))
    else:
        rel = os.path.join("job", js["buffers"][view["buffer"]]["uri"])
        data = bytearray(c.read(rel))
        struct.pack_into(fmt, data, off, v)
        c.write(rel, bytes(data))


def _mesh_indices(rng, c_fmt):
    n = 16  # vertices referenced: any index >= the vertex count is out of range
    fmt = c_fmt
    kind = rng.cycle(["just past", "far past", "negative", "2^31-1"])
    value = {"just past": None, "far past": 10 ** 6, "negative": -1, "2^31-1": BIG - 1}[kind]

    def apply(c):
        nv = c.s.mesh_vertices
        v = nv if value is None else value
        if fmt in ("glb", "gltf"):
            _set_index(c, v)
        elif fmt == "obj":
            lines = _text_lines(c, _m(c))
            i = next(k for k, x in enumerate(lines) if x.startswith("f "))
            parts = lines[i].split()
            vv = v + 1 if v >= 0 else 0   # OBJ counts from 1; negative indices are relative (legal): 0 is not
            parts[1] = "/".join([str(vv)] + parts[1].split("/")[1:])
            lines[i] = " ".join(parts)
            c.write(_m(c), "\n".join(lines))
        elif fmt == "off":
            lines = _text_lines(c, _m(c))
            i = 2 + nv
            parts = lines[i].split()
            parts[1] = str(v)
            lines[i] = " ".join(parts)
            c.write(_m(c), "\n".join(lines))
        else:
            data = bytearray(c.read(_m(c)))
            end = data.index(b"end_header\n") + 11
            head = data[:end].decode()
            vstride = _ply_vertex_stride(head)
            off = end + nv * vstride + 1    # first face: uchar count, then int indices
            struct.pack_into("<i", data, off, v)
            c.write(_m(c), bytes(data))
    del n
    return f"indices: {fmt} face index {kind}", apply, "refuse"


def _ply_vertex_stride(head: str) -> int:
    sizes = {"float": 4, "double": 8, "uchar": 1, "char": 1, "int": 4, "uint": 4, "short": 2, "ushort": 2,
             "float32": 4, "uint8": 1, "int32": 4}
    stride, in_vertex = 0, False
    for line in head.splitlines():
        if line.startswith("element"):
            in_vertex = line.split()[1] == "vertex"
        elif line.startswith("property") and in_vertex and "list" not in line:
            stride += sizes[line.split()[1]]
    return stride


def _mesh_counts(rng, fmt):
    kind = rng.cycle(["huge", "one more", "double"])

    def grow(n):
        return {"huge": 10 ** 9, "one more": n + 1, "double": 2 * n}[kind]

    def apply(c):
        if fmt in ("glb", "gltf"):
            js, binary = _gltf_doc(c)
            which = rng.choice(["indices", "position", "unviewed"])
            prim = js["meshes"][0]["primitives"][0]
            if which == "unviewed":   # an accessor without a buffer view: zeros by the specification
                a = js["accessors"][prim["attributes"]["TEXCOORD_0"]]
                a.pop("bufferView", None)
                a.pop("byteOffset", None)
                a["count"] = grow(a["count"])
            else:
                a = js["accessors"][prim["indices"] if which == "indices" else prim["attributes"]["POSITION"]]
                a["count"] = grow(a["count"])
            _gltf_save(c, js, binary)
        elif fmt == "off":
            lines = _text_lines(c, _m(c))
            nv, nf, ne = lines[1].split()
            lines[1] = f"{nv} {grow(int(nf))} {ne}" if rng.random() < 0.5 else f"{grow(int(nv))} {nf} {ne}"
            c.write(_m(c), "\n".join(lines))
        elif fmt == "ply":
            data = c.read(_m(c))
            end = data.index(b"end_header\n")
            head = data[:end].decode()
            el = rng.choice(["vertex", "face"])
            n = int(head.split(f"element {el} ")[1].split()[0])
            head = head.replace(f"element {el} {n}", f"element {el} {grow(n)}")
            c.write(_m(c), head.encode() + data[end:])
        else:   # OBJ has no counts: a face naming a vertex beyond the file
            lines = _text_lines(c, _m(c))
            lines.append(f"f 1 2 {grow(c.s.mesh_vertices)}")
            c.write(_m(c), "\n".join(lines))
    return f"counts: {fmt} count {kind}", apply, "refuse"


def _mesh_truncated(rng, fmt):
    frac = rng.cycle([0.1, 0.35, 0.5, 0.8, 0.97])

    def apply(c):
        rel = _m(c)
        if fmt == "gltf":
            rel = os.path.join("job", rng.choice(sorted(k for k in c.s.meshes["gltf"] if k.endswith(".bin"))))
        data = c.read(rel)
        cut = max(1, int(len(data) * frac))
        if fmt in ("obj", "off"):   # text formats cut in the middle of a number
            cut = max(1, int(len(data) * frac))
        c.write(rel, data[:cut])
    # OBJ cut at a line is still an OBJ: any clean outcome; the binary formats and OFF (counts) must refuse
    return f"truncated: {fmt} cut at {frac:.0%}", apply, (None if fmt == "obj" else "refuse")


def _mesh_nan(rng, fmt):
    what = rng.cycle(["some positions", "all positions", "texture coordinates", "one position inf"])

    def apply(c):
        if fmt in ("glb", "gltf"):
            js, binary = _gltf_doc(c)
            prim = js["meshes"][0]["primitives"][0]
            acc = js["accessors"][prim["attributes"]["TEXCOORD_0" if what == "texture coordinates" else "POSITION"]]
            view = js["bufferViews"][acc["bufferView"]]
            start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
            n = acc["count"] * (2 if what == "texture coordinates" else 3)
            value = float("inf") if "inf" in what else float("nan")
            every = 1 if what in ("all positions", "texture coordinates") else 7
            if "one" in what:
                every = n + 1
            if c.fmt == "glb":
                data = bytearray(binary)
            else:
                rel = os.path.join("job", js["buffers"][view["buffer"]]["uri"])
                data = bytearray(c.read(rel))
            for i in range(0, n, every):
                struct.pack_into("<f", data, start + 4 * i, value)
            if what != "texture coordinates":   # the accessor's min/max must not be what refuses it
                acc.pop("min", None)
                acc.pop("max", None)
            if c.fmt == "glb":
                _gltf_save(c, js, bytes(data))
            else:
                c.write(rel, bytes(data))
                _gltf_save(c, js)
        elif fmt in ("obj", "off"):
            lines = _text_lines(c, _m(c))
            prefix = {"texture coordinates": "vt ", "all positions": "v ", "some positions": "v ",
                      "one position inf": "v "}[what] if fmt == "obj" else None
            rows = ([k for k, x in enumerate(lines) if x.startswith(prefix)] if fmt == "obj"
                    else list(range(2, 2 + c.s.mesh_vertices)))
            if what == "texture coordinates" and fmt == "off":
                rows = rows[::5]
            step = 1 if what in ("all positions", "texture coordinates") else 7
            rows = rows[:1] if "one" in what else rows[::step]
            for k in rows:
                p = lines[k].split()
                lead = 1 if fmt == "obj" else 0
                p[lead] = "inf" if "inf" in what else "nan"
                lines[k] = " ".join(p)
            c.write(_m(c), "\n".join(lines))
        else:
            data = bytearray(c.read(_m(c)))
            end = data.index(b"end_header\n") + 11
            stride = _ply_vertex_stride(data[:end].decode())
            for v in range(0, c.s.mesh_vertices, 1 if what in ("all positions", "texture coordinates") else 7):
                struct.pack_into("<f", data, end + v * stride, float("inf") if "inf" in what else float("nan"))
                if "one" in what:
                    break
            c.write(_m(c), bytes(data))
    # all positions NaN: nothing to sample (refuse); NaN texture coordinates: colours from nothing (refuse or warn)
    expect = "refuse" if what in ("all positions",) or (what == "texture coordinates" and fmt in ("glb", "gltf",
                                                                                                  "obj")) else None
    return f"nan: {fmt} {what}", apply, expect


def _named_files(fmt):
    return {"gltf": ["tex.png", "gltf_buffer_0.bin", "gltf_buffer_1.bin"], "obj": ["material.mtl", "material_0.png"]
            }.get(fmt, [])


def _mesh_named(rng, fmt):
    rel = rng.choice(_named_files(fmt))
    how = rng.cycle(["missing", "a folder", "a FIFO", "a link outside", "garbage", "empty", "a link to itself"])

    def apply(c):
        p = os.path.join("job", rel)
        if how == "missing":
            os.unlink(c.path(p))
        elif how == "a folder":
            c.replace_with(p, "dir")
        elif how == "a FIFO":
            c.replace_with(p, "fifo")
        elif how == "a link outside":
            c.write(os.path.join("outside", rel), c.read(p))
            c.replace_with(p, "link", os.path.join(c.outside, rel))
        elif how == "garbage":
            c.write(p, random.Random(7).randbytes(200))
        elif how == "empty":
            c.write(p, b"")
        else:
            c.replace_with(p, "link", os.path.basename(p))
    # a link outside holding the right file may be read (no harm); every other damage must be refused or warned
    return f"named: {fmt} {rel} {how}", apply, (None if how == "a link outside" else "refuse")


def _mesh_uri(rng, fmt):
    how = rng.cycle(["outside the folder", "absolute", "same name elsewhere", "data URI broken", "empty",
                     "a folder name", "url"])
    target = rng.choice(["tex.png", "gltf_buffer_1.bin"]) if fmt == "gltf" else "material_0.png"

    def apply(c):
        if fmt == "gltf":
            js = _gltf(c)
            entries = js["images"] if target == "tex.png" else js["buffers"]
            entry = entries[0] if target == "tex.png" else entries[1]
        else:
            mtl = c.read("job/material.mtl").decode()
        if how == "outside the folder":
            c.write(os.path.join("outside", target), c.read(os.path.join("job", target)))
            new = f"../outside/{target}"
        elif how == "absolute":
            c.write(os.path.join("outside", target), c.read(os.path.join("job", target)))
            new = os.path.join(c.outside, target)
        elif how == "same name elsewhere":   # the named file is missing; another one of that base name is there
            data = bytearray(c.read(os.path.join("job", target)))
            if target.endswith(".bin"):
                arr = np.frombuffer(bytes(data), "<f4") * 10.0   # a car ten times as large
                data = bytearray(arr.astype("<f4").tobytes())
            else:
                from PIL import Image
                b = io.BytesIO()
                Image.new("RGB", (4, 4), (255, 255, 0)).save(b, format="PNG")
                data = b.getvalue()
            c.write(os.path.join("job", target), bytes(data))
            new = f"parts/{target}"
        elif how == "data URI broken":
            new = "data:application/octet-stream;base64,@@@@"
        elif how == "empty":
            new = ""
        elif how == "a folder name":
            os.makedirs(c.path("job/parts"), exist_ok=True)
            new = "parts"
        else:
            new = f"https://example.invalid/{target}"
        if fmt == "gltf":
            entry["uri"] = new
            _put_gltf(c, js)
        else:
            c.write("job/material.mtl", mtl.replace("map_Kd material_0.png", f"map_Kd {new}"))
    return f"uri: {fmt} {target} {how}", apply, "refuse"


def _mesh_bomb(rng, fmt):
    side = rng.cycle([20000, 12000, 30000])

    def apply(c):
        from PIL import Image

        b = io.BytesIO()
        Image.new("L", (side, side), 128).save(b, format="PNG", optimize=False, compress_level=9)
        c.write(os.path.join("job", "tex.png" if fmt == "gltf" else "material_0.png"), b.getvalue())
    return f"bomb: {fmt} texture of {side} x {side} px in a small PNG", apply, None


def _gltf_structure(rng, fmt):
    what = rng.cycle(["node is its own child", "two nodes each other's child", "primitive mode points",
                      "componentType 5130", "type MAT4 positions", "no scenes", "scene index 7", "indices float",
                      "mesh index 5", "accessor byteOffset huge", "byteStride 0 < element", "sparse accessor huge",
                      "JSON NaN count", "nested 10000 lists", "bufferView byteLength huge"])

    def apply(c):
        js, binary = _gltf_doc(c)
        prim = js["meshes"][0]["primitives"][0]
        pos = js["accessors"][prim["attributes"]["POSITION"]]
        raw = None
        if what == "node is its own child":
            js["nodes"][0]["children"] = [0]
        elif what == "two nodes each other's child":
            js["nodes"].append({"children": [0]})
            js["nodes"][0]["children"] = [len(js["nodes"]) - 1]
        elif what == "primitive mode points":
            prim["mode"] = 0
        elif what == "componentType 5130":
            pos["componentType"] = 5130
        elif what == "type MAT4 positions":
            pos["type"] = "MAT4"
        elif what == "no scenes":
            js.pop("scenes", None)
            js.pop("scene", None)
        elif what == "scene index 7":
            js["scene"] = 7
        elif what == "indices float":
            js["accessors"][prim["indices"]]["componentType"] = 5126
        elif what == "mesh index 5":
            js["nodes"][0]["mesh"] = 5
        elif what == "accessor byteOffset huge":
            pos["byteOffset"] = 10 ** 9
        elif what == "byteStride 0 < element":
            js["bufferViews"][pos["bufferView"]]["byteStride"] = 4
        elif what == "sparse accessor huge":
            pos["sparse"] = {"count": 10 ** 9, "indices": {"bufferView": pos["bufferView"], "componentType": 5125},
                             "values": {"bufferView": pos["bufferView"]}}
        elif what == "JSON NaN count":
            raw = json.dumps(js).replace(f'"count": {pos["count"]}', '"count": NaN', 1)
        elif what == "nested 10000 lists":
            js["extras"] = "@@"
            raw = json.dumps(js).replace('"@@"', "[" * 10000 + "]" * 10000)
        else:
            js["bufferViews"][pos["bufferView"]]["byteLength"] = 10 ** 12
        if raw is not None:
            if fmt == "glb":
                j = raw.encode()
                j += b" " * (-len(j) % 4)
                binary += b"\0" * (-len(binary) % 4)
                body = struct.pack("<II", len(j), 0x4E4F534A) + j + struct.pack("<II", len(binary), 0x004E4942) \
                    + binary
                c.write(_m(c), struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
            else:
                c.write(_m(c), raw)
        else:
            _gltf_save(c, js, binary)
    return f"structure: {fmt} {what}", apply, None


def _gltf_new_paths(rng, fmt):
    """Issue 31's glTF paths: KHR_texture_transform, texCoord, normalized accessors, Draco."""
    what = rng.cycle(["texture transform offset NaN", "texture transform scale 1e308", "texture transform rotation "
                      "1e300", "texture transform scale [0, 0]", "texture transform offset strings",
                      "texture transform texCoord 3", "texCoord 1 (no second set)", "texCoord -1", "texCoord \"0\"",
                      "TEXCOORD_0 normalized float", "POSITION normalized as bytes", "TEXCOORD_0 as signed ints 5130",
                      "Draco over garbage bytes", "Draco bufferView missing", "Draco attribute ids absent",
                      "Draco mesh with another vertex count", "Draco extension not an object"])

    def apply(c):
        js, binary = _gltf_doc(c)
        prim = js["meshes"][0]["primitives"][0]
        attrs = prim["attributes"]
        tex = js["materials"][0].setdefault("pbrMetallicRoughness", {}).setdefault("baseColorTexture", {"index": 0})
        if what.startswith("texture transform"):
            tt = {"offset NaN": {"offset": [float("nan"), 0]}, "scale 1e308": {"scale": [1e308, 1e308]},
                  "rotation 1e300": {"rotation": 1e300}, "scale [0, 0]": {"scale": [0, 0]},
                  "offset strings": {"offset": ["a", "b"]}, "texCoord 3": {"texCoord": 3}}[what[18:]]
            tex.setdefault("extensions", {})["KHR_texture_transform"] = tt
            js.setdefault("extensionsUsed", []).append("KHR_texture_transform")
        elif what.startswith("texCoord"):
            tex["texCoord"] = {"texCoord 1 (no second set)": 1, "texCoord -1": -1}.get(what, "0")
        elif what == "TEXCOORD_0 normalized float":
            js["accessors"][attrs["TEXCOORD_0"]]["normalized"] = True
        elif what == "POSITION normalized as bytes":
            js["accessors"][attrs["POSITION"]].update(componentType=5121, normalized=True)
        elif what == "TEXCOORD_0 as signed ints 5130":
            js["accessors"][attrs["TEXCOORD_0"]].update(componentType=5130, normalized=True)
        else:
            view = js["accessors"][attrs["POSITION"]]["bufferView"]
            ids = {"POSITION": 0, "TEXCOORD_0": 1}
            if what == "Draco mesh with another vertex count":
                import DracoPy
                blob = DracoPy.encode(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32),
                                      np.array([[0, 1, 2]], np.uint32))
                if binary is None:
                    js["buffers"].append({"uri": "draco.bin", "byteLength": len(blob)})
                    c.write("job/draco.bin", blob)
                    js["bufferViews"].append({"buffer": len(js["buffers"]) - 1, "byteLength": len(blob)})
                else:
                    binary += b"\0" * (-len(binary) % 4)
                    js["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(blob)})
                    binary += blob
                    js["buffers"][0]["byteLength"] = len(binary)
                view = len(js["bufferViews"]) - 1
                ids = {"POSITION": 0}
            ext = {"bufferView": 99 if what == "Draco bufferView missing" else view,
                   "attributes": {"POSITION": 7, "TEXCOORD_0": 8} if what == "Draco attribute ids absent" else ids}
            prim.setdefault("extensions", {})["KHR_draco_mesh_compression"] = (
                "draco" if what == "Draco extension not an object" else ext)
            for key in ("extensionsUsed", "extensionsRequired"):
                js.setdefault(key, []).append("KHR_draco_mesh_compression")
        _gltf_save(c, js, binary)
    return f"gltf paths: {fmt} {what}", apply, None


def _mesh_whole(rng, fmt):
    what = rng.cycle(["empty", "garbage", "a folder", "a FIFO", "another format's bytes", "only a header",
                      "a link outside", "zero bytes but the magic"])

    def apply(c):
        p = _m(c)
        if what == "empty":
            c.write(p, b"")
        elif what == "garbage":
            c.write(p, random.Random(3).randbytes(600))
        elif what == "a folder":
            c.replace_with(p, "dir")
        elif what == "a FIFO":
            c.replace_with(p, "fifo")
        elif what == "another format's bytes":
            other = {"glb": "off", "gltf": "ply", "obj": "glb", "off": "glb", "ply": "off"}[fmt]
            c.write(p, next(iter(c.s.meshes[other].values())))
        elif what == "only a header":
            c.write(p, {"glb": b"glTF\x02\0\0\0\x0c\0\0\0", "gltf": b'{"asset": {"version": "2.0"}}', "obj": b"# x\n",
                        "off": b"OFF\n16 24 0\n", "ply": b"ply\nformat binary_little_endian 1.0\nend_header\n"}[fmt])
        elif what == "a link outside":
            c.write("outside/elsewhere", c.read(p))
            c.replace_with(p, "link", os.path.join(c.outside, "elsewhere"))
        else:
            c.write(p, c.read(p)[:4])
    return f"whole: {fmt} {what}", apply, None


def _mesh_rewrite(rng, fmt):
    options = {"obj": ["CRLF", "comments and blank lines", "tabs and double spaces", "no trailing newline"],
               "off": ["comments and blank lines", "CRLF", "all on few lines", "scientific notation"],
               "gltf": ["indented JSON", "keys in reverse order", "unicode escapes in names"],
               "glb": ["keys in reverse order", "JSON padded with spaces"],
               "ply": ["ASCII", "big endian", "comments in the header", "CRLF header"]}[fmt]
    how = rng.cycle(options)

    def rev(d):
        if isinstance(d, dict):
            return {k: rev(d[k]) for k in reversed(list(d))}
        if isinstance(d, list):
            return [rev(x) for x in d]
        return d

    def apply(c):
        p = _m(c)
        if fmt in ("obj", "off"):
            text = c.read(p).decode()
            lines = text.split("\n")
            if how == "CRLF":
                text = text.replace("\n", "\r\n")
            elif how == "comments and blank lines":
                out = []
                for k, x in enumerate(lines):
                    out.append(x)
                    if k % 3 == 2 and (fmt == "obj" or k >= 2):
                        out += ["# a comment", ""] if fmt == "obj" else ["# a comment"]
                text = "\n".join(out)
            elif how == "tabs and double spaces":
                text = "\n".join(x.replace(" ", " \t ") if not x.startswith(("mtllib", "usemtl")) else x
                                 for x in lines)
            elif how == "no trailing newline":
                text = text.rstrip("\n")
            elif how == "all on few lines":
                nv = c.s.mesh_vertices
                text = "\n".join(lines[:2] + [" ".join(lines[2:2 + nv])] + lines[2 + nv:])
            else:
                text = "\n".join(lines[:2] + [" ".join(f"{float(v):.10e}" for v in x.split())
                                              for x in lines[2:2 + c.s.mesh_vertices]] + lines[2 + c.s.mesh_vertices:])
            c.write(p, text)
        elif fmt in ("gltf", "glb"):
            js, binary = _gltf_doc(c)
            if how == "indented JSON":
                c.write(p, json.dumps(js, indent=3))
            elif how == "keys in reverse order":
                _gltf_save(c, rev(js), binary)
            elif how == "unicode escapes in names":
                js.setdefault("asset", {})["generator"] = "caf\u00e9 \u2603"
                c.write(p, json.dumps(js, ensure_ascii=True))
            else:
                j = json.dumps(js).encode() + b" " * 64
                j += b" " * (-len(j) % 4)
                body = struct.pack("<II", len(j), 0x4E4F534A) + j + struct.pack("<II", len(binary), 0x004E4942) \
                    + binary
                c.write(p, struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
        else:
            import trimesh
            m = trimesh.load(c.path(p), process=False)
            if how == "ASCII":
                c.write(p, trimesh.exchange.ply.export_ply(m, encoding="ascii"))
            elif how == "big endian":
                data = c.read(p)
                end = data.index(b"end_header\n") + 11
                head = data[:end].decode()
                vs = _ply_vertex_stride(head)
                nv = c.s.mesh_vertices
                props = [ln.split() for ln in head.splitlines() if ln.startswith("property")]
                vdt = np.dtype([(x[2], "<" + {"float": "f4", "double": "f8", "uchar": "u1"}[x[1]])
                                for x in props if x[1] != "list"][:len([x for x in props if x[1] != "list"])])
                assert vdt.itemsize == vs
                verts = np.frombuffer(data, vdt, nv, end)
                fdt = np.dtype([("n", "u1"), ("i", "<i4", 3)])
                faces = np.frombuffer(data, fdt, c.s.mesh_faces, end + nv * vs)
                c.write(p, head.replace("binary_little_endian", "binary_big_endian").encode()
                        + verts.astype(vdt.newbyteorder(">")).tobytes() + faces.astype(fdt.newbyteorder(">")).tobytes())
            elif how == "comments in the header":
                data = c.read(p)
                c.write(p, data.replace(b"\nelement", b"\ncomment made elsewhere\nelement", 1))
            else:
                data = c.read(p)
                end = data.index(b"end_header\n") + 11
                c.write(p, data[:end].replace(b"\n", b"\r\n") + data[end:])
    return f"rewrite: {fmt} {how}", apply, "same"


def _format_family(make, formats):
    """A family whose cases cycle through ``formats`` (mesh or splat file formats): ``make(rng, fmt)``."""
    def fam(rng):
        fmt = rng.cycle(formats) if len(formats) > 1 else formats[0]
        rng.turn //= max(1, len(formats))
        d, apply, expect = make(rng, fmt)
        return d, apply, expect, fmt
    return fam



MESH_FAMILIES = [(_format_family(_mesh_indices, FORMATS), 3), (_format_family(_mesh_counts, FORMATS), 3),
                 (_format_family(_mesh_truncated, FORMATS), 2), (_format_family(_mesh_nan, FORMATS), 3),
                 (_format_family(_mesh_named, ("gltf", "obj")), 3), (_format_family(_mesh_uri, ("gltf", "obj")), 3),
                 (_format_family(_mesh_bomb, ("gltf", "obj")), 1), (_format_family(_gltf_structure, ("glb", "gltf")), 3),
                 (_format_family(_gltf_new_paths, ("glb", "gltf")), 2),
                 (_format_family(_mesh_whole, FORMATS), 2), (_format_family(_mesh_rewrite, FORMATS), 4)]


# ---------------------------------------------------------------------------------------------- splat mutations

def _asset_rel(fmt):
    return "job/car.ply" if fmt == "compressed" else "job/car.splat"


def _splat_size(rng, fmt):
    what = rng.cycle(["cut mid-record", "cut at a record", "empty", "one byte", "doubled", "31 bytes"])

    def apply(c):
        data = c.read(_asset_rel(fmt))
        out = {"cut mid-record": data[:len(data) - 13], "cut at a record": data[:len(data) - 64], "empty": b"",
               "one byte": data[:1], "doubled": data + data, "31 bytes": data[:31]}[what]
        c.write(_asset_rel(fmt), out)
    return f"size: {fmt} {what}", apply, None


def _splat_values(rng, fmt):
    what = rng.cycle(["all NaN positions", "all zero scales", "all zero quaternions", "some NaN positions",
                      "some negative scales", "all alpha 0", "inf positions everywhere"])
    every = what.startswith("all") or "everywhere" in what

    def apply(c):
        data = bytearray(c.read(_asset_rel(fmt)))
        rec = np.frombuffer(bytes(data), np.dtype([("xyz", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4),
                                                    ("rot", "u1", 4)])).copy()
        sel = slice(None) if every else slice(None, None, 3)
        if "NaN positions" in what:
            rec["xyz"][sel] = np.nan
        elif "inf" in what:
            rec["xyz"][sel] = np.inf
        elif "zero scales" in what:
            rec["scale"][sel] = 0
        elif "negative" in what:
            rec["scale"][sel] = -1
        elif "quaternions" in what:
            rec["rot"][sel] = 128
        else:
            rec["rgba"][sel, 3] = 0
        c.write(_asset_rel(fmt), rec.tobytes())
    # every Gaussian invalid: an asset that renders as nothing must be refused or warned about
    expect = "refuse" if every and "alpha" not in what else None
    return f"values: splat {what}", apply, expect


def _compressed_parts(data):
    """(the header's lines, end_header the last, the body)"""
    end = data.index(b"end_header\n") + 11
    return data[:end].decode().split("\n")[:-1], data[end:]


def _compressed_header(rng, fmt):
    what = rng.cycle(["fewer chunks", "more chunks", "vertex count larger", "vertex count 10^9", "no chunk element",
                      "packed_rotation missing", "packed words as float", "packed words as int",
                      "chunk property double", "extra sh element", "sh with 10 coefficients",
                      "elements swapped", "min_x missing", "chunk count 0"])

    def apply(c):
        lines, body = _compressed_parts(c.read(_asset_rel(fmt)))
        lines = lines[:-1]   # the header without its end_header line (written again below, once)
        nchunk = int(next(x for x in lines if x.startswith("element chunk")).split()[2])
        nvert = int(next(x for x in lines if x.startswith("element vertex")).split()[2])
        text = "\n".join(lines)
        if what == "fewer chunks":
            text = text.replace(f"element chunk {nchunk}", f"element chunk {max(0, nchunk - 1)}")
        elif what == "more chunks":
            text = text.replace(f"element chunk {nchunk}", f"element chunk {nchunk + 3}")
        elif what == "vertex count larger":
            text = text.replace(f"element vertex {nvert}", f"element vertex {nvert + 5}")
        elif what == "vertex count 10^9":
            text = text.replace(f"element vertex {nvert}", "element vertex 1000000000")
        elif what == "no chunk element":
            text = "\n".join(x for x in lines if not (x.startswith("element chunk") or
                                                       (x.startswith("property float") and "packed" not in x)))
            body = body[nchunk * 18 * 4:]
        elif what == "packed_rotation missing":
            text = text.replace("property uint packed_rotation\n", "")
        elif what == "packed words as float":
            text = text.replace("property uint packed_", "property float packed_")
        elif what == "packed words as int":
            text = text.replace("property uint packed_", "property int packed_")
        elif what == "chunk property double":
            text = text.replace("property float min_x", "property double min_x")
        elif what == "extra sh element":
            text += f"\nelement sh {nvert}\nproperty uchar f_rest_0"
        elif what == "sh with 10 coefficients":
            text += f"\nelement sh {nvert}\n" + "\n".join(f"property uchar f_rest_{i}" for i in range(10))
            body += bytes(10 * nvert)
        elif what == "elements swapped":
            ci = [k for k, x in enumerate(lines) if x.startswith("element")]
            a, b = lines[ci[0]:ci[1]], lines[ci[1]:]
            text = "\n".join(lines[:ci[0]] + b + a)
        elif what == "min_x missing":
            text = text.replace("property float min_x\n", "")
        else:
            text = text.replace(f"element chunk {nchunk}", "element chunk 0")
        c.write(_asset_rel(fmt), (text + "\nend_header\n").encode() + body)
    # "packed words as int": the reader takes int32 words as their bits (the same values)
    return f"header: compressed {what}", apply, ("same" if what == "packed words as int" else None)


def _compressed_values(rng, fmt):
    what = rng.cycle(["all chunk ranges NaN", "one chunk range NaN", "ranges inf", "min above max",
                      "all rotation words 0", "all words 0xFFFFFFFF", "scale range 1e30"])

    def apply(c):
        data = c.read(_asset_rel(fmt))
        lines, body = _compressed_parts(data)
        nchunk = int(next(x for x in lines if x.startswith("element chunk")).split()[2])
        nprop = sum(1 for x in lines if x.startswith("property float"))
        nvert = int(next(x for x in lines if x.startswith("element vertex")).split()[2])
        table = np.frombuffer(body, "<f4", nchunk * nprop).reshape(nchunk, nprop).copy()
        words = np.frombuffer(body, "<u4", nvert * 4, nchunk * nprop * 4).reshape(nvert, 4).copy()
        if what == "all chunk ranges NaN":
            table[:, :6] = np.nan
        elif what == "one chunk range NaN":
            table[:, 0] = np.nan
        elif what == "ranges inf":
            table[:, 3:6] = np.inf
        elif what == "min above max":
            table[:, :3], table[:, 3:6] = table[:, 3:6].copy(), table[:, :3].copy()
        elif what == "all rotation words 0":
            words[:, 1] = 0
        elif what == "all words 0xFFFFFFFF":
            words[:] = 0xFFFFFFFF
        else:
            table[:, 6:12] = 1e30
        head = ("\n".join(lines) + "\n").encode()
        c.write(_asset_rel(fmt), head + table.astype("<f4").tobytes() + words.astype("<u4").tobytes()
                + body[nchunk * nprop * 4 + nvert * 16:])
    # NaN position ranges for every chunk: every Gaussian is invalid
    expect = "refuse" if what in ("all chunk ranges NaN", "scale range 1e30") else None
    return f"values: compressed {what}", apply, expect


def _splat_rewrite(rng, fmt):
    options = (["comments in the header", "CRLF-free comment with end_header words", "obj_info lines"]
               if fmt == "compressed" else ["extension in capitals", "a copy named .splat under another folder"])
    how = rng.cycle(options)

    def apply(c):
        rel = _asset_rel(fmt)
        data = c.read(rel)
        if how == "comments in the header":
            c.write(rel, data.replace(b"\nelement chunk", b"\ncomment exported\nelement chunk", 1))
        elif how == "CRLF-free comment with end_header words":
            c.write(rel, data.replace(b"\nelement chunk", b"\ncomment the end_header is below\nelement chunk", 1))
        elif how == "obj_info lines":
            c.write(rel, data.replace(b"\nelement chunk", b"\nobj_info made by a test\nelement chunk", 1))
        elif how == "extension in capitals":
            os.unlink(c.path(rel))
            c.write("job/car.SPLAT", data)
            c.job["assets"][0]["ply"] = "car.SPLAT"
        else:
            os.unlink(c.path(rel))
            c.write("job/sub/car.splat", data)
            c.job["assets"][0]["ply"] = "sub/car.splat"
    return f"rewrite: {fmt} {how}", apply, "same"


SPLAT_FAMILIES = [(_format_family(_splat_size, ("splat", "compressed")), 2),
                  (_format_family(_splat_values, ("splat",)), 2), (_format_family(_compressed_header, ("compressed",)), 3),
                  (_format_family(_compressed_values, ("compressed",)), 2),
                  (_format_family(_splat_rewrite, ("compressed", "splat")), 2)]


# ---------------------------------------------------------------------------------------------- exr mutations

def _exr_rel(frame):
    return f"job/out/conditions/frame_{frame:06d}.exr"


def _read_layers(c, frame):
    from backend.render import channels
    return channels.read(c.path(_exr_rel(frame)))


def _write_exr(path, channels_, header=None):
    import OpenEXR

    h = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **(header or {})}
    img = OpenEXR.File(h, {k: np.ascontiguousarray(v) for k, v in channels_.items()})
    if os.path.lexists(path):
        os.unlink(path)
    img.write(path)


def _file_channels(layers, prefix=""):
    from backend.render import channels
    return {prefix + channels.FILE_NAMES[k]: v.astype(np.float32) for k, v in layers.items()}


def _exr_size(rng):
    shape = rng.cycle([(12, 20), (10, 16), (24, 32), (1, 1), (12, 17), (6, 8)])
    frame = rng.choice([1, 2])

    def apply(c):
        layers = _read_layers(c, frame)
        H, W = shape
        out = {k: np.resize(v, (H, W)).astype(np.float32) for k, v in layers.items()}
        _write_exr(c.path(_exr_rel(frame)), _file_channels(out))
    return f"size: frame {frame} EXR of {shape[1]} x {shape[0]} (the job: 16 x 12)", apply, "refuse"


def _exr_channels(rng):
    what = rng.cycle(["image.G missing", "hole missing", "asset_mask missing", "only depth", "extra channels",
                      "hole as UINT", "image as HALF", "hole.Y renamed hole.V", "channels in another case"])
    frame = rng.choice([1, 2])

    def apply(c):
        layers = _read_layers(c, frame)
        ch = _file_channels(layers)
        if what == "image.G missing":
            ch.pop("image.G")
        elif what == "hole missing":
            ch.pop("hole.Y")
        elif what == "asset_mask missing":
            ch.pop("asset_mask.Y")
        elif what == "only depth":
            ch = {"depth.Z": ch["depth.Z"]}
        elif what == "extra channels":
            ch["extra.Y"] = np.zeros_like(ch["hole.Y"])
        elif what == "hole as UINT":
            ch["hole.Y"] = ch["hole.Y"].astype(np.uint32)
        elif what == "image as HALF":
            for k in ("image.R", "image.G", "image.B"):
                ch[k] = ch[k].astype(np.float16)
        elif what == "hole.Y renamed hole.V":
            ch["hole.V"] = ch.pop("hole.Y")
        else:
            ch["IMAGE.R"] = ch.pop("image.R")
        _write_exr(c.path(_exr_rel(frame)), ch)
    return f"channels: frame {frame} {what}", apply, None


def _exr_values(rng):
    what = rng.cycle(["NaN image", "inf image", "negative image", "hole 0.5 everywhere", "hole NaN",
                      "asset mask 7"])

    def apply(c):
        layers = _read_layers(c, 1)
        if what == "NaN image":
            layers["R"][:] = np.nan
        elif what == "inf image":
            layers["G"][::2] = np.inf
        elif what == "negative image":
            layers["B"][:] = -3
        elif what == "hole 0.5 everywhere":
            layers["hole"][:] = 0.5
        elif what == "hole NaN":
            layers["hole"][:] = np.nan
        else:
            layers["asset_mask"][:] = 7
        _write_exr(c.path(_exr_rel(1)), _file_channels(layers))
    # values the renderer never writes (non-finite, outside [0, 1]) must be refused; a soft hole is valid data
    return f"values: frame 1 {what}", apply, (None if what == "hole 0.5 everywhere" else "refuse")


def _exr_file(rng):
    what = rng.cycle(["cut at 30%", "cut at 90%", "cut after the header", "garbage", "empty", "a folder", "a FIFO",
                      "a link outside", "missing", "a link to the other frame", "zlib data damaged"])
    frame = rng.choice([1, 2])

    def apply(c):
        rel = _exr_rel(frame)
        data = c.read(rel)
        if what.startswith("cut"):
            frac = {"cut at 30%": 0.3, "cut at 90%": 0.9, "cut after the header": None}[what]
            cut = int(len(data) * frac) if frac else data.index(b"\0\0", 300) if b"\0\0" in data[300:] else 320
            c.write(rel, data[:cut])
        elif what == "garbage":
            c.write(rel, random.Random(5).randbytes(len(data)))
        elif what == "empty":
            c.write(rel, b"")
        elif what == "a folder":
            c.replace_with(rel, "dir")
        elif what == "a FIFO":
            c.replace_with(rel, "fifo")
        elif what == "a link outside":
            c.write("outside/elsewhere.exr", data)
            c.replace_with(rel, "link", os.path.join(c.outside, "elsewhere.exr"))
        elif what == "missing":
            os.unlink(c.path(rel))
        elif what == "a link to the other frame":
            c.replace_with(rel, "link", f"frame_{3 - frame:06d}.exr")
        else:
            b = bytearray(data)
            for i in range(len(b) - 40, len(b) - 8):
                b[i] ^= 0x5A
            c.write(rel, bytes(b))
    return f"file: frame {frame} {what}", apply, None


def _exr_rewrite(rng):
    how = rng.cycle(["NO compression", "RLE", "ZIPS", "PIZ", "tiled 8x8", "channels as flat names", "Blender prefix",
                     "PXR24 on depth only", "two frames swapped back"])

    def apply(c):
        import OpenEXR

        for frame in (1, 2):
            layers = _read_layers(c, frame)
            comp = {"NO compression": OpenEXR.NO_COMPRESSION, "RLE": OpenEXR.RLE_COMPRESSION,
                    "ZIPS": OpenEXR.ZIPS_COMPRESSION, "PIZ": OpenEXR.PIZ_COMPRESSION}.get(how, OpenEXR.ZIP_COMPRESSION)
            header = {"compression": comp}
            if how == "tiled 8x8":
                tiles = OpenEXR.TileDescription()
                tiles.xSize, tiles.ySize = 8, 8
                header = {"type": OpenEXR.tiledimage, "tiles": tiles}
            if how == "channels as flat names":
                ch = {"R": layers["R"], "G": layers["G"], "B": layers["B"], "hole": layers["hole"],
                      "asset_mask": layers["asset_mask"], "Z": layers["Z"], "instance": layers["instance"]}
            else:
                ch = _file_channels(layers, "ViewLayer." if how == "Blender prefix" else "")
            if how == "two frames swapped back":
                ch = dict(reversed(list(ch.items())))
            _write_exr(c.path(_exr_rel(frame)), ch, header)
    return f"rewrite: {how}", apply, "same"


EXR_FAMILIES = [(_exr_size, 3), (_exr_channels, 2), (_exr_values, 1), (_exr_file, 3), (_exr_rewrite, 2)]


# ---------------------------------------------------------------------------------------------- clip mutations

def _poses_case(rng):
    what = rng.cycle(["fx 1e30", "fx 1e-30", "cx 1e12", "K NaN", "K shape (2, 3, 3)", "K missing", "K as strings",
                      "world_to_camera scaled", "vggt_to_world singular", "K as object array", "fy negative",
                      "K of 3 frames", "K int8 overflowed"])

    def apply(c):
        p = {k: v.copy() for k, v in c.s.poses.items()}
        allow_pickle = False
        if what == "fx 1e30":
            p["K"][:, 0, 0] = 1e30
        elif what == "fx 1e-30":
            p["K"][:, 0, 0] = 1e-30
        elif what == "cx 1e12":
            p["K"][:, 0, 2] = 1e12
        elif what == "K NaN":
            p["K"][0, 1, 1] = np.nan
        elif what == "K shape (2, 3, 3)":
            p["K"] = p["K"][:, :2]
        elif what == "K missing":
            p.pop("K")
        elif what == "K as strings":
            p["K"] = p["K"].astype(str)
        elif what == "world_to_camera scaled":
            p["world_to_camera"][:, :3, :3] *= 2
        elif what == "vggt_to_world singular":
            p["vggt_to_world"][:3, :3] = 0
        elif what == "K as object array":
            p["K"] = p["K"].astype(object)
            allow_pickle = True
        elif what == "fy negative":
            p["K"][:, 1, 1] *= -1
        elif what == "K of 3 frames":
            p["K"] = np.concatenate([p["K"], p["K"][:1]])
        else:
            p["K"] = np.full((2, 3, 3), 100, np.int8)
        del allow_pickle   # np.savez pickles an object array itself; the reader must refuse it
        c.write("job/poses.npz", _npz(p))
    expect = "refuse" if what in ("fx 1e30", "fx 1e-30", "cx 1e12") else None
    return f"poses: {what}", apply, expect, "poses.npz"


def _frames_case(rng):
    what = rng.cycle(["frame 1 missing", "frame 0 truncated", "frame 1 garbage", "frame 0 a folder",
                      "frame 1 a FIFO", "frame 1 of another size", "frame 0 16-bit grey", "frame 1 RGBA",
                      "frame 0 a 30000 x 30000 PNG", "frame 1 empty", "frame 0 a JPEG named .png",
                      "frame 1 a link outside"])

    def apply(c):
        from PIL import Image

        t = int(what.split()[1])
        rel = f"job/frames/frame_{t:06d}.png"
        if what.endswith("missing"):
            os.unlink(c.path(rel))
        elif "truncated" in what:
            c.write(rel, c.read(rel)[:len(c.read(rel)) // 2])
        elif "garbage" in what:
            c.write(rel, random.Random(2).randbytes(500))
        elif "folder" in what:
            c.replace_with(rel, "dir")
        elif "FIFO" in what:
            c.replace_with(rel, "fifo")
        elif "empty" in what:
            c.write(rel, b"")
        elif "link outside" in what:
            c.write("outside/frame.png", c.read(rel))
            c.replace_with(rel, "link", os.path.join(c.outside, "frame.png"))
        else:
            b = io.BytesIO()
            if "another size" in what:
                Image.fromarray(c.s.clip_frames[t]).resize((40, 20)).save(b, format="PNG")
            elif "16-bit" in what:
                Image.fromarray((c.s.clip_frames[t][..., 0].astype(np.uint16) * 257)).save(b, format="PNG")
            elif "RGBA" in what:
                Image.fromarray(c.s.clip_frames[t]).convert("RGBA").save(b, format="PNG")
            elif "JPEG" in what:
                Image.fromarray(c.s.clip_frames[t]).save(b, format="JPEG")
            else:
                Image.new("L", (30000, 30000), 0).save(b, format="PNG", compress_level=9)
            c.write(rel, b.getvalue())
    return f"frames: {what}", apply, None, ""


def _video_case(rng):
    what = rng.cycle(["3 frames for 2", "cut in half", "garbage", "empty", "a folder", "a FIFO", "missing",
                      "a PNG named .mp4"])

    def apply(c):
        c.clip["frames"] = "drive.mp4"
        if what == "3 frames for 2":
            c.write("job/drive.mp4", c.s.clip_video3)
        elif what == "cut in half":
            c.write("job/drive.mp4", c.s.clip_video[:len(c.s.clip_video) // 2])
        elif what == "garbage":
            c.write("job/drive.mp4", random.Random(4).randbytes(3000))
        elif what == "empty":
            c.write("job/drive.mp4", b"")
        elif what == "a folder":
            c.replace_with("job/drive.mp4", "dir")
        elif what == "a FIFO":
            c.replace_with("job/drive.mp4", "fifo")
        elif what == "missing":
            pass
        else:
            c.write("job/drive.mp4", c.s.clip_pngs[0])
    return f"video: {what}", apply, ("refuse" if what == "3 frames for 2" else None), ""


def _clip_json_case(rng):
    what = rng.cycle(["frames pattern {0.__class__}", "frames pattern {}{}", "frames pattern {:d}", "frames list of 1",
                      "frames list of 3", "fps NaN", "fps 0", "predictions missing", "poses a folder",
                      "schema other", "frames absolute outside", "frames ../", "frames pattern {:999999d}",
                      "cars box NaN", "distortion 3 values", "views shift NaN"])

    def apply(c):
        j = c.clip
        if what == "frames pattern {0.__class__}":
            j["frames"] = "frames/frame_{0.__class__}.png"
        elif what == "frames pattern {}{}":
            j["frames"] = "frames/frame_{}{}.png"
        elif what == "frames pattern {:d}":
            j["frames"] = "frames/frame_{:d}.png"
        elif what == "frames list of 1":
            j["frames"] = ["frames/frame_000000.png"]
        elif what == "frames list of 3":
            j["frames"] = ["frames/frame_000000.png"] * 3
        elif what == "fps NaN":
            j["fps"] = float("nan")
        elif what == "fps 0":
            j["fps"] = 0
        elif what == "predictions missing":
            os.unlink(c.path("job/predictions.npz"))
        elif what == "poses a folder":
            c.replace_with("job/poses.npz", "dir")
        elif what == "schema other":
            j["schema"] = "scpainter.clip/9"
        elif what == "frames absolute outside":
            for t in range(2):
                c.write(f"outside/frame_{t:06d}.png", c.s.clip_pngs[t])
            j["frames"] = os.path.join(c.outside, "frame_{:06d}.png")
        elif what == "frames ../":
            for t in range(2):
                c.write(f"outside/frame_{t:06d}.png", c.s.clip_pngs[t])
            j["frames"] = "../outside/frame_{:06d}.png"
        elif what == "frames pattern {:999999d}":
            j["frames"] = "frames/frame_{:999999d}.png"
        elif what == "cars box NaN":
            j["cars"] = [{"id": "a", "size": [1.8, 4.4, 1.5], "boxes": {"0": [[float("nan")] * 4] * 4}}]
        elif what == "distortion 3 values":
            j["distortion"] = [0.1, 0.0, 0.0]
        else:
            j["views"] = {"nan": "frames/frame_{:06d}.png"}
    return f"json: {what}", apply, None, ""


def _clip_rewrite(rng):
    how = rng.cycle(["PNG at compression 0", "PNG with a text chunk", "predictions deflated", "poses deflated",
                     "frames as a list", "PNG interlaced"])

    def apply(c):
        from PIL import Image, PngImagePlugin

        if how.startswith("PNG"):
            for t in range(2):
                b = io.BytesIO()
                im = Image.fromarray(c.s.clip_frames[t])
                if how == "PNG at compression 0":
                    im.save(b, format="PNG", compress_level=0)
                elif how == "PNG interlaced":
                    im.save(b, format="PNG", interlace=1)
                else:
                    info = PngImagePlugin.PngInfo()
                    info.add_text("Comment", "re-saved")
                    im.save(b, format="PNG", pnginfo=info)
                c.write(f"job/frames/frame_{t:06d}.png", b.getvalue())
        elif how == "predictions deflated":
            c.write("job/predictions.npz", c.base.npz_deflated)
        elif how == "poses deflated":
            c.write("job/poses.npz", _npz(c.s.poses, deflate=True))
        else:
            c.clip["frames"] = [f"frames/frame_{t:06d}.png" for t in range(2)]
    return f"rewrite: {how}", apply, "same", ""


CLIP_FAMILIES = [(_poses_case, 3), (_frames_case, 3), (_video_case, 2), (_clip_json_case, 3), (_clip_rewrite, 2)]


# ---------------------------------------------------------------------------------------------- kill cases

#: The kill scenarios and how many atomic renames the killed run makes (``_gate_renames``; measured on this job:
#: a generate after a finished render renames the render record, 10 frames, the video and the manifest; a render
#: of the moved car 4 files a frame and its record; mesh-asset its PLY): the kill lands before one of them.
KILL_SCENARIOS = {"generate other settings killed, first again": 13, "generate killed, same again": 13,
                  "render of a moved car killed, first again": 41, "mesh-asset killed, again": 1,
                  "two generates at once": 0, "render and generate at once": 0}


def _kill_case(rng):
    scenario = rng.cycle(list(KILL_SCENARIOS))
    renames = KILL_SCENARIOS[scenario]
    sig = ("SIGKILL", "SIGTERM")[rng.turn // len(KILL_SCENARIOS) % 2] if renames else ""
    point = rng.randrange(1, renames + 1) if renames else 0
    return (f"{scenario.split(',')[0].split(' killed')[0]}: {scenario}" + (f", {sig} before rename {point}" if sig
                                                                            else ""),
            {"scenario": scenario, "signal": sig, "point": point}, None, "")


KILL_FAMILIES = [(_kill_case, 1)]

import fuzz_splat_formats  # noqa: E402  (the splat2 kind's mutations; it imports nothing of this module)

SPLAT2_FAMILIES = fuzz_splat_formats.families(_format_family)
FAMILIES = {"mesh": MESH_FAMILIES, "splat": SPLAT_FAMILIES, "splat2": SPLAT2_FAMILIES, "exr": EXR_FAMILIES, "clip": CLIP_FAMILIES,
            "kill": KILL_FAMILIES}


def make_case(kind: str, index: int, seed: int) -> Case:
    """Case ``index`` of ``kind`` (families' slots by weight, in rounds; choices seeded by (seed, kind, index))."""
    families = FAMILIES[kind]
    slots = [j for j, (_, w) in enumerate(families) for _ in range(w)]
    slot = index % len(slots)
    j = slots[slot]
    rng = Draw(f"{seed}/{kind}/{index}")
    rng.turn = (index // len(slots)) * families[j][1] + slots[:slot].count(j)
    got = tuple(families[j][0](rng)) + (None, "")
    description, apply, expect, extra = got[:4]
    fmt, must = (extra, "") if kind in ("mesh", "splat", "splat2") else ("", extra)
    return Case(kind, index, seed, description, apply, expect, fmt, must)


# ---------------------------------------------------------------------------------------------- running a case

def _dir(F, case, base, root):
    """The case folder (``fuzz_inputs.prepare``'s layout: job/ with the job, its inputs and out/, outside/ with
    planted files) plus this kind's files; the mutation is applied by the caller."""
    s = surfaces(base)
    plain = F.Case("job", case.index, case.seed, case.description, lambda c: None)
    c = F.prepare(plain, base, root)
    c.s, c.fmt, c.base, c.clip = s, case.fmt, base, None
    c.read = lambda rel: open(c.path(rel), "rb").read()
    if case.kind == "mesh":
        for name, data in s.meshes[case.fmt].items():
            c.write(os.path.join("job", name), data)
    elif case.kind == "splat":
        if case.fmt == "compressed":
            c.write("job/car.ply", s.compressed)
        else:
            os.unlink(c.ply)
            c.write("job/car.splat", s.splat)
            c.job["assets"][0]["ply"] = "car.splat"
    elif case.kind == "splat2":
        import fuzz_splat_formats
        os.unlink(c.ply)
        c.write(fuzz_splat_formats.asset_rel(case.fmt), s.splat2.files[case.fmt])
        c.job["assets"][0]["ply"] = os.path.basename(fuzz_splat_formats.asset_rel(case.fmt))
    elif case.kind == "exr":
        r = F.invoke(["render", c.job_json, "--device", "cpu"], 600)
        if r["rc"] != 0:
            raise RuntimeError(f"the render before an exr case failed: {r['stdout'][-500:]} {r['stderr'][-500:]}")
    elif case.kind == "clip":
        c.clip = copy.deepcopy(s.clip_json)
        c.write("job/poses.npz", _npz(s.poses))
        for t, data in enumerate(s.clip_pngs):
            c.write(f"job/frames/frame_{t:06d}.png", data)
    return c


def _finish(c, case):
    if case.kind == "clip":
        c.write("job/clip.json", json.dumps(c.clip))
    elif c.job is not None:
        import fuzz_inputs as F
        c.write("job/job.json", F.to_json(c.job))


def _argv(case, c):
    if case.kind == "mesh":
        return ["mesh-asset", c.path(_m(c)), "--out", os.path.join(c.job_dir, "out", "asset.ply"), "--count",
                str(MESH_COUNT)]
    if case.kind == "exr":
        return ["generate", c.job_json, "--device", "cpu"]
    return ["render", c.job_json, "--device", "cpu"]


def _run_clip(F, c, timeout):
    """``clip.load`` + ``load_frames`` in this process, reported as main() would: an InputError is exit 2 with an
    error event (its file and field), any other exception a traceback."""
    import traceback as tb_mod

    from scpainter_blender.core.errors import InputError

    out = {"rc": None, "exc": None, "hang": False, "stdout": "", "stderr": "", "seconds": 0.0, "value": None}
    t0 = time.perf_counter()
    try:
        with F.alarm(timeout, cpu=True):
            from backend.train import clip as clip_mod
            clip = clip_mod.load(c.path("job/clip.json"))
            frames = clip.load_frames(16, 12)
            out["value"] = (frames, clip.K, clip.world_to_camera)
            out["rc"] = 0
    except F.Hang:
        out["hang"] = True
    except InputError as e:
        out["rc"] = 2
        out["stdout"] = json.dumps({"event": "error", "message": str(e), "file": e.path, "field": e.field}) + "\n"
    except BaseException:  # noqa: BLE001
        out["exc"] = tb_mod.format_exc()
    out["seconds"] = time.perf_counter() - t0
    return out


def _warnings(stdout: str) -> list:
    import fuzz_inputs as F
    return [e for e in F.parse_events(stdout) if e.get("event") == "warning"]


def _png_pixels(path):
    from PIL import Image
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def _generated(out_dir, frames=(1, 2)):
    return [_png_pixels(os.path.join(out_dir, "generated", f"frame_{f:06d}.png")) for f in frames]


def _misread(case, c, ran, base) -> str:
    """Why an accepted case is a misread (the module docstring's rules), or ""."""
    from scpainter_blender.core.splats import reader as splats_io

    s = surfaces(base)
    warned = bool(_warnings(ran["stdout"]))
    if case.kind == "mesh":
        out = os.path.join(c.job_dir, "out", "asset.ply")
        try:
            g = splats_io.read(out)
        except Exception as e:  # noqa: BLE001
            return f"accepted, but its PLY cannot be read: {type(e).__name__}: {e}"
        if case.expect == "refuse" and not warned:
            return f"accepted without a warning ({len(g.xyz)} Gaussians)"
        if len(g.xyz) < MESH_COUNT and not warned:
            return f"accepted with {len(g.xyz)} of {MESH_COUNT} Gaussians and no warning"
        if case.expect == "same":
            ref = s.refs.get(("mesh", case.fmt))
            if ref is not None and not F_equal(g, ref):
                return "the rewritten mesh gives other Gaussians than the original file"
    elif case.kind in ("splat", "splat2"):
        if case.expect == "refuse" and not warned:
            return ("every Gaussian is invalid, rendered without a warning" if case.kind == "splat" else
                    "accepted without a warning (every Gaussian invalid, or data misaligned with its header)")
        if case.expect == "same":
            asset = c.job["assets"][0]["ply"]
            try:
                got = splats_io.read(os.path.join(c.job_dir, asset))
            except Exception as e:  # noqa: BLE001
                return f"accepted, but core.splats.reader.read fails: {type(e).__name__}: {e}"
            ref = (s.splat2.refs[case.fmt] if case.kind == "splat2" else
                   s.compressed_raw if case.fmt == "compressed" else s.splat_raw)
            if not F_equal(got, ref):
                return "core.splats.reader.read gives other values than the original file"
    elif case.kind == "exr":
        if case.expect == "refuse":
            return ("generate accepted a condition EXR with values the renderer never writes" if "values:" in
                    case.description else "generate accepted a condition EXR of another size than the job's")
        if case.expect == "same":
            try:
                got = _generated(os.path.join(c.job_dir, "out"))
            except Exception as e:  # noqa: BLE001
                return f"accepted, but its frames cannot be read: {type(e).__name__}: {e}"
            if any(not np.array_equal(a, b) for a, b in zip(got, s.refs["exr"])):
                return "the losslessly rewritten EXRs give other generated frames"
    elif case.kind == "clip":
        if case.expect == "refuse":
            return "loaded without a refusal"
        if case.expect == "same":
            frames, K, w2c = ran["value"]
            rf, rK, rw = s.refs["clip"]
            if not (np.array_equal(frames, rf) and np.array_equal(K, rK) and np.array_equal(w2c, rw)):
                return "the rewritten clip loads other frames or poses"
    return ""


def F_equal(a, b) -> bool:
    import fuzz_inputs as F
    return F._gaussians_equal(a, b)


def run_case(case: Case, base, workdir: str, timeout: float, keep: bool = False) -> dict:
    """Build, run and classify one case of a kind of this module in this process (``fuzz_inputs.run_case``)."""
    import fuzz_inputs as F

    root = os.path.join(workdir, f"{case.kind}-{case.index:04d}")
    result = {"kind": case.kind, "index": case.index, "seed": case.seed, "description": case.description,
              "family": case.family, "rc": None, "seconds": 0.0, "message": "", "file": None, "field": None}
    if case.kind == "kill":
        if _SERVER:   # (the server and its runners hold none: it was forked before it was recorded)
            return _run_kill_served(case, workdir, keep, result)
        return _run_kill(F, case, base, root, workdir, result, keep)
    c = _dir(F, case, base, root)
    case.apply(c)
    _finish(c, case)
    names = F._case_names(c, F.Case("job", case.index, case.seed, case.description, None)) | {"clip.json",
                                                                                            "poses.npz"}
    for dirpath, dirnames, filenames in os.walk(c.job_dir):
        names.update(dirnames + filenames)
    before, top_before = F.snapshot(root, c.job_dir), set(os.listdir(workdir))
    ran = _run_clip(F, c, timeout) if case.kind == "clip" else F.invoke(_argv(case, c), timeout)
    escapes = F._changed(before, F.snapshot(root, c.job_dir))
    escapes += [f"created ../{n}" for n in sorted(set(os.listdir(workdir)) - top_before)]
    result["rc"], result["seconds"] = ran["rc"], round(ran["seconds"], 4)
    outcome = F.classify(result, ran, escapes, names, timeout)
    if outcome == "accepted":
        try:
            with F.alarm(max(timeout, 10.0), cpu=True):
                why = _misread(case, c, ran, base)
        except BaseException as e:  # noqa: BLE001
            why = f"the misread check failed: {type(e).__name__}: {e}"
        if why:
            outcome, result["message"] = "misread", F._first_line(why)
    elif outcome == "clean" and case.must_name:
        errors = [e for e in F.parse_events(ran["stdout"]) if e.get("event") == "error"]
        if not any(F.names_a_file(str(e.get("message", "")), {case.must_name}) for e in errors):
            outcome = "unclear"
            result["message"] = f"(names not {case.must_name}) " + result["message"]
    return F.finish(result, outcome, ran, root, keep)


def warm_up(kind: str, base, workdir: str, seed: int) -> dict:
    """Run the valid input of ``kind`` (untimed) and keep what the misread checks compare with."""
    import fuzz_inputs as F
    from scpainter_blender.core.splats import reader as splats_io

    s = surfaces(base)
    t0 = time.perf_counter()
    outcomes, message = [], ""
    variants = {"mesh": FORMATS, "splat": ("compressed", "splat"),
                "splat2": __import__("fuzz_splat_formats").FORMATS, "exr": ("",), "clip": ("",), "kill": ("",)}[kind]
    for fmt in variants:
        case = Case(kind, -1, seed, "base: the valid input, unchanged", lambda c: None, None, fmt)
        root = os.path.join(workdir, f"{kind}-base-{fmt}")
        if kind == "kill":
            got = start_fork_server(base, workdir).warm()
            outcomes.append(got["outcome"])
            message = message or got["message"]
            continue
        c = _dir(F, case, base, root)
        _finish(c, case)
        ran = _run_clip(F, c, 600) if kind == "clip" else F.invoke(_argv(case, c), 600)
        r = {"message": ""}
        outcome = F.classify(r, ran, [], {"job.json"}, 600)
        outcomes.append(outcome)
        message = message or r["message"]
        if outcome == "accepted":
            if kind == "mesh":
                s.refs[("mesh", fmt)] = splats_io.read(os.path.join(c.job_dir, "out", "asset.ply"))
                if _warnings(ran["stdout"]):
                    outcomes[-1], message = "warned", f"{fmt}: the valid mesh gives a warning"
            elif kind == "exr":
                s.refs["exr"] = _generated(os.path.join(c.job_dir, "out"))
            elif kind == "clip":
                s.refs["clip"] = ran["value"]
        shutil.rmtree(root, ignore_errors=True)
    bad = [o for o in outcomes if o != "accepted"]
    return {"outcome": bad[0] if bad else "accepted", "seconds": round(time.perf_counter() - t0, 3),
            "message": message}


# ---------------------------------------------------------------------------------------------- kill runner

def _kill_job(base, moved=False):
    """The base job with KILL_FRAMES frames (the two cameras alternating); ``moved``: the car 0.5 m to the side."""
    job = copy.deepcopy(base.job)
    frames = [dict(copy.deepcopy(base.job["frames"][i % 2]), frame=i + 1) for i in range(KILL_FRAMES)]
    o2w = np.array(next(iter(base.job["assets"][0]["object_to_world"].values())))
    if moved:
        o2w[0, 3] += 0.5
    job["frames"] = frames
    job["assets"][0]["object_to_world"] = {str(f["frame"]): o2w.tolist() for f in frames}
    return job


def _kill_folder(F, base, root):
    c = F.prepare(F.Case("job", -1, 0, "kill", lambda c: None), base, root)
    c.write("job/job.json", F.to_json(_kill_job(base)))
    c.write("job/job_moved.json", F.to_json(_kill_job(base, moved=True)))
    for name, data in surfaces(base).meshes["glb"].items():
        c.write(os.path.join("job", name), data)
    return c


def _kill_argv(c, what):
    job = c.job_json
    return {"render": ["render", job, "--device", "cpu"],
            "render moved": ["render", os.path.join(c.job_dir, "job_moved.json"), "--device", "cpu"],
            "telea": ["generate", job, "--device", "cpu", "--inpaint", "telea"],
            "navier-stokes": ["generate", job, "--device", "cpu", "--inpaint", "navier-stokes"],
            "mesh": ["mesh-asset", os.path.join(c.job_dir, "car.glb"), "--out",
                     os.path.join(c.job_dir, "out", "asset.ply"), "--count", "100000"]}[what]


def _kill_references(F, base, root):
    """The finished outputs the kill cases compare with: condition layers of the job, generated frames of both
    inpainting methods, the mesh asset."""
    from backend.render import channels
    from scpainter_blender.core.splats import reader as splats_io

    s = surfaces(base)
    if "kill" in s.refs:
        return
    refs = {}
    for method in ("telea", "navier-stokes"):
        c = _kill_folder(F, base, root + "-" + method)
        for what in (method, "mesh") if method == "telea" else (method,):
            ch = _Child(_kill_argv(c, what), os.path.join(os.path.dirname(root), f"kill-ref-{what}.log"))
            if not ch.wait(time.monotonic() + 600) or ch.rc != 0:
                raise RuntimeError(f"kill reference {what}: exit {ch.rc}: {' '.join(ch.lines[-3:])[-400:]} "
                                   f"{ch.stderr()[-400:]}")
            os.unlink(ch.log)
        out = os.path.join(c.job_dir, "out")
        refs[method] = _generated(out, range(1, KILL_FRAMES + 1))
        refs["exr"] = {f: channels.read(os.path.join(out, "conditions", f"frame_{f:06d}.exr"))
                       for f in range(1, KILL_FRAMES + 1)}
        if method == "telea":
            refs["mesh"] = splats_io.read(os.path.join(out, "asset.ply"))
        shutil.rmtree(c.root, ignore_errors=True)
    if any(np.array_equal(a, b) for a, b in zip(refs["telea"], refs["navier-stokes"])):
        raise RuntimeError("kill references: the two inpainting methods give the same frame somewhere, so mixed "
                           "frames could not be told apart: the kill job needs more hole")
    s.refs["kill"] = refs


#: The line a gated child writes to its standard output before each atomic rename of a temporary into place.
GATE = "#gate "


def _gate_renames(ack_fd):
    """In a gated child: before each ``os.replace`` / ``os.rename`` of a temporary (``.<name>.<random>.tmp``, as
    ``core.outputs`` writes every output) the child says ``#gate <target>`` on standard output and waits for one
    byte on ``ack_fd``; the end of that pipe opens every later gate. The parent signals the child at a chosen gate,
    so a kill lands at the same point of the run however busy the machine is: the temporary whole, the target not
    yet replaced (the moment a kill during writing leaves behind)."""
    import threading

    lock, opened = threading.Lock(), []

    def gated(real):
        def call(src, dst, *args, **kwargs):
            name = os.path.basename(os.fspath(src))
            if name.startswith(".") and name.endswith(".tmp"):
                target = os.fspath(dst)
                if kwargs.get("dst_dir_fd") is not None:   # core.outputs renames within a folder's descriptor
                    target = os.path.join(os.readlink(f"/proc/self/fd/{kwargs['dst_dir_fd']}"), target)
                with lock:
                    os.write(1, f"{GATE}{target}\n".encode())
                    if not opened and not os.read(ack_fd, 1):
                        opened.append(True)
            return real(src, dst, *args, **kwargs)
        return call

    os.replace, os.rename = gated(os.replace), gated(os.rename)


class _Child:
    """A forked child running ``backend.__main__.main(argv)``: events on a pipe, standard error in a file.
    ``gated``: it stops before each atomic rename until ``step`` (or ``open``) lets it on (``_gate_renames``)."""

    def __init__(self, argv, log, gated=False):
        r, w = os.pipe()
        ack_r, ack_w = os.pipe() if gated else (None, None)
        pid = os.fork()
        if pid == 0:   # the child: never returns into the worker
            rc = 99
            try:
                os.close(r)
                if gated:
                    os.close(ack_w)
                    _gate_renames(ack_r)
                os.dup2(w, 1)
                fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
                os.dup2(fd, 2)
                for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGALRM):
                    signal.signal(sig, signal.SIG_DFL)
                signal.setitimer(signal.ITIMER_REAL, 0)
                sys.stdout = io.TextIOWrapper(io.FileIO(1, "w", closefd=False), line_buffering=True,
                                              write_through=True)
                sys.stderr = io.TextIOWrapper(io.FileIO(2, "w", closefd=False), line_buffering=True,
                                              write_through=True)
                from backend.__main__ import main
                rc = main(argv)
            except BaseException:  # noqa: BLE001
                import traceback as tb_mod
                tb_mod.print_exc()
            finally:
                try:
                    sys.stdout.flush()
                    sys.stderr.flush()
                finally:
                    os._exit(rc if isinstance(rc, int) else 98)
        os.close(w)
        if gated:
            os.close(ack_r)
        self.pid, self.fd, self.log, self.buf, self.lines, self.status = pid, r, log, b"", [], None
        self.signalled, self.ack = "", ack_w

    def step(self):
        """Let the child past the gate it waits at."""
        os.write(self.ack, b"1")

    def open(self):
        """Let the child past every gate from now on."""
        if self.ack is not None:
            os.close(self.ack)
            self.ack = None

    def read(self, timeout):
        """Read what arrived within ``timeout`` s; returns the new complete lines ([] at the end: ``eof``)."""
        import select
        ready, _, _ = select.select([self.fd], [], [], timeout)
        if not ready:
            return None
        chunk = os.read(self.fd, 1 << 16)
        if not chunk:
            return []
        self.buf += chunk
        *lines, self.buf = self.buf.split(b"\n")
        new = [ln.decode("utf-8", "replace") for ln in lines if ln.strip()]
        self.lines += new
        return new

    def signal(self, name):
        self.signalled = name
        try:
            os.kill(self.pid, getattr(signal, name))
        except ProcessLookupError:
            pass

    def wait(self, deadline):
        """Read to the end and reap; False if it did not end by ``deadline`` (it is then killed)."""
        self.open()
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                os.kill(self.pid, signal.SIGKILL)
                os.waitpid(self.pid, 0)
                os.close(self.fd)
                return False
            got = self.read(left)
            if got == []:
                break
        _, status = os.waitpid(self.pid, 0)
        os.close(self.fd)
        self.status = status
        return True

    @property
    def rc(self):
        return os.waitstatus_to_exitcode(self.status) if self.status is not None else None

    def stderr(self):
        with open(self.log, "rb") as f:
            return f.read().decode("utf-8", "replace")


def _judge(F, child, label) -> tuple:
    """(outcome or "", message) of one child that was not killed on purpose: exit 0, or exit 1 naming a busy
    folder (the lock respected) are fine; a traceback, another exit, or exit 2 are not."""
    err = child.stderr()
    events = F.parse_events("\n".join(ln for ln in child.lines if not ln.startswith(GATE)))
    errors = [e for e in events if e.get("event") == "error"]
    msg = F._first_line(str(errors[-1].get("message", ""))) if errors else ""
    if "Traceback" in err:
        return "traceback", f"{label}: {F._last_exception(err)}"
    if child.signalled:
        return "", ""
    if child.rc == 0:
        return "", ""
    if child.rc == 1 and ("being written by another run" in msg or "locked" in msg):
        return "", ""
    if child.rc == 2:
        return "unclear", f"{label}: exit 2: {msg}"
    return "traceback", f"{label}: exit {child.rc}: {msg or F._first_line(err)}"


def _leftovers(folder) -> list:
    out = []
    for dirpath, dirnames, filenames in os.walk(folder):
        out += [os.path.relpath(os.path.join(dirpath, n), folder) for n in dirnames + filenames
                if n.startswith(".") and ".tmp" in n]
    return out


def _run_kill(F, case, base, root, workdir, result, keep) -> dict:
    from numba.np.ufunc import parallel

    from backend.render import channels
    from scpainter_blender.core.splats import reader as splats_io

    if parallel._is_initialized:   # its forked backend children would stop themselves (see ForkServer)
        raise RuntimeError("kill cases run in a process that launched numba's threading layer: start "
                           "fuzz_surfaces.start_fork_server() first")
    s = surfaces(base)
    _kill_references(F, base, os.path.join(workdir, "kill-refs"))
    refs = s.refs["kill"]
    spec = case.apply
    c = _kill_folder(F, base, root)
    out = os.path.join(c.job_dir, "out")
    logs = iter(range(100))
    before, top_before = F.snapshot(root, c.job_dir), set(os.listdir(workdir))
    t0 = time.perf_counter()
    problems, hang, gates = [], [], []

    def run(what, kill_at=None, sig=""):
        """Run ``what`` to its end, or signal it at its kill_at-th atomic rename (``_gate_renames``: the
        temporary written, not yet in place); returns the child."""
        ch = _Child(_kill_argv(c, what), os.path.join(workdir, f"kill-{case.index}-{next(logs)}.log"),
                    gated=kill_at is not None)
        deadline = time.monotonic() + KILL_TIMEOUT_S
        if kill_at is not None:
            seen = 0
            while time.monotonic() < deadline and ch.ack is not None:
                got = ch.read(max(0.0, deadline - time.monotonic()))
                if not got:
                    break
                for ln in got:
                    if not ln.startswith(GATE):
                        continue
                    seen += 1
                    gates.append(os.path.relpath(ln[len(GATE):], c.job_dir))
                    if seen == kill_at:
                        ch.signal(sig)   # then the gates open: a SIGTERM is handled by the run itself
                        ch.open()
                        break
                    ch.step()
        ended(ch, what, deadline)
        return ch

    def ended(ch, what, deadline, how=""):
        """Wait for ``ch`` until ``deadline``: a hang if it runs on, else what ``_judge`` finds in its output."""
        if not ch.wait(deadline):
            hang.append(f"{what}{how} did not end within {KILL_TIMEOUT_S:g} s")
        else:
            o, m = _judge(F, ch, what)
            if o:
                problems.append((o, m))

    def together(a, b):
        ca = _Child(_kill_argv(c, a), os.path.join(workdir, f"kill-{case.index}-{next(logs)}.log"))
        cb = _Child(_kill_argv(c, b), os.path.join(workdir, f"kill-{case.index}-{next(logs)}.log"))
        deadline = time.monotonic() + KILL_TIMEOUT_S
        for ch, what in ((ca, a), (cb, b)):
            ended(ch, what, deadline, " (run at once)")

    sc, sig, point = spec["scenario"], spec["signal"], spec["point"]
    final = "telea"
    try:
        with F.alarm(KILL_TIMEOUT_S * 4):
            if sc.startswith("generate other settings"):
                run("telea")
                run("navier-stokes", point, sig)
                run("telea")
            elif sc.startswith("generate killed"):
                run("render")
                run("navier-stokes", point, sig)
                run("navier-stokes")
                final = "navier-stokes"
            elif sc.startswith("render of a moved car"):
                run("render")
                run("render moved", point, sig)
                run("render")
                final = "render"
            elif sc.startswith("mesh-asset"):
                run("mesh", point, sig)
                run("mesh")
                final = "mesh"
            elif sc == "two generates at once":
                run("render")
                together("telea", "navier-stokes")
                run("telea")
            else:
                together("render", "telea")
                run("telea")
    except F.Hang:
        hang.append("the case did not end")
    result["seconds"] = round(time.perf_counter() - t0, 3)
    if sig:   # where the kill landed: the rename it stopped before (none: the run ended first)
        result["killed_before"] = gates[point - 1] if len(gates) >= point else f"(the run ended: {len(gates)} renames)"
    escapes = F._changed(before, F.snapshot(root, c.job_dir))
    escapes += [f"created ../{n}" for n in sorted(set(os.listdir(workdir)) - top_before)
                if not n.startswith(f"kill-{case.index}-")]
    if escapes:
        outcome, result["message"], result["escaped"] = "escape", "; ".join(escapes[:3]), escapes[:6]
    elif hang:
        outcome, result["message"] = "hang", hang[0]
    elif problems:
        outcome, result["message"] = problems[0]
    else:
        why = []
        try:
            if final in ("telea", "navier-stokes"):
                got = _generated(out, range(1, KILL_FRAMES + 1))
                wrong = [f + 1 for f, (a, b) in enumerate(zip(got, refs[final])) if not np.array_equal(a, b)]
                if wrong:
                    why.append(f"generated frames {wrong} are not the finished {final} run's (mixed frames kept)")
            if final in ("render", "telea", "navier-stokes"):
                wrong = []
                for f, ref in refs["exr"].items():
                    got = channels.read(os.path.join(out, "conditions", f"frame_{f:06d}.exr"))
                    if any(not np.array_equal(got[k], ref[k], equal_nan=True) for k in ref):
                        wrong.append(f)
                if wrong:
                    why.append(f"condition frames {wrong} are not the finished render's")
            if final == "mesh" and not F_equal(splats_io.read(os.path.join(out, "asset.ply")), refs["mesh"]):
                why.append("the asset PLY is not the finished run's")
        except Exception as e:  # noqa: BLE001
            why.append(f"the finished folder cannot be read: {type(e).__name__}: {e}")
        left = _leftovers(c.job_dir)
        if left:
            why.append(f"temporaries left after the next run: {left[:3]}")
        outcome = "misread" if why else "accepted"
        result["message"] = "; ".join(why)
        result["rc"] = 0
    return finish_case(result, outcome, workdir, f"kill-{case.index}-", root, keep)


def finish_case(result: dict, outcome: str, workdir: str, prefix: str, root: str, keep: bool) -> dict:
    """A kill case's end: its outcome set, the harness's files for it (``prefix``) removed from ``workdir``, its
    folder ``root`` kept (``--keep``: named in the result) or removed."""
    result["outcome"] = outcome
    for n in os.listdir(workdir):
        if n.startswith(prefix):
            os.unlink(os.path.join(workdir, n))
    if keep:
        result["folder"] = root
    else:
        shutil.rmtree(root, ignore_errors=True)
    return result


# ---------------------------------------------------------------------------------------------- fork server

class ForkServer:
    """The process the kill cases run in: forked by the worker before anything in it launches numba's threading
    layer. The backend's CPU kernels are ``@njit(parallel=True)`` on numba's GNU OpenMP layer, which refuses to run in
    a process forked after its parent launched it ("Terminating: fork() called from a process already using GNU
    OpenMP", then ``raise(SIGTERM)``: the backend's own SIGTERM handler then stops the run after its first frame).
    A worker renders in-process, so the backend processes of a kill case are forked from here instead (imports
    done, no kernel ever run here): each one launches its own threading layer, as ``python -m backend`` does.

    Requests, one JSON line each on a socket: ``{"op": "warm"}`` builds the kill references (in forked children);
    ``{"op": "case", "index", "seed", "workdir", "keep", "out"}`` forks a case runner (its own process group, so
    a hang is ended with its backend children) that runs ``_run_kill`` and writes the result to ``out``; the
    server answers ``{"started": pid}``, then ``{"status": waitstatus}`` when the runner is reaped."""

    def __init__(self, base, workdir):
        import socket

        ours, theirs = socket.socketpair()
        pid = os.fork()
        if pid == 0:   # the server: never returns into the worker
            code = 1
            try:
                ours.close()
                _serve(theirs, base, workdir)
                code = 0
            except BaseException:  # noqa: BLE001
                import traceback as tb_mod
                tb_mod.print_exc()
            finally:
                os._exit(code)
        theirs.close()
        self.pid, self.sock, self.buf = pid, ours, b""

    def _send(self, request):
        self.sock.sendall((json.dumps(request) + "\n").encode())

    def _reply(self, timeout):
        """The next answer line, or None if none came within ``timeout`` s."""
        import select
        deadline = time.monotonic() + timeout
        while b"\n" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self.sock], [], [], left)[0]:
                return None
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                raise RuntimeError("the kill cases' fork server died (its traceback is in the worker's log)")
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        return json.loads(line)

    def warm(self, kind="kill") -> dict:
        """Build the references of ``kind``'s cases (kill, or ``fuzz_round3``'s varykill) in the server."""
        self._send({"op": "warm", "kind": kind})
        return self._reply(1200) or {"outcome": "hang", "message": f"the {kind} references took over 20 minutes"}

    def case(self, index, seed, workdir, keep, kind="kill") -> dict | None:
        """Run case ``index`` of ``kind`` (kill, or ``fuzz_round3``'s varykill) in a forked runner; its result
        dict, or None if it did not end in time (the runner's process group is then killed)."""
        out = os.path.join(workdir, f"{kind}-{index}-result.json")
        self._send({"op": "case", "index": index, "seed": seed, "workdir": workdir, "keep": keep, "out": out,
                    "kind": kind})
        started = self._reply(60)
        if started is None:
            raise RuntimeError("the kill cases' fork server does not answer")
        reply = self._reply(KILL_TIMEOUT_S * 4 + 20)
        if reply is None:
            try:
                os.killpg(started["started"], signal.SIGKILL)
            except ProcessLookupError:
                pass
            self._reply(60)
            return None
        try:
            with open(out) as f:
                result = json.load(f)
        except (OSError, ValueError):
            status = reply["status"]
            raise RuntimeError(f"the kill case runner ended ({_status_words(status)}) without a result")
        os.unlink(out)
        return result

    def close(self):
        self.sock.close()
        os.waitpid(self.pid, 0)


def _status_words(status) -> str:
    code = os.waitstatus_to_exitcode(status)
    return f"killed by {signal.Signals(-code).name}" if code < 0 else f"exit {code}"


def _serve(sock, base, workdir):
    import fuzz_inputs as F
    # what every backend child needs, imported once here (no kernel runs on import)
    import backend.__main__  # noqa: F401
    import backend.generate.command  # noqa: F401
    import backend.mesh.asset  # noqa: F401
    import backend.render.command  # noqa: F401
    import torch

    torch.set_num_threads(1)   # as the worker's own cases (a 2-core machine shared with the other worker)
    surfaces(base)
    f = sock.makefile("rb")
    for line in f:
        req = json.loads(line)
        if req["op"] == "warm":
            t0 = time.perf_counter()
            try:
                if req.get("kind", "kill") == "kill":
                    _kill_references(F, base, os.path.join(workdir, "kill-refs"))
                else:
                    import fuzz_round3
                    fuzz_round3.varykill_references(base, workdir)
                answer = {"outcome": "accepted", "message": ""}
            except Exception as e:  # noqa: BLE001
                answer = {"outcome": "traceback", "message": f"{type(e).__name__}: {e}"[:400]}
            answer["seconds"] = round(time.perf_counter() - t0, 3)
            sock.sendall((json.dumps(answer) + "\n").encode())
            continue
        pid = os.fork()
        if pid == 0:   # the case runner
            code = 1
            try:
                os.setpgid(0, 0)
                sock.close()
                if req.get("kind", "kill") == "kill":
                    case = make_case("kill", req["index"], req["seed"])
                    result = run_case(case, base, req["workdir"], KILL_TIMEOUT_S, req["keep"])
                else:   # fuzz_round3's varykill: vary forked from here
                    import fuzz_round3
                    case = fuzz_round3.make_case(req["kind"], req["index"], req["seed"])
                    result = fuzz_round3.run_varykill(case, base, os.path.join(
                        req["workdir"], f"{case.kind}-{case.index:04d}"), req["workdir"], req["keep"])
                with open(req["out"] + ".part", "w") as out:
                    json.dump(result, out)
                os.replace(req["out"] + ".part", req["out"])
                code = 0
            except BaseException:  # noqa: BLE001
                import traceback as tb_mod
                tb_mod.print_exc()
            finally:
                os._exit(code)
        sock.sendall((json.dumps({"started": pid}) + "\n").encode())
        _, status = os.waitpid(pid, 0)
        sock.sendall((json.dumps({"status": status}) + "\n").encode())


_SERVER: list = []


def start_fork_server(base, workdir) -> ForkServer:
    """Start (once per process) the fork server the kill cases need; call it before this process runs any
    backend kernel (``numba.set_num_threads`` launches the threading layer too)."""
    from numba.np.ufunc import parallel

    if not _SERVER:
        if parallel._is_initialized:
            raise RuntimeError("the kill cases' fork server must start before numba's threading layer is launched")
        _SERVER.append(ForkServer(base, workdir))
    return _SERVER[0]


def _run_kill_served(case, workdir, keep, result) -> dict:
    """A kill case in this (worker) process: through the fork server."""
    if not _SERVER:
        raise RuntimeError("kill cases need fuzz_surfaces.start_fork_server() before the first kernel runs")
    got = _SERVER[0].case(case.index, case.seed, workdir, keep)
    if got is None:
        result.update(outcome="hang", message=f"the case did not end within {KILL_TIMEOUT_S * 4 + 20:g} s")
        return result
    return got
