"""PlayCanvas SOG ("spatially ordered Gaussians", SuperSplat's current export), version 2, read into the raw INRIA
values of ``core.splats.gaussians.GaussianPly`` (``format`` "sog").

Layout (writer: playcanvas/splat-transform ``src/lib/writers/write-sog.ts``; readers: its ``read-sog.ts`` and
playcanvas/engine ``gsplat-sog-data.js``). A scene is a ``meta.json`` and lossless WebP images, either bundled in a
zip archive (``scene.sog``: ``meta.json`` and the images at the archive's root, stored) or as files in one folder
(``meta.json`` beside them; the images are named by ``meta.json``, relative to its folder). ``meta.json``::

    {"version": 2, "count": N,
     "means":  {"mins": [3], "maxs": [3], "files": ["means_l.webp", "means_u.webp"]},
     "scales": {"codebook": [256], "files": ["scales.webp"]},
     "quats":  {"files": ["quats.webp"]},
     "sh0":    {"codebook": [256], "files": ["sh0.webp"]},
     "shN":    {"count": P, "bands": 1..3, "codebook": [256], "files": ["shN_centroids.webp", "shN_labels.webp"]}}

(``shN`` only with SH beyond degree 0.) Every per-Gaussian image is RGBA, at least N texels, Gaussian i at texel i
in row-major order (the writer sorts the Gaussians in Morton order first: the rows come back in that order, not the
source file's). Per Gaussian, with bytes r, g, b, a of its texel:

* means: u = r_l + 256 r_u (16 bits, ``means_l`` low byte, ``means_u`` high byte) per axis (x, y, z in r, g, b);
  t = min + (max - min) u / 65535 (a span of 0 taken as 1, as the readers do); the position is the inverse of the
  writer's t = sign(x) ln(|x| + 1): x = sign(t) (exp|t| - 1). mins and maxs are of t, not x.
* quats ("smallest three"): a = 252 + i names the largest-magnitude component i of (w, x, y, z) (rot_0..rot_3);
  the other three, in increasing index order, are r, g, b as (byte / 255 · 2 - 1) / √2; component i = sqrt(max(0,
  1 - the three squared)) (the writer flips the sign so it is positive). An alpha outside 252-255 is refused (the
  public readers silently take the identity).
* scales: r, g, b index ``scales.codebook`` (the log scales scale_0..2).
* sh0: r, g, b index ``sh0.codebook`` (f_dc_0..2); a is the opacity itself (sigmoid of the logit), stored
  trunc(255 σ(logit)); read as logit(clamp(a / 255, 1e-6, 1 - 1e-6)) as splat-transform reads it.
* shN: label = r + 256 g of ``shN_labels`` picks one of P palette entries; entry p lies in ``shN_centroids`` (64
  entries per row, each C = 3 / 8 / 15 texels wide for bands 1 / 2 / 3: width 64 C) at row p // 64, texels
  (p % 64) C + j for coefficient j; that texel's r, g, b index ``shN.codebook`` for red's, green's and blue's
  coefficient j (f_rest channel-major, as INRIA's). A label at or past P is refused (readers give zeros).

Codebooks are read as float32 (as the readers do). Lossy quantisation, by what the writer keeps: positions to 16 bits
of the log-transformed range, scales and colours to 256 shared values, opacity to 8 bits, rotations to 8 bits per
component, higher SH to a palette of P entries (k-means) of 256 values: the bounds measured against the source PLYs
are in tests/core/splats/test_sog.py.

Images are decoded by an injected ``decode_webp(data, name) -> (H, W, 4) uint8 RGBA`` (``core.splats.webp``: the
backend's, set on import); everything else is here. ``meta.json`` is read within ``MAX_META_BYTES`` and checked
field by field, every image's size is checked (from the WebP header, before decoding, and after) against ``count``,
and archive entries are checked against the archive's size before they are read: a broken or hostile file is a
``SplatsError`` naming the file and the entry or field. Version 1 (``meta.json`` without ``version``) and streamed
SOG (``lod-meta.json``) are refused with what to do.

No bpy, no torch: numpy only.

(Over 400 lines, most of it the format: the docstring and the checks of meta.json and each image,
which a SOG bundle from the wild needs.)
"""

from __future__ import annotations

import json
import math
import os
import zipfile
import zlib

import numpy as np

from . import webp
from .gaussians import GaussianPly, SplatsError, open_file

