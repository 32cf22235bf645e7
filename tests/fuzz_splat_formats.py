"""Seeded fuzz cases for the splat formats of issue 31 (kind ``splat2`` of ``tests/fuzz_surfaces.py``, run by
``tests/fuzz_inputs.py``'s harness): the job's asset (the base's 20 Gaussians, SH degree 1) written, without Node,
as Niantic SPZ version 2 and 3 (gzip), GaussianSplats3D ``.ksplat`` at compression levels 0, 1 and 2, a PlayCanvas
SOG bundle (lossless WebP from OpenCV; ``tests/sog_fixtures.py``'s hand-made texels, 20 Gaussians) and a glTF
``KHR_gaussian_splatting`` GLB (writers: ``tests/core/splats/splat_fixtures.py``, ``tests/sog_fixtures.py``), each changed
one way and rendered (``render job.json --device cpu``):

* truncation at seeded points (of the file, and inside SPZ's gzip stream);
* header fields: counts huge / zero / off by one, versions, SH degree, fractional bits, section and bucket fields,
  GLB chunk and total lengths, a gzip bomb (an SPZ claiming 10^9 Gaussians over 64 MiB of zeros, 64 KiB of gzip);
* SOG's meta.json (wrong types, huge or negative counts, NaN, codebooks of other lengths, file names leading out,
  other SH bands) and its zip (entry sizes lying, entries missing, swapped, garbage, a lossy image);
* glTF accessors and views out of their buffers, strides, component types, foreign required extensions, node
  transforms (NaN, 10^400, shear), malformed JSON structure;
* non-finite and degenerate payloads (NaN positions, zero rotations, NaN block sizes);
* content-preserving rewrites (re-gzipped, a ``.ksplat`` or SPZ saved as ``.splat``, a deflated or reordered SOG
  zip, SOG as a folder, the GLB as a ``.gltf`` with a data: URI or a percent-encoded external buffer).

Expected outcomes (``fuzz_surfaces.Case.expect``): None (accepted, or refused cleanly with a SplatsError naming the
file), "refuse" (every Gaussian invalid, or the data misaligned with the header: acceptance without a ``warning``
event is a misread), "same" (accepted with other raw values than ``core.splats.reader.read`` of the base file is a
misread).
"""

from __future__ import annotations

import gzip
import io
import json
import os
import struct
import zipfile
import zlib

import numpy as np

FORMATS = ("spz2", "spz3", "ksplat0", "ksplat1", "ksplat2", "sog", "glb")
EXT = {"spz2": "spz", "spz3": "spz", "ksplat0": "ksplat", "ksplat1": "ksplat", "ksplat2": "ksplat", "sog": "sog",
       "glb": "glb"}
SOG_COUNT, SOG_SIDE = 20, 8
MAIN, SECTION = 4096, 1024   # core.splats.ksplat's header sizes (checked against the module in Bases)


class Bases:
    """The valid files (``files[fmt]`` bytes) and their raw values as ``core.splats.reader.read`` gives them
    (``refs[fmt]``), built from ``base.gaussians`` in ``folder``."""

    def __init__(self, base, folder):
        import sog_fixtures as SOG
        from tests.core.splats import splat_fixtures as SF
        from scpainter_blender.core.splats import ksplat, reader as splats_io

        assert (ksplat.MAIN_HEADER, ksplat.SECTION_HEADER) == (MAIN, SECTION)
        os.makedirs(folder, exist_ok=True)
        g = base.gaussians
        self.n = len(g)
        self.files, self.refs = {}, {}
        for v in (2, 3):
            self.files[f"spz{v}"] = gzip.compress(SF.spz_body(g, v), mtime=0)
        for level in (0, 1, 2):
            p = os.path.join(folder, f"car{level}.ksplat")
            SF.write_ksplat(p, g, level, capacity=4, partial=(4, 3))
            self.files[f"ksplat{level}"] = open(p, "rb").read()
        meta, images = SOG.tiny(n=SOG_COUNT, bands=1, side=SOG_SIDE, seed=31)
        self.sog_meta, self.sog_images = meta, {k: SOG.encode_webp(v) for k, v in images.items()}
        self.files["sog"] = sog_zip(meta, self.sog_images)
        tree, blob = SF.gltf_splats(g, [{"mesh": 0}])
        self.files["glb"] = SF.glb(tree, blob)
        for fmt, data in self.files.items():
            p = os.path.join(folder, f"ref-{fmt}.{EXT[fmt]}")
            with open(p, "wb") as f:
                f.write(data)
            self.refs[fmt] = splats_io.read(p)
            want = SOG_COUNT if fmt == "sog" else self.n
            assert len(self.refs[fmt]) == want, (fmt, len(self.refs[fmt]))