#: ``GaussianPly.format`` of a SOG, its bundle's extension and the name of its metadata.
FORMAT = "sog"
EXTENSION = ".sog"
META_NAME = "meta.json"
#: The one ``meta.json`` version read.
VERSION = 2
#: A real meta.json is ~16 KB (three 256-entry codebooks); far more is not one.
MAX_META_BYTES = 1 << 20
#: A lossless WebP of the largest SOG texture (16383² RGBA) stays well under this.
MAX_IMAGE_BYTES = 1 << 30
#: At most one Gaussian per texel of a WebP of the largest size.
MAX_COUNT = webp.MAX_SIDE * webp.MAX_SIDE
#: Codebook length the writer uses (indices are bytes).
CODEBOOK_SIZE = 256
#: SH coefficients per channel beyond the DC term, by ``shN.bands``.
SH_COEFFS = {1: 3, 2: 8, 3: 15}
#: Palette entries per row of ``shN_centroids``.
PALETTE_ROW = 64
#: Alpha of a quaternion texel: QUAT_TAG + index of the largest component.
QUAT_TAG = 252
#: The opacity's clamp before the logit (splat-transform's ``sigmoidInv``).
OPACITY_EPS = 1e-6
#: Zip archives start with a local file header (or, empty, the end of central directory).
ZIP_MAGICS = (b"PK\x03\x04", b"PK\x05\x06")
#: Which of meta.json's images each role reads, by its index in ``files``.
_IMAGES = (("means", 0), ("means", 1), ("quats", 0), ("scales", 0), ("sh0", 0))
_SHN_IMAGES = (("shN", 0), ("shN", 1))
#: Deflate expands at most ~1032:1; a zip entry claiming more per stored byte is a forged size.
_MAX_EXPANSION = 1100
#: Which three components (in order) the texel's r, g, b hold, by the largest component's index.
_QUAT_OTHERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


def read(path, decode_webp=None) -> GaussianPly:
    """Read a SOG bundle (``.sog`` zip) or an unbundled SOG (the path of its ``meta.json``) into raw float32 values
    (module docstring). ``decode_webp(data: bytes, name: str)`` -> (H, W, 4) uint8 RGBA, raising ValueError when
    the bytes do not decode; None: this process's (``core.splats.webp.decoder()``). SplatsError naming the file
    and the entry or field when unusable."""
    path = os.fspath(path)
    with _open(path) as source:
        meta = parse_meta(source.read(META_NAME, MAX_META_BYTES), path, source.meta_field)
        decode_webp = decode_webp or webp.decoder()
        if decode_webp is None:
            raise SplatsError(path, "a SOG's images are WebP, which this Python cannot decode", "(file)",
                              hint="import it with the add-on (it converts SOG through the backend), or convert "
                                   "it first: python -m backend splat-asset FILE --out FILE.ply")
        images = {}
        for name in image_names(meta):
            if name not in images:
                images[name] = _decode(source, name, meta["count"], decode_webp, path)
    return from_images(meta, images, path)


def image_names(meta: dict) -> list:
    """The image file names a (checked) meta.json uses, in reading order."""
    roles = _IMAGES + (_SHN_IMAGES if "shN" in meta else ())
    return [meta[role]["files"][i] for role, i in roles]


# -- meta.json ---------------------------------------------------------------------------------------------------

def _refuse_constant(name):
    raise ValueError(f"{name} is not a JSON number")


def parse_meta(data: bytes, path, where: str = META_NAME) -> dict:
    """SOG metadata (``where``: how messages name meta.json) from its bytes, checked field by field: the fields the
    reader uses, with their types, lengths and ranges; an ``shN`` of 0 bands is dropped. SplatsError naming the
    field otherwise (version 1 and streamed SOG named as such)."""
    try:
        meta = json.loads(data.decode("utf-8-sig"), parse_constant=_refuse_constant)
    except UnicodeDecodeError as e:
        raise SplatsError(path, f"{where} is not UTF-8 text (byte {e.start})", where) from None
    except json.JSONDecodeError as e:
        raise SplatsError(path, f"{where} is not valid JSON: {e.msg} at line {e.lineno} column {e.colno}",
                          where) from None
    except (ValueError, RecursionError) as e:
        raise SplatsError(path, f"{where} is not valid JSON: {e}", where) from None
    if not isinstance(meta, dict):
        raise SplatsError(path, f"{where} holds {type(meta).__name__}, expected an object", where)
    if "lodLevels" in meta or "tree" in meta:
        raise SplatsError(path, f"{where} describes a streamed SOG (level-of-detail units), which is not read", where,
                          hint="convert it to one .sog or .ply first (e.g. with playcanvas/splat-transform)")
    version = meta.get("version")
    if version is None:
        raise SplatsError(path, f"{where} has no 'version': a SOG of version 1, which is not read", f"{where}: version",
                          hint="convert it to a current .sog or to .ply (e.g. with playcanvas/splat-transform)")
    if version != VERSION:
        raise SplatsError(path, f"{where}: version {version!r} is not read (SOG version {VERSION} is)",
                          f"{where}: version")

    def need(parent, key, what):
        field = f"{where}: {parent}.{key}" if parent else f"{where}: {key}"
        node = meta if not parent else meta[parent]
        if key not in node:
            raise SplatsError(path, f"{field} is missing ({what})", field)
        return node[key], field

    def integer(value, field, lo, hi):
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise SplatsError(path, f"{field} is {_show(value)}, expected an integer in {lo}..{hi:,}", field)
        return value

    def numbers(value, field, lo_len, hi_len):
        ok = isinstance(value, list) and lo_len <= len(value) <= hi_len and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
        if not ok:
            size = f"{lo_len}" if lo_len == hi_len else f"{lo_len} to {hi_len}"
            raise SplatsError(path, f"{field} is {_show(value)}, expected a list of {size} finite numbers", field)
        return value

    def files(parent, n):
        value, field = need(parent, "files", f"{n} image file name{'s' if n > 1 else ''}")
        if not (isinstance(value, list) and len(value) == n and all(_plain_name(v) for v in value)):
            raise SplatsError(path, f"{field} is {_show(value)}, expected {n} file name{'s' if n > 1 else ''} in "
                                    "meta.json's folder (no path separators)", field)

    for key in ("means", "scales", "quats", "sh0"):
        node, field = need("", key, "an object")
        if not isinstance(node, dict):
            raise SplatsError(path, f"{field} is {_show(node)}, expected an object", field)
    meta["count"] = integer(*need("", "count", "the number of Gaussians"), 0, MAX_COUNT)
    numbers(*need("means", "mins", "3 numbers"), 3, 3)
    numbers(*need("means", "maxs", "3 numbers"), 3, 3)
    files("means", 2)
    for key in ("scales", "sh0"):
        numbers(*need(key, "codebook", f"{CODEBOOK_SIZE} numbers"), 1, CODEBOOK_SIZE)
        files(key, 1)
    files("quats", 1)
    shn = meta.get("shN")
    if shn is not None:
        if not isinstance(shn, dict):
            raise SplatsError(path, f"{where}: shN is {_show(shn)}, expected an object", f"{where}: shN")
        bands = integer(*need("shN", "bands", "the SH degree, 1 to 3"), 0, max(SH_COEFFS))
        if bands == 0:  # the readers take it as no higher SH
            del meta["shN"]
        else:
            integer(*need("shN", "count", "the palette size"), 1, 1 << 16)
            numbers(*need("shN", "codebook", f"{CODEBOOK_SIZE} numbers"), 1, CODEBOOK_SIZE)
            files("shN", 2)
    return meta


def _plain_name(v) -> bool:
    return (isinstance(v, str) and 0 < len(v) <= 255 and v not in (".", "..") and "/" not in v and "\\" not in v
            and "\0" not in v)


def _show(value) -> str:
    text = json.dumps(value)
    return text if len(text) <= 60 else text[:57] + "..."


# -- the images ----------------------------------------------------------------------------------------------------

class _Folder:
    """An unbundled SOG: ``meta.json`` at ``path``, its images beside it."""

    def __init__(self, path):
        self.path, self.folder = path, os.path.dirname(os.path.abspath(path))
        self.meta_field = os.path.basename(path)

    def read(self, name, limit) -> bytes:
        full = self.path if name == META_NAME else os.path.join(self.folder, name)
        with open_file(full) as f:  # SplatsError naming that file when missing or not a regular file
            data = f.read(limit + 1)
        if len(data) > limit:
            raise SplatsError(self.path, f"{name} is larger than {limit >> 20} MiB: not a SOG {_what(name)}", name)
        return data

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