def sog_zip(meta, images: dict, deflate=False, order=None, raw_meta=None) -> bytes:
    """A SOG bundle's bytes: meta.json (or ``raw_meta``) and the encoded ``images`` (name -> WebP bytes)."""
    buf = io.BytesIO()
    entries = [("meta.json", raw_meta if raw_meta is not None else json.dumps(meta).encode())]
    entries += list(images.items())
    if order is not None:
        entries = [entries[i] for i in order]
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED) as z:
        for name, data in entries:
            z.writestr(name, data)
    return buf.getvalue()


def asset_rel(fmt):
    return f"job/car.{EXT[fmt]}"


def glb_split(data: bytes):
    """(json dict, BIN bytes) of a GLB."""
    n = struct.unpack_from("<I", data, 12)[0]
    js = json.loads(data[20:20 + n])
    binlen = struct.unpack_from("<I", data, 20 + n)[0]
    return js, data[28 + n:28 + n + binlen]


def _bases(c):
    return c.s.splat2


def _put(c, fmt, data):
    c.write(asset_rel(fmt), data)


# ---------------------------------------------------------------------------------------------- every format

def _truncate(rng, fmt):
    where = rng.cycle(["1 byte", "16 bytes", "header only", "10 %", "half", "90 %", "all but 1 byte",
                       "inside the stream"])

    def apply(c):
        data = c.s.splat2.files[fmt]
        if where == "inside the stream" and fmt.startswith("spz"):
            body = gzip.decompress(data)
            _put(c, fmt, gzip.compress(body[:16 + (len(body) - 16) * 2 // 3], mtime=0))
            return
        head = {"spz2": 10, "spz3": 10, "sog": 30, "glb": 20}.get(fmt, MAIN + 2 * SECTION)
        cut = {"1 byte": 1, "16 bytes": 16, "header only": head, "10 %": len(data) // 10, "half": len(data) // 2,
               "90 %": len(data) * 9 // 10, "all but 1 byte": len(data) - 1,
               "inside the stream": len(data) * 2 // 3}[where]
        _put(c, fmt, data[:cut])
    return f"truncated: {fmt} {where}", apply, None


def _whole(rng, fmt):
    what = rng.cycle(["empty", "zeros", "random bytes", "doubled", "another format's bytes", "a folder"])

    def apply(c):
        data = c.s.splat2.files[fmt]
        if what == "a folder":
            c.replace_with(asset_rel(fmt), "dir")
            return
        other = c.s.splat2.files["glb" if fmt != "glb" else "spz3"]
        out = {"empty": b"", "zeros": bytes(len(data)), "doubled": data + data, "another format's bytes": other,
               "random bytes": np.random.default_rng(len(data)).integers(0, 256, len(data), np.uint8).tobytes()}
        _put(c, fmt, out[what])
    return f"whole file: {fmt} {what}", apply, None


# ---------------------------------------------------------------------------------------------- SPZ

_SPZ_FIELDS = {"count": (8, "<I"), "version": (4, "<I"), "sh degree": (12, "<B"), "fractional bits": (13, "<B")}


def _spz_header(rng, fmt):
    field, value = rng.cycle([("count", 0), ("count", 10 ** 9), ("count", 0xFFFFFFFF), ("count", "n+1"),
                              ("count", "n-1"), ("version", 0), ("version", 1), ("version", 4), ("version", 5),
                              ("version", 0xFFFFFFFF), ("sh degree", 0), ("sh degree", 2), ("sh degree", 3),
                              ("sh degree", 4), ("sh degree", 255), ("fractional bits", 0),
                              ("fractional bits", 23), ("fractional bits", 24), ("fractional bits", 255),
                              ("magic", "NGSQ"), ("count", "bomb")])

    def apply(c):
        b = c.s.splat2
        body = bytearray(gzip.decompress(b.files[fmt]))
        if value == "bomb":   # 10^9 Gaussians claimed, 64 MiB of zeros behind: a 64 KiB file
            struct.pack_into("<I", body, 8, 10 ** 9)
            z = zlib.compressobj(9, zlib.DEFLATED, 31)
            out = z.compress(bytes(body[:16]))
            zeros = bytes(1 << 20)
            for _ in range(64):
                out += z.compress(zeros)
            _put(c, fmt, out + z.flush())
            return
        if field == "magic":
            body[:4] = value.encode()
        else:
            off, code = _SPZ_FIELDS[field]
            v = {"n+1": b.n + 1, "n-1": b.n - 1}.get(value, value)
            struct.pack_into(code, body, off, v)
        _put(c, fmt, gzip.compress(bytes(body), mtime=0))
    # fewer or more Gaussians than the data holds: the attribute blocks would be read misaligned
    expect = "refuse" if value in ("n+1", "n-1") or (field == "sh degree" and value in (0, 2, 3)) else None
    return f"header: {fmt} {field} {value}", apply, expect


def _spz_values(rng, fmt):
    what = rng.cycle(["all alpha 0", "all scale bytes 0", "all scale bytes 255", "positions at the 24-bit limit",
                      "rotation bytes 0xFF", "rotation bytes 0", "trailing garbage in the stream",
                      "a second gzip member"])

    def apply(c):
        b = c.s.splat2
        body = bytearray(gzip.decompress(b.files[fmt]))
        n, rot = b.n, (3 if fmt == "spz2" else 4)
        at = {"pos": 16, "alpha": 16 + 9 * n, "color": 16 + 10 * n, "scale": 16 + 13 * n, "rot": 16 + 16 * n}
        if what == "all alpha 0":
            body[at["alpha"]:at["alpha"] + n] = bytes(n)
        elif what.startswith("all scale bytes"):
            body[at["scale"]:at["scale"] + 3 * n] = bytes([0 if what.endswith("0") else 255]) * (3 * n)
        elif what.startswith("positions"):
            body[at["pos"]:at["pos"] + 9 * n] = b"\xff\xff\x7f" * (3 * n)
        elif what.startswith("rotation bytes"):
            body[at["rot"]:at["rot"] + rot * n] = bytes([0xFF if what.endswith("0xFF") else 0]) * (rot * n)
        elif what.startswith("trailing"):
            body += b"garbage after the attributes" * 8
        if what == "a second gzip member":
            _put(c, fmt, b.files[fmt] + b.files[fmt])
            return
        _put(c, fmt, gzip.compress(bytes(body), mtime=0))
    expect = "refuse" if what == "trailing garbage in the stream" else None
    return f"values: {fmt} {what}", apply, expect


# ---------------------------------------------------------------------------------------------- .ksplat

#: (name, offset, struct code) of main-header fields, and of section fields (relative to the section header)
_KS_MAIN = {"version major": (0, "<B"), "version minor": (1, "<B"), "section headers": (4, "<I"),
            "sections used": (8, "<I"), "most Gaussians": (12, "<I"), "Gaussians": (16, "<I"), "level": (20, "<H"),
            "SH min": (36, "<f"), "SH max": (40, "<f")}
_KS_SECTION = {"Gaussians": (0, "<I"), "slots": (4, "<I"), "bucket capacity": (8, "<I"), "buckets": (12, "<I"),
               "block size": (16, "<f"), "bucket bytes": (20, "<H"), "range": (24, "<I"), "full buckets": (32, "<I"),
               "partial buckets": (36, "<I"), "SH degree": (40, "<H")}


def _ksplat_header(rng, fmt):
    where, field, value = rng.cycle([
        ("main", "version major", 1), ("main", "version minor", 0), ("main", "section headers", 0),
        ("main", "section headers", 65537), ("main", "section headers", 3), ("main", "sections used", 9),
        ("main", "Gaussians", 0), ("main", "Gaussians", 10 ** 9), ("main", "level", 3), ("main", "level", 65535),
        ("main", "SH min", float("nan")), ("main", "SH max", float("inf")), ("main", "SH min", 1.5),
        ("section", "Gaussians", 0), ("section", "Gaussians", 0xFFFFFFFF), ("section", "slots", 0),
        ("section", "slots", 10 ** 8), ("section", "bucket capacity", 0), ("section", "bucket capacity", 10 ** 9),
        ("section", "buckets", 0), ("section", "buckets", 10 ** 9), ("section", "block size", float("nan")),
        ("section", "block size", float("inf")), ("section", "block size", 0.0), ("section", "bucket bytes", 0),
        ("section", "bucket bytes", 65535), ("section", "range", 0), ("section", "range", 1),
        ("section", "full buckets", 10 ** 9), ("section", "partial buckets", 10 ** 9),
        ("section", "partial buckets", 0), ("section", "SH degree", 0), ("section", "SH degree", 3),
        ("section", "SH degree", 7)])

    def apply(c):
        data = bytearray(c.s.splat2.files[fmt])
        off, code = (_KS_MAIN if where == "main" else _KS_SECTION)[field]
        struct.pack_into(code, data, off + (0 if where == "main" else MAIN), value)
        _put(c, fmt, bytes(data))
    # every position NaN (the block size) or infinite: nothing to render
    expect = "refuse" if (field == "block size" and value != 0.0 and fmt != "ksplat0") else None
    return f"header: {fmt} {where} {field} {value}", apply, expect


def _ksplat_values(rng, fmt):
    what = rng.cycle(["all positions NaN", "all scales inf", "all rotations zero", "all alpha 0", "SH NaN",
                      "partial bucket sizes huge", "bucket centres NaN"])

    def apply(c):
        from scpainter_blender.core.splats import ksplat

        b = c.s.splat2
        data = bytearray(b.files[fmt])
        level = int(fmt[-1])
        rec = ksplat.record_dtype(level, 1)
        sec = np.frombuffer(bytes(data), "<u4", 10, MAIN)
        # the first section's data: partial sizes, centres, then its records
        n_part, n_buck, bb = int(sec[9]), int(sec[3]), int(np.frombuffer(bytes(data), "<u2", 1, MAIN + 20)[0])
        first = MAIN + 2 * SECTION + (4 * n_part + bb * n_buck if level else 0)
        m = int(sec[0])
        r = np.frombuffer(bytes(data), rec, m, first).copy()
        nan = np.float32("nan") if level == 0 else np.float16("nan")
        if what == "all positions NaN" and level == 0:
            r["xyz"] = np.nan
        elif what == "all positions NaN":
            r["xyz"] = 65535
        elif what == "all scales inf":
            r["scale"] = np.inf
        elif what == "all rotations zero":
            r["rot"] = 0
        elif what == "all alpha 0":
            r["rgba"][:, 3] = 0
        elif what == "SH NaN" and level < 2:
            r["sh"] = nan
        elif what == "partial bucket sizes huge" and level:
            struct.pack_into("<I", data, MAIN + 2 * SECTION, 0xFFFFFFFF)
        elif what == "bucket centres NaN" and level:
            struct.pack_into("<fff", data, MAIN + 2 * SECTION + 4 * n_part, np.nan, np.nan, np.nan)
        data[first:first + r.nbytes] = r.tobytes()
        _put(c, fmt, bytes(data))
    return f"values: {fmt} {what}", apply, None


# ---------------------------------------------------------------------------------------------- SOG

class _Raw:
    def __init__(self, text):
        self.text = text


def _sog_meta(rng, fmt):
    path, value = rng.cycle([
        (("count",), 0), (("count",), -1), (("count",), 10 ** 12), (("count",), "20"), (("count",), 20.0),
        (("count",), 19), (("count",), 21), (("count",), 2 ** 31), (("count",), None), (("version",), 1),
        (("version",), "2"), (("version",), None), (("means", "mins"), _Raw("[NaN, 0, 0]")),
        (("means", "mins"), [0, 0]), (("means", "maxs"), [1e308, 1e308, 1e308]), (("means", "mins"), "0 0 0"),
        (("scales", "codebook"), list(range(255))), (("scales", "codebook"), list(range(300))),
        (("scales", "codebook"), ["a"] * 256), (("sh0", "codebook"), [1e38] * 256), (("scales", "codebook"), []),
        (("means", "files"), ["../means_l.webp", "means_u.webp"]), (("means", "files"), ["means_l.webp"]),
        (("quats", "files"), ["nothere.webp"]), (("quats", "files"), "quats.webp"), (("sh0",), [1, 2]),
        (("shN", "bands"), 4), (("shN", "bands"), 0), (("shN", "bands"), -1), (("shN", "bands"), 3),
        (("shN", "count"), 0), (("shN", "count"), 70000), (("shN", "count"), 1), (("shN",), None),
        (("means",), None), (("lodLevels",), 3), (None, _Raw("[" * 10000 + "]" * 10000)),
        (None, _Raw("{\"version\": 2, " + "\"x\": 1, " * 200000 + "\"y\": 0}")), (None, _Raw("\xff\xfe{}"))])

    def apply(c):
        b = c.s.splat2
        import fuzz_inputs as FI
        if path is None:
            raw = value.text.encode("utf-8", "surrogateescape") if "\xff" not in value.text else b"\xff\xfe{}"
        else:
            meta = json.loads(json.dumps(b.sog_meta))
            node = meta
            for k in path[:-1]:
                node = node[k]
            if value is None:
                node.pop(path[-1], None)
            else:
                node[path[-1]] = FI.Raw(value.text) if isinstance(value, _Raw) else value
            raw = FI.to_json(meta).encode()
        _put(c, fmt, sog_zip(None, b.sog_images, raw_meta=raw))
    label = value.text[:20] if isinstance(value, _Raw) else json.dumps(value)[:24]
    return f"meta.json: {'.'.join(path or ('(whole)',))} {label}", apply, None


def _record(data: bytes, name: str, magic: bytes, name_length_at: int, name_at: int) -> int:
    """Offset of the zip record of entry ``name`` that starts with ``magic`` (its name's length at
    ``name_length_at``, the name at ``name_at``, from the record's start)."""
    at = 0
    while True:
        at = data.index(magic, at)
        n = struct.unpack_from("<H", data, at + name_length_at)[0]
        if data[at + name_at:at + name_at + n] == name.encode():
            return at
        at += 4


def _central(data: bytes, name: str) -> int:
    """Offset of the central directory record of entry ``name`` in a zip."""
    return _record(data, name, b"PK\x01\x02", 28, 46)


def _local(data: bytes, name: str) -> int:
    """Offset of the local file header of entry ``name`` in a zip."""
    return _record(data, name, b"PK\x03\x04", 26, 30)


def _sog_zip(rng, fmt):
    what, entry = rng.cycle([("size larger", "meta.json"), ("size smaller", "quats.webp"),
                             ("stored size 2^32-1", "means_l.webp"), ("local size lying", "sh0.webp"),
                             ("compression method 99", "scales.webp"), ("missing", "quats.webp"),
                             ("missing", "shN_labels.webp"), ("garbage", "means_u.webp"),
                             ("lossy", "scales.webp"), ("swapped with quats", "means_l.webp"),
                             ("WebP header 16383 x 16383", "sh0.webp"), ("empty", "sh0.webp"),
                             ("in a folder", "meta.json"), ("deflate bomb", "meta.json"),
                             ("crc wrong", "quats.webp"), ("meta.json twice", "meta.json"), ("no entries", "")])

    def apply(c):
        b = c.s.splat2
        images = dict(b.sog_images)
        if what in ("missing", "garbage", "lossy", "swapped with quats", "WebP header 16383 x 16383", "empty",
                    "in a folder", "deflate bomb", "meta.json twice", "no entries"):
            raw_meta = json.dumps(b.sog_meta).encode()
            if what == "missing":
                images.pop(entry)
            elif what == "garbage":
                images[entry] = b"RIFF" + bytes(200)
            elif what == "lossy":
                import cv2
                img = cv2.imdecode(np.frombuffer(images[entry], np.uint8), cv2.IMREAD_UNCHANGED)
                images[entry] = cv2.imencode(".webp", img, [cv2.IMWRITE_WEBP_QUALITY, 80])[1].tobytes()
            elif what == "swapped with quats":
                images[entry], images["quats.webp"] = images["quats.webp"], images[entry]
            elif what == "WebP header 16383 x 16383":
                d = bytearray(images[entry])
                bits = (16382) | (16382 << 14) | (int.from_bytes(d[21:25], "little") & ~((1 << 28) - 1))
                d[21:25] = bits.to_bytes(4, "little")
                images[entry] = bytes(d)
            elif what == "empty":
                images[entry] = b""
            if what == "in a folder":
                buf = io.BytesIO()
                with zipfile.ZipFile(buf, "w") as z:
                    for name, d in [("meta.json", raw_meta)] + list(images.items()):
                        z.writestr("scene/" + name, d)
                _put(c, fmt, buf.getvalue())
                return
            if what == "deflate bomb":
                buf = io.BytesIO()
                with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
                    z.writestr("meta.json", b"{" + b" " * (200 << 20) + b"}")
                    for name, d in images.items():
                        z.writestr(name, d)
                _put(c, fmt, buf.getvalue())
                return
            if what == "meta.json twice":
                buf = io.BytesIO()
                with zipfile.ZipFile(buf, "w") as z:
                    z.writestr("meta.json", b"{}")
                    for name, d in [("meta.json", raw_meta)] + list(images.items()):
                        z.writestr(name, d)
                _put(c, fmt, buf.getvalue())
                return
            if what == "no entries":
                buf = io.BytesIO()
                zipfile.ZipFile(buf, "w").close()
                _put(c, fmt, buf.getvalue())
                return
            _put(c, fmt, sog_zip(None, images, raw_meta=raw_meta))
            return
        data = bytearray(b.files[fmt])
        cd, lo = _central(bytes(data), entry), _local(bytes(data), entry)
        if what == "size larger":
            struct.pack_into("<I", data, cd + 24, struct.unpack_from("<I", data, cd + 24)[0] + 1000)
        elif what == "size smaller":
            struct.pack_into("<I", data, cd + 24, 10)
            struct.pack_into("<I", data, cd + 20, 10)
        elif what == "stored size 2^32-1":
            struct.pack_into("<I", data, cd + 20, 0xFFFFFFFE)
            struct.pack_into("<I", data, cd + 24, 0xFFFFFFFE)
        elif what == "local size lying":
            struct.pack_into("<I", data, lo + 18, 5)
            struct.pack_into("<I", data, lo + 22, 5)
        elif what == "compression method 99":
            struct.pack_into("<H", data, cd + 10, 99)
            struct.pack_into("<H", data, lo + 8, 99)
        elif what == "crc wrong":
            struct.pack_into("<I", data, cd + 16, 0x12345678)
            struct.pack_into("<I", data, lo + 14, 0x12345678)
        _put(c, fmt, bytes(data))
    return f"zip: sog {entry} {what}", apply, None


# ---------------------------------------------------------------------------------------------- glTF (GLB)

def _glb_structure(rng, fmt):
    path, value = rng.cycle([
        (("accessors", 0, "count"), 2 ** 31), (("accessors", 0, "count"), -1), (("accessors", 0, "count"), 21),
        (("accessors", 0, "count"), 0), (("accessors", 0, "count"), "20"), (("accessors", 0, "count"), 1e10),
        (("accessors", 1, "byteOffset"), 10 ** 6), (("accessors", 1, "byteOffset"), -12),
        (("bufferViews", 1, "byteLength"), 10 ** 9), (("bufferViews", 1, "byteOffset"), 2 ** 40),
        (("bufferViews", 0, "byteStride"), 1), (("bufferViews", 0, "byteStride"), 255),
        (("bufferViews", 0, "byteStride"), -28), (("accessors", 0, "componentType"), 5124),
        (("accessors", 0, "componentType"), 5121), (("accessors", 2, "normalized"), True),
        (("accessors", 0, "type"), "MAT4"), (("accessors", 0, "type"), "VEC2"), (("accessors", 0, "bufferView"), 99),
        (("accessors", 0, "bufferView"), -1), (("accessors", 0, "bufferView"), "0"),
        (("accessors", 0, "bufferView"), None), (("accessors", 0, "sparse"), {"count": 1}),
        (("buffers", 0, "uri"), "../outside/car.bin"), (("buffers", 0, "uri"), "missing.bin"),
        (("buffers", 0, "uri"), "data:application/octet-stream;base64,@@@"), (("buffers", 0, "uri"), "a\0b"),
        (("buffers", 0, "uri"), 7), (("buffers", 0, "byteLength"), 10 ** 12), (("buffers",), []),
        (("extensionsRequired",), ["KHR_draco_mesh_compression"]), (("extensionsRequired",), 5),
        (("extensionsRequired",), "KHR_gaussian_splatting"), (("nodes", 0, "matrix"), [float("nan")] * 16),
        (("nodes", 0, "matrix"), [1e308] * 16), (("nodes", 0, "scale"), [1, 2, 1]), (("nodes", 0, "scale"), [0, 0, 0]),
        (("nodes", 0, "rotation"), [0, 0, 0, 0]), (("nodes", 0, "translation"), ["x", 0, 0]),
        (("nodes", 0, "translation"), _Raw("[1" + "0" * 400 + ", 0, 0]")), (("nodes", 0, "children"), 5),
        (("nodes", 0, "children"), [0]), (("nodes", 0, "mesh"), 3), (("scene",), 4), (("scenes",), [{"nodes": 5}]),
        (("scenes",), [{"nodes": ["a"]}]), (("scenes",), [5]), (("meshes", 0, "primitives"), 5),
        (("meshes", 0, "primitives"), [5]), (("meshes", 0, "primitives", 0, "attributes"), ["POSITION"]),
        (("meshes", 0, "primitives", 0, "attributes"), "POSITION KHR_gaussian_splatting:ROTATION"),
        (("meshes", 0, "primitives", 0, "attributes", "POSITION"), None),
        (("meshes", 0, "primitives", 0, "attributes", "KHR_gaussian_splatting:SH_DEGREE_1_COEF_1"), None),
        (("meshes", 0, "primitives", 0, "attributes", "KHR_gaussian_splatting:SH_DEGREE_3_COEF_0"), 4),
        (("meshes", 0, "primitives", 0, "extensions"), "KHR_gaussian_splatting"), (("asset",), None),
        (("accessors",), {"0": 1}), (("nodes",), "x")])

    def apply(c):
        import fuzz_inputs as FI
        from tests.core.splats import splat_fixtures as SF

        js, binary = glb_split(c.s.splat2.files[fmt])
        node = js
        for k in path[:-1]:
            node = node[k]
        if value is None:
            node.pop(path[-1], None) if isinstance(node, dict) else None
        else:
            node[path[-1]] = FI.Raw(value.text) if isinstance(value, _Raw) else value
        if isinstance(value, _Raw):
            text = FI.to_json(js).encode()
            text += b" " * (-len(text) % 4)
            binary += bytes(-len(binary) % 4)
            body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary),
                                                                                  0x004E4942) + binary
            _put(c, fmt, struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
        else:
            _put(c, fmt, SF.glb(js, binary))
    label = value.text[:16] if isinstance(value, _Raw) else json.dumps(value)[:24]
    return f"glTF: {'.'.join(map(str, path))} {label}", apply, None


def _glb_chunks(rng, fmt):
    what = rng.cycle(["JSON length beyond the file", "JSON length 0", "BIN length beyond the file", "no BIN chunk",
                      "total length short", "version 1", "BIN first", "JSON not UTF-8", "JSON chunk padded with NULs"])

    def apply(c):
        data = bytearray(c.s.splat2.files[fmt])
        jlen = struct.unpack_from("<I", data, 12)[0]
        if what == "JSON length beyond the file":
            struct.pack_into("<I", data, 12, 0x7FFFFFF0)
        elif what == "JSON length 0":
            struct.pack_into("<I", data, 12, 0)
        elif what == "BIN length beyond the file":
            struct.pack_into("<I", data, 20 + jlen, 0x7FFFFFF0)
        elif what == "no BIN chunk":
            data = data[:20 + jlen]
            struct.pack_into("<I", data, 8, len(data))
        elif what == "total length short":
            struct.pack_into("<I", data, 8, 24)
        elif what == "version 1":
            struct.pack_into("<I", data, 4, 1)
        elif what == "BIN first":
            js, binary = data[20:20 + jlen], data[20 + jlen:]
            data = data[:12] + binary + struct.pack("<II", jlen, 0x4E4F534A) + js
        elif what == "JSON not UTF-8":
            data[21] = 0xFF
        else:
            text = data[20:20 + jlen].rstrip(b" ")
            data[20:20 + jlen] = text + b"\0" * (jlen - len(text))
        _put(c, fmt, bytes(data))
    return f"chunks: glb {what}", apply, None


def _glb_values(rng, fmt):
    what = rng.cycle(["all positions NaN", "some positions inf", "all scales 0", "all scales negative",
                      "all rotations zero", "SH NaN"])

    def apply(c):
        from tests.core.splats import splat_fixtures as SF

        js, binary = glb_split(c.s.splat2.files[fmt])
        binary = bytearray(binary)
        n = c.s.splat2.n
        views = js["bufferViews"]
        inter = np.frombuffer(bytes(binary), "<f4", 7 * n, views[0]["byteOffset"]).reshape(n, 7).copy()
        if what == "all positions NaN":
            inter[:, :3] = np.nan
        elif what == "some positions inf":
            inter[::3, :3] = np.inf
        elif what == "all rotations zero":
            inter[:, 3:] = 0
        binary[views[0]["byteOffset"]:views[0]["byteOffset"] + inter.nbytes] = inter.tobytes()
        if "scales" in what:
            sc = np.full((n, 3), 0.0 if what.endswith("0") else -1.0, "<f4")
            binary[views[1]["byteOffset"]:views[1]["byteOffset"] + sc.nbytes] = sc.tobytes()
        if what == "SH NaN":
            sh = np.full((n, 3), np.nan, "<f4")
            binary[views[5]["byteOffset"]:views[5]["byteOffset"] + sh.nbytes] = sh.tobytes()
        _put(c, fmt, SF.glb(js, bytes(binary)))
    expect = "refuse" if what in ("all positions NaN", "all rotations zero") else None
    return f"values: glb {what}", apply, expect


# ---------------------------------------------------------------------------------------------- rewrites

def _rewrite(rng, fmt):
    options = {"spz2": ["re-gzipped at level 1", "a gzip header with a file name", "saved as .splat"],
               "spz3": ["re-gzipped at level 1", "saved as .splat"],
               "ksplat0": ["saved as .splat"], "ksplat1": ["saved as .splat", "extension in capitals"],
               "ksplat2": ["saved as .splat"],
               "sog": ["deflated entries", "entries in another order", "unbundled (meta.json and images)"],
               "glb": ["as .gltf with a data: URI", "as .gltf with an external buffer named with a space"]}[fmt]
    how = rng.cycle(options)

    def apply(c):
        import base64

        b = c.s.splat2
        data = b.files[fmt]
        rel = asset_rel(fmt)
        os.unlink(c.path(rel))
        if how == "re-gzipped at level 1":
            c.write(rel, gzip.compress(gzip.decompress(data), 1, mtime=0))
        elif how == "a gzip header with a file name":
            buf = io.BytesIO()
            with gzip.GzipFile("car.spz", "wb", fileobj=buf, mtime=0) as z:
                z.write(gzip.decompress(data))
            c.write(rel, buf.getvalue())
        elif how in ("saved as .splat", "extension in capitals"):
            new = "car.splat" if how == "saved as .splat" else "car.KSPLAT"
            c.write("job/" + new, data)
            c.job["assets"][0]["ply"] = new
        elif how == "deflated entries":
            c.write(rel, sog_zip(b.sog_meta, b.sog_images, deflate=True))
        elif how == "entries in another order":
            c.write(rel, sog_zip(b.sog_meta, b.sog_images, order=[3, 1, 0, 7, 6, 2, 5, 4]))
        elif how.startswith("unbundled"):
            c.write("job/sog/meta.json", json.dumps(b.sog_meta))
            for name, d in b.sog_images.items():
                c.write("job/sog/" + name, d)
            c.job["assets"][0]["ply"] = "sog/meta.json"
        else:
            js, binary = glb_split(data)
            if "data:" in how:
                js["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(binary).decode()
            else:
                js["buffers"][0]["uri"] = "car%20splats.bin"
                c.write("job/car splats.bin", binary)
            c.write("job/car.gltf", json.dumps(js))
            c.job["assets"][0]["ply"] = "car.gltf"
    return f"rewrite: {fmt} {how}", apply, "same"


def families(format_family):
    """The ``splat2`` families (``fuzz_surfaces._format_family`` wraps each ``make(rng, fmt)``) with weights."""
    spz = ("spz2", "spz3")
    ks = ("ksplat0", "ksplat1", "ksplat2")
    return [(format_family(_truncate, FORMATS), 3), (format_family(_whole, FORMATS), 1),
            (format_family(_spz_header, spz), 3), (format_family(_spz_values, spz), 1),
            (format_family(_ksplat_header, ks), 3), (format_family(_ksplat_values, ks), 1),
            (format_family(_sog_meta, ("sog",)), 3), (format_family(_sog_zip, ("sog",)), 2),
            (format_family(_glb_structure, ("glb",)), 4), (format_family(_glb_chunks, ("glb",)), 1),
            (format_family(_glb_values, ("glb",)), 1), (format_family(_rewrite, FORMATS), 2)]