class _Bundle:
    """A SOG bundle: a zip archive with ``meta.json`` at its root (or in its one folder)."""

    def __init__(self, path):
        self.path = path
        self.file = open_file(path)
        try:
            self.size = os.fstat(self.file.fileno()).st_size
            self.zip = zipfile.ZipFile(self.file)
            self.entries = {i.filename: i for i in self.zip.infolist() if not i.is_dir()}
        except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError, OverflowError,
                UnicodeDecodeError) as e:
            self.file.close()
            raise SplatsError(path, f"is not a readable SOG bundle (zip archive), truncated or corrupt? ({e})",
                              "(file)") from None
        metas = [n for n in self.entries if n == META_NAME or n.endswith("/" + META_NAME)]
        if META_NAME not in metas and len(metas) != 1:
            self.file.close()
            listed = ", ".join(sorted(self.entries)[:8]) or "none"
            raise SplatsError(path, f"a zip archive without {META_NAME} at its root: not a SOG bundle (entries: "
                                    f"{listed})", META_NAME)
        self.prefix = "" if META_NAME in metas else metas[0][:-len(META_NAME)]
        self.meta_field = self.prefix + META_NAME

    def read(self, name, limit) -> bytes:
        entry = self.prefix + name
        info = self.entries.get(entry)
        if info is None:
            listed = ", ".join(sorted(self.entries)[:12])
            raise SplatsError(self.path, f"the bundle has no entry {entry!r}, which {META_NAME} names (entries: "
                                         f"{listed})", entry)
        # the directory's sizes are claims: checked against the archive before anything is read
        if info.compress_size > self.size or (info.compress_type == zipfile.ZIP_STORED
                                              and info.compress_size != info.file_size) \
                or info.file_size > _MAX_EXPANSION * max(info.compress_size, 1) + 1024:
            raise SplatsError(self.path, f"entry {entry!r}: the archive's directory gives impossible sizes "
                                         f"({info.compress_size:,} bytes stored for {info.file_size:,}): truncated "
                                         "or corrupt", entry)
        if info.file_size > limit:
            raise SplatsError(self.path, f"entry {entry!r} is {info.file_size:,} bytes: not a SOG {_what(name)}",
                              entry)
        try:
            return self.zip.read(info)
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError, NotImplementedError, RuntimeError,
                ValueError) as e:
            raise SplatsError(self.path, f"entry {entry!r} cannot be read: {e}", entry) from None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.zip.close()
        self.file.close()
        return False


def _what(name) -> str:
    return "metadata file" if name == META_NAME else "image"


def _open(path):
    """The SOG at ``path`` as a source of named entries: a bundle (zip) or a meta.json beside its images."""
    with open_file(path) as f:
        head = f.read(4)
    if head.startswith(ZIP_MAGICS):
        return _Bundle(path)
    if os.path.basename(path).lower().endswith(EXTENSION):
        raise SplatsError(path, "is named .sog but is not a zip archive (a SOG bundle is one)", "(file)")
    return _Folder(path)


def _decode(source, name, count, decode_webp, path) -> np.ndarray:
    """Image ``name`` decoded to (H, W, 4) uint8 RGBA, checked: a lossless WebP (its header, before decoding) of
    at least ``count`` texels, decoded to the size its header gives."""
    data = source.read(name, MAX_IMAGE_BYTES)
    field = getattr(source, "prefix", "") + name
    try:
        width, height, kind = webp.header(data)
    except ValueError as e:
        raise SplatsError(path, f"{field}: {e}", field) from None
    if kind != "lossless":
        raise SplatsError(path, f"{field} is a {kind} WebP: SOG images are lossless (their bytes are indices and "
                                "bit fields, which a lossy encoder changes)", field)
    if not name.startswith("shN_centroids") and width * height < count:
        raise SplatsError(path, f"{field} is {width} x {height} = {width * height:,} texels, fewer than meta.json's "
                                f"count {count:,}", field)
    try:
        image = decode_webp(data, field)
    except ValueError as e:
        raise SplatsError(path, f"{field} cannot be decoded: {e}", field) from None
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.shape != (height, width, 4):
        raise SplatsError(path, f"{field} decoded to {image.dtype} {image.shape}, expected uint8 ({height}, {width}, "
                                "4) RGBA as its header says", field)
    return image


# -- values --------------------------------------------------------------------------------------------------------

def from_images(meta: dict, images: dict, path) -> GaussianPly:
    """Raw INRIA values of a SOG from its checked ``meta`` (``parse_meta``) and its decoded images ``{file name:
    (H, W, 4) uint8 RGBA}`` (module docstring for the formulas); SplatsError naming the image when one is too small
    or holds values the format does not allow (a quaternion tag outside 252-255, a codebook index past the
    codebook, a palette label past shN.count)."""
    n = meta["count"]

    def texels(role, i=0):
        name = meta[role]["files"][i]
        image = np.asarray(images[name])
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 4:
            raise SplatsError(path, f"{name} is {image.dtype} {image.shape}, expected (H, W, 4) uint8 RGBA", name)
        if image.shape[0] * image.shape[1] < n:
            raise SplatsError(path, f"{name} has {image.shape[0] * image.shape[1]:,} texels, fewer than meta.json's "
                                    f"count {n:,}", name)
        return image.reshape(-1, 4)[:n], name

    def lookup(role, indices, name):
        book = np.asarray(meta[role]["codebook"], np.float32)  # float32, as the readers hold it
        if indices.size and int(indices.max()) >= len(book):
            raise SplatsError(path, f"{name} indexes entry {int(indices.max())} of {role}.codebook, which has "
                                    f"{len(book)}", name)
        return book[indices]

    lo, name_l = texels("means", 0)
    hi, _ = texels("means", 1)
    u = lo[:, :3].astype(np.float64) + 256.0 * hi[:, :3]
    mins = np.asarray(meta["means"]["mins"], np.float64)
    span = np.asarray(meta["means"]["maxs"], np.float64) - mins
    span[span == 0] = 1.0  # the readers' `|| 1`
    t = mins + span * (u / 65535.0)
    with np.errstate(over="ignore"):  # a forged range: an infinite position, dropped as non-finite on decoding
        xyz = (np.sign(t) * np.expm1(np.abs(t))).astype(np.float32)

    q, name_q = texels("quats")
    largest = q[:, 3].astype(np.int64) - QUAT_TAG
    bad = (largest < 0) | (largest > 3)
    if bad.any():
        raise SplatsError(path, f"{name_q}: {int(bad.sum()):,} of {n:,} texels have an alpha outside "
                                f"{QUAT_TAG}-{QUAT_TAG + 3} (the largest component's index): not a SOG quaternion "
                                "image", name_q)
    three = (q[:, :3].astype(np.float64) / 255.0 * 2.0 - 1.0) / math.sqrt(2.0)
    rot = np.zeros((n, 4), np.float64)
    rows = np.arange(n)[:, None]
    rot[rows, _QUAT_OTHERS[largest]] = three
    rot[np.arange(n), largest] = np.sqrt(np.maximum(0.0, 1.0 - np.sum(three * three, axis=1)))

    s, name_s = texels("scales")
    scale = lookup("scales", s[:, :3], name_s)
    c, name_c = texels("sh0")
    f_dc = lookup("sh0", c[:, :3], name_c)
    alpha = np.clip(c[:, 3].astype(np.float64) / 255.0, OPACITY_EPS, 1.0 - OPACITY_EPS)
    opacity = np.log(alpha / (1.0 - alpha)).astype(np.float32)

    f_rest = np.zeros((n, 3, 0), np.float32)
    if "shN" in meta:
        f_rest = _sh_rest(meta, images, n, texels, lookup, path)
    return GaussianPly(xyz=xyz, f_dc=f_dc, f_rest=f_rest, opacity=opacity, scale=scale,
                       rot=rot.astype(np.float32), format=FORMAT)


def _sh_rest(meta, images, n, texels, lookup, path) -> np.ndarray:
    """f_rest (N, 3, C) channel-major of the SH palette (module docstring)."""
    shn = meta["shN"]
    coeffs, palette_count = SH_COEFFS[shn["bands"]], shn["count"]
    name_c = shn["files"][0]
    centroids = np.asarray(images[name_c])
    rows_needed = -(-palette_count // PALETTE_ROW)
    if centroids.dtype != np.uint8 or centroids.ndim != 3 or centroids.shape[1:] != (PALETTE_ROW * coeffs, 4) \
            or centroids.shape[0] < rows_needed:
        raise SplatsError(path, f"{name_c} is {centroids.dtype} {centroids.shape}, expected at least "
                                f"({rows_needed}, {PALETTE_ROW * coeffs}, 4) uint8 for a palette of "
                                f"{palette_count:,} entries of {shn['bands']} bands", name_c)
    labels_px, name_l = texels("shN", 1)
    labels = labels_px[:, 0].astype(np.int64) + 256 * labels_px[:, 1].astype(np.int64)
    beyond = labels >= palette_count
    if beyond.any():
        raise SplatsError(path, f"{name_l}: {int(beyond.sum()):,} labels are past the palette of shN.count = "
                                f"{palette_count:,} entries", name_l)
    # entry p is row p // 64, texels (p % 64) C .. + C - 1: the image read as (rows · 64, C) entries is indexed by p
    palette = centroids.reshape(-1, coeffs, 4)[:, :, :3]
    return np.swapaxes(lookup("shN", palette[labels], name_c), 1, 2)  # (N, C, 3) -> channel-major (N, 3, C)
