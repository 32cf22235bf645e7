"""3D Gaussian splat files: read (INRIA PLY, half-float PLY, SuperSplat compressed PLY, .splat), write, decode,
and evaluate their spherical harmonics.

Every reader returns a ``GaussianPly``: the raw values an INRIA file would hold (positions, ``f_dc``, ``f_rest``,
opacity logit, log scales, quaternion (w, x, y, z)), so decoding and everything downstream is one path.
``read(path)`` picks the reader by content (PLY magic, then the header's elements) or, for headerless ``.splat``,
by extension; ``load(path) = decode(read(path))``. ``GaussianPly.format`` says which layout the file had
(``FORMAT_NAMES``).

INRIA PLY (graphdeco-inria/gaussian-splatting ``scene/gaussian_model.py``, ``save_ply``): one ``vertex`` element
with float properties ``x y z [nx ny nz] f_dc_0..2 [f_rest_0..M-1] opacity scale_0..2 rot_0..3``, binary little-
or big-endian, where

* ``opacity`` is a logit (decoded with a sigmoid), ``scale_*`` are natural logs (decoded with exp),
* ``rot_*`` is a quaternion (w, x, y, z), not necessarily unit (decoded by normalising),
* ``f_rest`` holds SH degree d >= 1 coefficients channel-major: M = 3 ((d+1)^2 - 1), first all of red's
  coefficients 1..K-1, then green's, then blue's. Colour = max(0.5 + Σ_k SH_k(dir) c_k, 0), dir = normalise(mean -
  camera centre).

Property types: ``float`` and ``double`` are read as float32 ("inria"). A file whose every Gaussian property
(x y z f_dc_* opacity scale_* rot_* f_rest_*) is ``ushort``/``uint16`` is a half-float export: the 16 bits are
IEEE half floats in the file's byte order ("inria_half"). Any other integer type among them (or a mix of ushort
and float) is refused naming the property: integers there have no agreed meaning. Other properties (normals,
labels...) keep their own type in ``extra``.

SuperSplat compressed PLY ("supersplat_compressed"; writers: playcanvas/supersplat ``src/splat-serialize.ts``
``serializePlyCompressed``, playcanvas/splat-transform ``src/lib/writers/write-compressed-ply.ts`` and
``compressed-chunk.ts``; readers: playcanvas/engine ``src/scene/gsplat/gsplat-compressed-data.js``,
playcanvas/splat-transform ``src/lib/readers/decompress-ply.ts``). Elements, in order:

* ``chunk`` (one per 256 consecutive vertices, ceil(M / 256) rows), float: ``min_x min_y min_z max_x max_y max_z``
  (the box of the chunk's means), ``min_scale_x.. max_scale_z`` (range of the log scales, clamped to [-20, 20]),
  and in newer files ``min_r min_g min_b max_r max_g max_b`` (range of the colours 0.5 + C0 f_dc).
* ``vertex`` (M rows), uint32 ``packed_position packed_rotation packed_scale packed_color``.
* optional ``sh`` (M rows), uchar ``f_rest_0..`` (9, 24 or 45, INRIA's channel-major order).

A u-bit field k decodes to t = k / (2^u - 1) and a value lo + t (hi - lo) with the chunk's range.
``packed_position`` and ``packed_scale``: x in bits 21-31 (11 bits), y in bits 11-20 (10), z in bits 0-10 (11).
``packed_color``: r bits 24-31, g 16-23, b 8-15, alpha 0-7 (8 each); with chunk colours r = lerp(min_r, max_r, t),
without them r = t; f_dc = (r - 0.5) / C0; alpha is the sigmoid of the opacity itself, stored as the logit
log(a / (1 - a)), with ±40 for a = 0 / 1 as the engine does. ``packed_rotation`` ("smallest three"): bits 30-31
= index i of the largest-magnitude component in file order (rot_0..rot_3 = w, x, y, z); the other three
components, in increasing index order, are in bits 20-29, 10-19 and 0-9 as (k / 1023 - 0.5) · √2 (the writer
stores q_j · √2/2 + 0.5, so ±1/√2 spans the range); the writer flips the quaternion's sign so component i is
positive, and it is decoded as sqrt(max(0, 1 - a² - b² - c²)). ``sh`` bytes: the writer stores
trunc((v / 8 + 0.5) · 256) clamped to 0..255; decoded to the bucket's middle ((k + 0.5) / 256 - 0.5) · 8, with
0 → -4 and 255 → +4 (splat-transform's reader; the engine's k · 8/255 - 4 differs by < 1/64).

antimatter15 ``.splat`` ("splat"; antimatter15/splat ``convert.py`` writes it, ``main.js`` reads it): no header,
32 bytes per Gaussian, little-endian: position 3 × float32, scale 3 × float32 (σ itself, not its log), colour
RGBA 4 × uint8 (r = (0.5 + C0 f_dc) · 255, alpha = sigmoid(opacity) · 255), quaternion 4 × uint8 (w, x, y, z),
byte = q / |q| · 128 + 128, read back as (byte - 128) / 128. Read as log σ, f_dc = (byte / 255 - 0.5) / C0,
opacity logit of byte / 255 clamped to [1e-6, 1 - 1e-6] (so 0 and 255 stay finite), and that raw quaternion.
No SH beyond degree 0.

TRELLIS / Amodal3R write the INRIA layout with SH degree 0 (17 properties, zero normals), the object inside the
unit cube, and positions/rotations multiplied by ``ZUP_TO_TRELLIS_FILE`` (the file holds (x, -z, y) of their
Z-up frame); ``detect_axes`` recognises them. Everything else decodes exactly like an INRIA file.

Raw values (``GaussianPly``) are kept apart from decoded ones (``Gaussians``) so that write -> read is bit-exact.
Rows with NaN/inf, zero quaternions or scales that overflow are dropped on decoding and counted, never passed on.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

from . import files
from . import sh as _sh
from .sh import SH_C0, SH_C1, SH_C2, SH_C3  # noqa: F401 (defined once in core.sh; splats.SH_C0 etc. stay usable)

#: File axes from TRELLIS's Z-up object axes: p_file = ZUP_TO_TRELLIS_FILE @ p (a -90° turn about X undoes it).
ZUP_TO_TRELLIS_FILE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

#: What TRELLIS's ``Gaussian.save_ply`` writes (microsoft/TRELLIS ``trellis/representations/gaussian/
#: gaussian_model.py``, ``construct_list_of_attributes`` with SH degree 0), in this order, all float32.
TRELLIS_PROPERTIES = ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
                      "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")

#: How far a TRELLIS/Amodal3R mean can be from the origin. microsoft/TRELLIS
#: ``trellis/models/structured_latent_vae/decoder_gs.py`` (``to_representation``) puts each Gaussian at its voxel
#: centre (i + 0.5) / 64 plus tanh(.) / 64 · 0.5 · voxel_size, with resolution 64 and voxel_size 1.5 in the
#: released decoder's config (``slat_dec_gs_swin8_B_64l8gs32_fp16``), so at most 0.75 voxel from the centre; the
#: ``Gaussian`` aabb [-0.5, -0.5, -0.5, 1, 1, 1] then shifts the cube to [-0.5, 0.5]^3 and save_ply only permutes
#: axes. The tightest bound is 0.5 - 0.5/64 + 0.75/64 = 0.50390625; we accept 0.75 voxel beyond the cube's face,
#: 0.5 + 0.75/64 = 0.51171875, plus float slack, so that a fork with another voxel-centre convention still passes.
TRELLIS_MEAN_BOUND = 0.5 + 0.75 / 64 + 1e-5

REQUIRED = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
            "rot_0", "rot_1", "rot_2", "rot_3")
MAX_HEADER = 1 << 16        # bytes: a degree-3 INRIA header is ~1.5 KB
MAX_HEADER_LINES = 4096     # an INRIA header has 62 property lines at most; more is not a splat file
_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
          "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
_PLY_TYPE = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint", "f4": "float",
             "f8": "double"}

#: Human names of ``GaussianPly.format`` values, for import reports.
FORMAT_NAMES = {"inria": "INRIA 3DGS PLY", "inria_half": "INRIA 3DGS PLY, half floats",
                "supersplat_compressed": "SuperSplat compressed PLY", "splat": "antimatter15 .splat"}
ACCEPTED = ("binary INRIA 3DGS PLY (float, double or half floats in ushort slots; TRELLIS/Amodal3R included), "
            "SuperSplat compressed PLY (.compressed.ply) and antimatter15 .splat")

#: Mesh files: not splats, but what the car-asset import converts to Gaussians (backend ``mesh-asset``, trimesh);
#: a ``.ply`` is a mesh when ``is_mesh_ply`` says so.
MESH_EXTENSIONS = (".glb", ".gltf", ".obj", ".stl", ".off")

#: SuperSplat compressed PLY: splats per chunk, and the chunk/vertex properties (module docstring).
CHUNK_SIZE = 256
_CHUNK_PROPS = ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z", "min_scale_x", "min_scale_y", "min_scale_z",
                "max_scale_x", "max_scale_y", "max_scale_z")
_CHUNK_COLOR_PROPS = ("min_r", "min_g", "min_b", "max_r", "max_g", "max_b")
_PACKED_PROPS = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
#: Opacity logit for alpha bytes 0 and 255 (playcanvas/engine gsplat-compressed-data.js uses ±40).
_COMPRESSED_LOGIT_LIMIT = 40.0

#: antimatter15 .splat: one 32-byte little-endian record per Gaussian.
SPLAT_RECORD = np.dtype([("xyz", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)), ("rot", "u1", (4,))])
_SPLAT_ALPHA_EPS = 1e-6


class SplatsError(files.InputError):
    """A Gaussian file that cannot be used; the message names the file and what is wrong. ``field``: the property,
    element or "header line N" at fault ("(file)" for the file as a whole)."""

    def __init__(self, path, message, field=None, hint=None):
        files.InputError.__init__(self, path, field, message, hint)
        self.args = (f"{os.path.basename(self.path)}: {message} ({self.path})",)  # the text it has always had


def num_sh_coefficients(degree: int) -> int:
    return (degree + 1) ** 2


@dataclass
class GaussianPly:
    """Raw per-Gaussian values as an INRIA file holds them (float32), N rows.

    ``f_rest`` is (N, 3, K - 1): channel-major, as in the file. ``extra`` keeps any other vertex properties
    (normals, per-splat labels...) in file order so a rewrite loses nothing; decoding ignores them.
    ``format`` is the layout the values came from (a key of ``FORMAT_NAMES``); ``properties`` the file's vertex
    property names in file order (empty when not read from a PLY vertex element).
    """

    xyz: np.ndarray
    f_dc: np.ndarray
    f_rest: np.ndarray
    opacity: np.ndarray
    scale: np.ndarray
    rot: np.ndarray
    extra: dict = field(default_factory=dict)
    format: str = "inria"
    properties: tuple = ()

    def __len__(self):
        return len(self.xyz)

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.f_rest.shape[2] + 1))) - 1


@dataclass
class Gaussians:
    """Decoded Gaussians in the file's object frame.

    ``means`` (N, 3); ``scales`` (N, 3) standard deviations along the local axes; ``quats`` (N, 4) unit (w, x, y, z);
    ``opacities`` (N,) in [0, 1]; ``sh`` (N, K, 3) coefficient-major (``sh[:, 0]`` is the DC term). All float32.
    ``dropped`` counts the rows left out on decoding, by reason.
    """

    means: np.ndarray
    scales: np.ndarray
    quats: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    dropped: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.means)

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.sh.shape[1]))) - 1

    def base_colors(self) -> np.ndarray:
        """View-independent colour (the DC term only), (N, 3) in [0, ...)."""
        return np.maximum(SH_C0 * self.sh[:, 0] + 0.5, 0.0).astype(np.float32)

    def extents(self):
        """Axis-aligned bounds (min (3,), max (3,)) of the means; zeros for an empty set."""
        if not len(self):
            return np.zeros(3), np.zeros(3)
        return self.means.min(axis=0).astype(np.float64), self.means.max(axis=0).astype(np.float64)


# --------------------------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------------------------

def read(path) -> GaussianPly:
    """Read any accepted Gaussian file (module docstring) into raw float32 arrays; SplatsError if unusable.

    PLY files (INRIA, half-float, SuperSplat compressed) are recognised by content; headerless ``.splat`` files by
    their extension. Only regular files are opened (a FIFO or a directory is refused at once, not waited on).
    """
    path = os.fspath(path)
    head = _head(path, 4)
    if head.startswith(b"ply"):
        return read_ply(path)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".splat":
        return read_splat(path)
    raise SplatsError(path, _not_accepted(head, ext))


def load(path) -> Gaussians:
    """read + decode: decoded Gaussians of any accepted file."""
    return decode(read(path))


def _file_error(path, field, message):
    """``files``' error callback: its "not found" / "is a FIFO ..." messages as SplatsError."""
    return SplatsError(path, "file not found" if message == "not found" else message, field)


def _open(path):
    return files.open_regular(path, _file_error)


def _head(path, n: int) -> bytes:
    try:
        with _open(path) as f:
            return f.read(n)
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None


def _not_accepted(head: bytes, ext: str) -> str:
    if head.startswith(b"glTF") or ext in MESH_EXTENSIONS:
        return (f"a mesh ({ext or 'glTF'}), not Gaussian splats: the car-asset import and `python -m backend "
                f"mesh-asset` turn meshes into Gaussians; Gaussian files accepted are {ACCEPTED}")
    if ext in (".fbx", ".blend", ".usd", ".usdz", ".usdc", ".dae", ".3ds"):
        return (f"{ext} files are not read: export the car as GLB, glTF, OBJ, STL or PLY (mesh), or as Gaussian "
                f"splats ({ACCEPTED})")
    if ext in (".ksplat", ".spz", ".sog", ".sogs", ".lcc"):
        return (f"{ext} Gaussian files are not supported: convert it to .ply (e.g. with playcanvas/splat-transform); "
                f"accepted are {ACCEPTED}")
    return f"not a PLY file (it does not start with 'ply') and not named .splat: accepted are {ACCEPTED}"


def _line_error(path, n: int, message: str) -> SplatsError:
    """A header problem, named by its line (``field`` "header line N", as the message has always said)."""
    e = SplatsError(path, f"header line {n}: {message}", f"header line {n}")
    e.message = message
    return e


def _header_lines(raw: bytes, path):
    """(header lines as bytes without their line ends, offset of the first data byte).

    The header ends at the first line whose only word is ``end_header`` (PLY's rule; surrounding spaces, tabs and
    a CR of CRLF files are allowed, as plyfile allows them): a ``comment`` or ``obj_info`` line that merely
    contains the words does not end it, so it can never shift the data."""
    if raw.split(b"\n", 1)[0].strip(b" \t\r") != b"ply":
        raise SplatsError(path, f"not a PLY file (its first line is not 'ply'); accepted are {ACCEPTED}")
    lines, pos = [], 0
    while True:
        nl = raw.find(b"\n", pos)
        if nl < 0:
            if raw[pos:].strip(b" \t\r") == b"end_header":
                raise SplatsError(path, "the header ends without a newline after 'end_header' (truncated file?)")
            if len(raw) >= MAX_HEADER:
                raise SplatsError(path, f"no 'end_header' line in the first {MAX_HEADER} bytes: the header is too "
                                        "long, or this is not a PLY file")
            raise SplatsError(path, "the header has no 'end_header' line: the file is truncated or not a PLY file")
        line = raw[pos:nl]
        pos = nl + 1
        if line.split() == [b"end_header"]:
            return lines, pos
        lines.append(line)
        if len(lines) > MAX_HEADER_LINES:
            raise SplatsError(path, f"the header has more than {MAX_HEADER_LINES} lines: not a splat file")


def _parse_header(raw: bytes, path, binary_only: bool = True):
    """(format, [[element name, count, [(property, numpy type code or None for a list)]]], data offset) of the
    header at the start of ``raw``; SplatsError naming the header line for anything malformed."""
    lines, start = _header_lines(raw, path)
    fmt, elements = None, []
    for n, raw_line in enumerate(lines[1:], start=2):
        words = raw_line.split()
        if not words or words[0] in (b"comment", b"obj_info"):
            continue  # free text: any bytes (UTF-8 names), never parsed
        try:
            line = raw_line.decode("ascii").rstrip("\r")
        except UnicodeDecodeError as e:
            raise _line_error(path, n, f"is not ASCII text (byte {e.start}: {raw_line[:60]!r})") from None
        words = line.split()
        if words[0] == "format":
            if len(words) != 3:
                raise _line_error(path, n, f"malformed format line {line!r}")
            if fmt is not None:
                raise _line_error(path, n, "a second format line")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not re.fullmatch(r"\d{1,15}", words[2]):
                raise _line_error(path, n, f"malformed element line {line!r}")
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property":
            if not elements:
                raise _line_error(path, n, "property before any element")
            if len(words) >= 2 and words[1] == "list":
                if len(words) != 5 or words[2] not in _TYPES or words[3] not in _TYPES:
                    raise _line_error(path, n, f"malformed list property {line!r} (expected 'property list "
                                               "<count type> <item type> <name>')")
                elements[-1][2].append((words[-1], None))
                continue
            if len(words) != 3 or words[1] not in _TYPES:
                raise _line_error(path, n, f"unknown property {line!r}")
            names = [p[0] for p in elements[-1][2]]
            if words[2] in names:
                raise _line_error(path, n, f"property {words[2]!r} appears twice")
            elements[-1][2].append((words[2], _TYPES[words[1]]))
        else:
            raise _line_error(path, n, f"unexpected {words[0]!r}")
    if binary_only:
        _check_binary(fmt, path)
    return fmt, elements, start


def read_ply_header(path):
    """(format, elements, data offset) of a PLY file's header (see ``_parse_header``; ASCII files included), read
    from a regular file only; SplatsError naming the file (and the header line) otherwise. For callers that only
    need to know what a PLY holds (the mesh import)."""
    path = os.fspath(path)
    try:
        with _open(path) as f:
            raw = f.read(MAX_HEADER)
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None
    return _parse_header(raw, path, binary_only=False)


def _check_binary(fmt, path) -> None:
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        raise SplatsError(path, f"format {fmt!r} is not supported: expected binary_little_endian or "
                                "binary_big_endian (ASCII splat files are not used in practice)", "format")


def _element(elements, name):
    """The first element called ``name`` as (count, [(property, type)]), or None."""
    for e in elements:
        if e[0] == name:
            return e[1], e[2]
    return None


_GAUSSIAN_HINTS = ("f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1",
                   "rot_2", "rot_3") + _PACKED_PROPS


def _mesh_message(elements):
    """A message when the PLY looks like a mesh or point cloud (no Gaussian property at all), else None."""
    vertex = _element(elements, "vertex")
    if vertex is None:
        return None
    names = [p for p, _ in vertex[1]]
    if not names or set(names) & set(_GAUSSIAN_HINTS) or _element(elements, "chunk") is not None:
        return None
    face = _element(elements, "face")
    what = f"{vertex[0]} vertices ({' '.join(names[:8])}{' ...' if len(names) > 8 else ''})"
    what += f" and {face[0]} faces" if face is not None else ""
    return (f"looks like a mesh without Gaussian properties: it has {what} but none of f_dc_*, opacity, scale_*, "
            "rot_*: import it as a mesh asset (.glb/.obj/.ply mesh)")


def is_mesh_ply(path) -> bool:
    """True for a readable PLY (binary or ASCII) whose header has faces and no Gaussian property (a mesh to
    convert); never raises."""
    try:
        _, elements, _ = read_ply_header(path)
    except (OSError, SplatsError):
        return False
    face = _element(elements, "face")
    return face is not None and face[0] > 0 and _mesh_message(elements) is not None


def _read_elements(f, path, size: int, order: str, elements, start: int, wanted) -> dict:
    """Structured arrays of the ``wanted`` elements (first of each name), skipping the ones before them."""
    noun = {"vertex": "Gaussians", "chunk": "chunks", "sh": "SH rows"}
    last = max(i for i, e in enumerate(elements) if e[0] in wanted)
    out, offset = {}, start
    for name, count, props in elements[:last + 1]:
        if any(t is None for _, t in props):
            if name in wanted and name not in out:
                raise SplatsError(path, f"the {name!r} element has list properties", name)
            raise SplatsError(path, f"element {name!r} before {elements[last][0]!r} has list properties", name)
        dtype = np.dtype([(p, order + t) for p, t in props])
        need = count * dtype.itemsize
        if name in wanted and name not in out:
            if not props:
                raise SplatsError(path, f"the {name!r} element has no properties", name)
            if offset + need > size:  # checked before anything is allocated: counts are claims
                raise SplatsError(path, f"truncated: the header promises {count} {noun.get(name, name + ' rows')} "
                                        f"({need} bytes from byte {offset}) but the file has {size} bytes", name)
            f.seek(offset)
            buf = f.read(need)
            if len(buf) != need:  # the file shrank while being read
                raise SplatsError(path, f"truncated: {len(buf)} of the {need} bytes of the {name!r} element could be "
                                        "read", name)
            out[name] = np.frombuffer(buf, dtype=dtype, count=count)
        offset += need
    return out


def read_ply(path) -> GaussianPly:
    """Read a Gaussian-splat PLY (INRIA, TRELLIS/Amodal3R, half-float or SuperSplat compressed) into raw float32
    arrays; SplatsError if unusable."""
    path = os.fspath(path)
    try:
        with _open(path) as f:
            size = os.fstat(f.fileno()).st_size
            head = f.read(MAX_HEADER)
            fmt, elements, start = _parse_header(head, path, binary_only=False)
            mesh = _mesh_message(elements)
            if mesh:
                raise SplatsError(path, mesh)
            _check_binary(fmt, path)
            order = "<" if fmt == "binary_little_endian" else ">"
            vertex = _element(elements, "vertex")
            if vertex is None:
                raise SplatsError(path, "no 'vertex' element", "vertex")
            vnames = [p for p, _ in vertex[1]]
            if _element(elements, "chunk") is not None or "packed_position" in vnames:
                _check_compressed_header(elements, path)
                wanted = ("chunk", "vertex", "sh") if _element(elements, "sh") is not None else ("chunk", "vertex")
                arrays = _read_elements(f, path, size, order, elements, start, wanted)
                return _from_compressed(arrays, path)
            data = _read_elements(f, path, size, order, elements, start, ("vertex",))["vertex"]
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None
    return _from_structured(data, vnames, path)


def _type_name(dt: np.dtype) -> str:
    code = dt.str[1:]
    return f"{_PLY_TYPE.get(code, code)} ({dt.name})"


def _storage(data, keys, path) -> str:
    """"inria" when every key is float/double, "inria_half" when every key is ushort; SplatsError otherwise."""
    kinds = {k: data.dtype[k] for k in keys}
    nonfloat = [k for k in keys if kinds[k].kind != "f"]
    if not nonfloat:
        return "inria"
    if len(nonfloat) == len(keys) and all(kinds[k].str[1:] == "u2" for k in keys):
        return "inria_half"
    k = nonfloat[0]
    more = f" (and {len(nonfloat) - 1} more)" if len(nonfloat) > 1 else ""
    if all(kinds[n].str[1:] == "u2" for n in nonfloat):
        raise SplatsError(path, f"property {k!r}{more} is stored as {_type_name(kinds[k])} while others are "
                                "float: a half-float export stores every Gaussian property as ushort, a mix is "
                                "ambiguous; re-export the file as float32", k)
    raise SplatsError(path, f"property {k!r}{more} is stored as {_type_name(kinds[k])}: Gaussian properties must be "
                            "float or double (integers have no agreed scale); re-export the file as float32", k)


def _from_structured(data, names, path) -> GaussianPly:
    missing = [k for k in REQUIRED if k not in names]
    if missing:
        raise SplatsError(path, f"missing required properties {missing}", missing[0])
    rest = sorted((n for n in names if n.startswith("f_rest_")), key=lambda n: int(n[7:]) if n[7:].isdigit() else -1)
    if rest and [n[7:] for n in rest] != [str(i) for i in range(len(rest))]:
        raise SplatsError(path, f"f_rest properties must be numbered 0..{len(rest) - 1} without gaps", rest[0])
    valid = {3 * (num_sh_coefficients(d) - 1): d for d in range(4)}
    if len(rest) not in valid:
        raise SplatsError(path, f"{len(rest)} f_rest properties: expected 0, 9, 24 or 45 (SH degree 0-3)",
                          rest[-1])
    used = list(REQUIRED) + rest
    storage = _storage(data, used, path)

    def column(k):
        if storage == "inria_half":  # the same bits as IEEE half floats, in the file's byte order
            return data[k].view(data.dtype[k].str[0] + "f2")
        return data[k]

    def cols(keys):  # doubles beyond float32's range become inf here, and are dropped on decoding
        out = np.empty((len(data), len(keys)), np.float32)
        with np.errstate(invalid="ignore", over="ignore"):
            for i, k in enumerate(keys):
                out[:, i] = column(k)
        return out

    K1 = len(rest) // 3
    used_set = set(used)
    return GaussianPly(
        xyz=cols(["x", "y", "z"]), f_dc=cols(["f_dc_0", "f_dc_1", "f_dc_2"]),
        f_rest=cols(rest).reshape(len(data), 3, K1), opacity=cols(["opacity"])[:, 0],
        scale=cols(["scale_0", "scale_1", "scale_2"]), rot=cols(["rot_0", "rot_1", "rot_2", "rot_3"]),
        extra={n: data[n].astype(data.dtype[n].newbyteorder("=")) for n in names if n not in used_set},
        format=storage, properties=tuple(names))


# -- SuperSplat compressed PLY -------------------------------------------------------------------------------------

def _require_properties(path, what, element, types: dict, needed, allowed, expected) -> None:
    """Refuse an element of the compressed layout that lacks one of ``needed`` or stores one in another type."""
    missing = [p for p in needed if p not in types]
    if missing:
        raise SplatsError(path, f"{what} needs {element} properties {list(needed)}; missing {missing}", missing[0])
    bad = [p for p in needed if types[p] not in allowed]
    if bad:
        raise SplatsError(path, f"{what}: {element} property {bad[0]!r} is {_type_name(np.dtype(types[bad[0]]))}, "
                                f"expected {expected}", bad[0])


def _check_compressed_header(elements, path) -> None:
    """Refuse a compressed layout that is incomplete or inconsistent, naming what is wrong (before reading data)."""
    what = "a SuperSplat compressed PLY"
    chunk, vertex, sh = (_element(elements, n) for n in ("chunk", "vertex", "sh"))
    if chunk is None:
        raise SplatsError(path, f"the vertices have packed_* properties ({what}) but there is no 'chunk' element",
                          "chunk")
    _require_properties(path, what, "vertex", dict(vertex[1]), _PACKED_PROPS, ("u4", "i4"), "uint (32-bit)")
    ctypes = dict(chunk[1])
    needed = _CHUNK_PROPS + (_CHUNK_COLOR_PROPS if any(p in ctypes for p in _CHUNK_COLOR_PROPS) else ())
    _require_properties(path, what, "chunk", ctypes, needed, ("f4", "f8"), "float")
    expect = -(-vertex[0] // CHUNK_SIZE)
    if chunk[0] != expect:
        raise SplatsError(path, f"{what}: {vertex[0]} Gaussians need {expect} chunks of {CHUNK_SIZE}, "
                                f"the header has {chunk[0]}", "chunk")
    if sh is not None:
        names = [p for p, _ in sh[1]]
        if len(names) not in (9, 24, 45) or names != [f"f_rest_{i}" for i in range(len(names))]:
            raise SplatsError(path, f"{what}: the 'sh' element must hold f_rest_0..f_rest_(9, 24 or 45 - 1), "
                                    f"it has {len(names)} properties", "sh")
        _require_properties(path, what, "sh", dict(sh[1]), names, ("u1",), "uchar")
        if sh[0] != vertex[0]:
            raise SplatsError(path, f"{what}: the 'sh' element has {sh[0]} rows for {vertex[0]} Gaussians", "sh")


def _unorm(packed: np.ndarray, shift: int, bits: int) -> np.ndarray:
    """The ``bits``-bit field at ``shift`` as k / (2^bits - 1) in [0, 1] (float64)."""
    top = (1 << bits) - 1
    return ((packed >> np.uint32(shift)) & np.uint32(top)).astype(np.float64) / top


#: For the index of the largest quaternion component, the indices of the other three in storage order.
_SMALLEST_THREE = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


def decode_packed_rotation(packed) -> np.ndarray:
    """(N, 4) quaternions (rot_0..rot_3 = w, x, y, z) from SuperSplat's 2-10-10-10 "smallest three" words."""
    packed = np.asarray(packed, np.uint32)
    small = np.stack([(_unorm(packed, s, 10) - 0.5) * np.sqrt(2.0) for s in (20, 10, 0)], axis=1)
    largest = (packed >> np.uint32(30)).astype(np.intp)
    q = np.empty((len(packed), 4), np.float64)
    rows = np.arange(len(packed))[:, None]
    q[rows, _SMALLEST_THREE[largest]] = small
    q[rows[:, 0], largest] = np.sqrt(np.maximum(0.0, 1.0 - (small * small).sum(axis=1)))
    return q


def _from_compressed(arrays, path) -> GaussianPly:
    chunk, vert = arrays["chunk"], arrays["vertex"]
    M = len(vert)
    ci = np.arange(M) // CHUNK_SIZE

    def ch(name):
        return np.asarray(chunk[name], np.float64)[ci]

    def lerp(lo, hi, t):  # as the readers do it: lo (1 - t) + hi t
        return ch(lo) * (1.0 - t) + ch(hi) * t

    def words(name):  # int32 words are read as their bits
        w = np.asarray(vert[name])
        return w.astype("=i4").view(np.uint32) if w.dtype.kind == "i" else w.astype(np.uint32)

    pos, scl, col = words("packed_position"), words("packed_scale"), words("packed_color")
    with np.errstate(invalid="ignore", over="ignore"):  # NaN/inf chunk values make NaN rows, dropped on decoding
        xyz = np.stack([lerp("min_x", "max_x", _unorm(pos, 21, 11)), lerp("min_y", "max_y", _unorm(pos, 11, 10)),
                        lerp("min_z", "max_z", _unorm(pos, 0, 11))], axis=1)
        scale = np.stack([lerp("min_scale_x", "max_scale_x", _unorm(scl, 21, 11)),
                          lerp("min_scale_y", "max_scale_y", _unorm(scl, 11, 10)),
                          lerp("min_scale_z", "max_scale_z", _unorm(scl, 0, 11))], axis=1)
        rgb = np.stack([_unorm(col, 24, 8), _unorm(col, 16, 8), _unorm(col, 8, 8)], axis=1)
        if "min_r" in chunk.dtype.names:
            rgb = np.stack([lerp(f"min_{c}", f"max_{c}", rgb[:, i]) for i, c in enumerate("rgb")], axis=1)
        alpha = _unorm(col, 0, 8)
        inner = np.clip(alpha, 1e-300, 1 - 1e-16)
        opacity = np.where(alpha <= 0, -_COMPRESSED_LOGIT_LIMIT,
                           np.where(alpha >= 1, _COMPRESSED_LOGIT_LIMIT, np.log(inner / (1.0 - inner))))
    f_rest = np.zeros((M, 3, 0), np.float32)
    if "sh" in arrays:
        sh = arrays["sh"]
        raw = np.stack([np.asarray(sh[f"f_rest_{i}"]) for i in range(len(sh.dtype.names))], axis=1)
        vals = ((raw.astype(np.float64) + 0.5) / 256.0 - 0.5) * 8.0
        vals[raw == 0], vals[raw == 255] = -4.0, 4.0
        f_rest = vals.astype(np.float32).reshape(M, 3, -1)
    with np.errstate(invalid="ignore", over="ignore"):  # beyond float32's range becomes inf: dropped on decoding
        return GaussianPly(xyz=xyz.astype(np.float32), f_dc=((rgb - 0.5) / SH_C0).astype(np.float32),
                           f_rest=f_rest, opacity=opacity.astype(np.float32), scale=scale.astype(np.float32),
                           rot=decode_packed_rotation(words("packed_rotation")).astype(np.float32),
                           format="supersplat_compressed")


# -- antimatter15 .splat -------------------------------------------------------------------------------------------

def read_splat(path) -> GaussianPly:
    """Read an antimatter15 ``.splat`` file (module docstring) as raw INRIA values; SplatsError if unusable."""
    path = os.fspath(path)
    try:
        with _open(path) as f:
            size = os.fstat(f.fileno()).st_size
            if size == 0:
                raise SplatsError(path, "the .splat file is empty (0 bytes)")
            if size % SPLAT_RECORD.itemsize:
                raise SplatsError(path, f"a .splat file holds {SPLAT_RECORD.itemsize} bytes per Gaussian, but this "
                                        f"one has {size} bytes, not a multiple of {SPLAT_RECORD.itemsize} ({size % 32} "
                                        "left over): truncated, or not a .splat file")
            buf = f.read(size)
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None
    if len(buf) != size:  # the file changed while being read
        raise SplatsError(path, f"only {len(buf)} of its {size} bytes could be read: the file changed while being read")
    data = np.frombuffer(buf, dtype=SPLAT_RECORD)
    rgba = data["rgba"].astype(np.float64) / 255.0
    alpha = np.clip(rgba[:, 3], _SPLAT_ALPHA_EPS, 1.0 - _SPLAT_ALPHA_EPS)
    with np.errstate(divide="ignore", invalid="ignore"):  # σ <= 0 gives -inf/NaN: dropped on decoding
        log_scale = np.log(data["scale"].astype(np.float64))
    return GaussianPly(xyz=data["xyz"].astype(np.float32), f_dc=((rgba[:, :3] - 0.5) / SH_C0).astype(np.float32),
                       f_rest=np.zeros((len(data), 3, 0), np.float32),
                       opacity=np.log(alpha / (1.0 - alpha)).astype(np.float32), scale=log_scale.astype(np.float32),
                       rot=((data["rot"].astype(np.float64) - 128.0) / 128.0).astype(np.float32), format="splat")


# -- TRELLIS / Amodal3R ------------------------------------------------------------------------------------------

def _layout(ply: GaussianPly) -> tuple:
    """The vertex properties of ``ply``'s file, or for an in-memory one those ``write_ply`` would write."""
    if ply.properties:
        return tuple(ply.properties)
    normals = [n for n in ("nx", "ny", "nz") if n in ply.extra]
    K1 = ply.f_rest.shape[2]
    return tuple(["x", "y", "z"] + normals + [f"f_dc_{i}" for i in range(3)]
                 + [f"f_rest_{i}" for i in range(3 * K1)] + ["opacity"] + [f"scale_{i}" for i in range(3)]
                 + [f"rot_{i}" for i in range(4)] + [n for n in ply.extra if n not in normals])


def detect_axes(ply: GaussianPly, keep=None) -> tuple[str, str]:
    """("TRELLIS" or "NONE", one sentence why) for the import report.

    TRELLIS/Amodal3R files are recognised by their exact layout (``TRELLIS_PROPERTIES`` in that order, all normals
    zero, SH degree 0, float PLY) and all kept means within ``TRELLIS_MEAN_BOUND`` (see there); ``keep`` is the
    mask of rows to use (default: the rows ``decode`` keeps).
    """
    if ply.format != "inria":
        return "NONE", f"not TRELLIS: its layout is {FORMAT_NAMES.get(ply.format, ply.format)}"
    if ply.sh_degree:
        return "NONE", f"not TRELLIS: has f_rest (SH {ply.sh_degree})"
    if not {"nx", "ny", "nz"} <= set(ply.extra):
        return "NONE", "not TRELLIS: no normals (TRELLIS writes zero nx ny nz)"
    layout = _layout(ply)
    if layout != TRELLIS_PROPERTIES:
        others = [n for n in layout if n not in TRELLIS_PROPERTIES]
        if others:
            return "NONE", f"not TRELLIS: extra properties {others}"
        return "NONE", "not TRELLIS: the properties are not in TRELLIS's save_ply order"
    if any(np.any(np.asarray(ply.extra[n]) != 0) for n in ("nx", "ny", "nz")):
        return "NONE", "not TRELLIS: normals are not all zero"
    keep = valid_rows(ply)[0] if keep is None else np.asarray(keep, bool)
    if not keep.any():
        return "NONE", "not TRELLIS: no valid Gaussians"
    reach = float(np.abs(ply.xyz[keep].astype(np.float64)).max())
    if reach > TRELLIS_MEAN_BOUND:
        return "NONE", (f"not TRELLIS: means reach {reach:.4g}, outside the unit cube (TRELLIS stays within "
                        f"±{TRELLIS_MEAN_BOUND:.4f})")
    return "TRELLIS", (f"TRELLIS/Amodal3R layout ({len(TRELLIS_PROPERTIES)} properties, zero normals, SH 0) and all "
                       f"means within ±{TRELLIS_MEAN_BOUND:.4f} (the decoder's unit cube)")


# --------------------------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------------------------

def write_ply(path, ply: GaussianPly, byte_order: str = "<", comment: str | None = None) -> None:
    """Write ``ply`` in the INRIA layout (float32; extras in their own types), atomically (temp file, rename).

    Property order: x y z, normals if present among the extras, f_dc, f_rest, opacity, scale, rot, other extras.
    """
    if byte_order not in "<>":
        raise ValueError("byte_order must be '<' or '>'")
    N = len(ply)
    K1 = ply.f_rest.shape[2]
    normals = [n for n in ("nx", "ny", "nz") if n in ply.extra]
    others = [n for n in ply.extra if n not in normals]
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4")] + [(n, ply.extra[n].dtype.str[1:]) for n in normals]
    fields += [(f"f_dc_{i}", "f4") for i in range(3)] + [(f"f_rest_{i}", "f4") for i in range(3 * K1)]
    fields += [("opacity", "f4")] + [(f"scale_{i}", "f4") for i in range(3)] + [(f"rot_{i}", "f4") for i in range(4)]
    fields += [(n, ply.extra[n].dtype.str[1:]) for n in others]
    arr = np.empty(N, dtype=[(n, byte_order + t) for n, t in fields])
    for i, k in enumerate("xyz"):
        arr[k] = ply.xyz[:, i]
    for i in range(3):
        arr[f"f_dc_{i}"] = ply.f_dc[:, i]
        arr[f"scale_{i}"] = ply.scale[:, i]
    flat_rest = ply.f_rest.reshape(N, 3 * K1)
    for i in range(3 * K1):
        arr[f"f_rest_{i}"] = flat_rest[:, i]
    arr["opacity"] = ply.opacity
    for i in range(4):
        arr[f"rot_{i}"] = ply.rot[:, i]
    for n in normals + others:
        arr[n] = ply.extra[n]
    names = {v: k for k, v in _TYPES.items() if k in ("char", "uchar", "short", "ushort", "int", "uint", "float",
                                                         "double")}
    header = ["ply", f"format binary_{'little' if byte_order == '<' else 'big'}_endian 1.0"]
    if comment:  # one line of printable ASCII: a newline in it would write header lines of its own
        header.append("comment " + "".join(ch if " " <= ch <= "~" else "?" for ch in comment))
    header.append(f"element vertex {N}")
    header += [f"property {names[t]} {n}" for n, t in fields]
    header.append("end_header")
    with files.atomic_write(os.fspath(path)) as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(arr.tobytes())


def write_splat(path, g) -> None:
    """Write decoded ``Gaussians`` (or a raw ``GaussianPly``, decoded first) as an antimatter15 ``.splat``, atomically.

    Bytes as antimatter15/splat ``convert.py`` makes them, except that colour, alpha and quaternion bytes are rounded
    to the nearest value instead of truncated (readers decode both the same way); SH beyond degree 0 is dropped.
    """
    if isinstance(g, GaussianPly):
        g = decode(g)
    N = len(g)
    rec = np.zeros(N, SPLAT_RECORD)
    rec["xyz"] = g.means
    rec["scale"] = g.scales
    rgba = np.concatenate([0.5 + SH_C0 * g.sh[:, 0].astype(np.float64), g.opacities.astype(np.float64)[:, None]], 1)
    rec["rgba"] = np.clip(np.rint(rgba * 255.0), 0, 255).astype(np.uint8)
    q = g.quats.astype(np.float64)
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-30)
    rec["rot"] = np.clip(np.rint(q * 128.0 + 128.0), 0, 255).astype(np.uint8)
    with files.atomic_write(os.fspath(path)) as f:
        f.write(rec.tobytes())

# --------------------------------------------------------------------------------------------------------------
# Decoding and encoding
# --------------------------------------------------------------------------------------------------------------

def decode(ply: GaussianPly) -> Gaussians:
    """Activate raw values: exp scales, sigmoid opacity, normalised quaternions; drop and count bad rows.

    A row is dropped for any NaN/inf among its used values ("non_finite"), a quaternion shorter than 1e-12
    ("zero_quaternion"), or a scale whose exp overflows float32 ("scale_overflow").
    """
    with np.errstate(invalid="ignore", over="ignore"):  # bad rows are expected here: they are counted below
        return _decode(ply)


def valid_rows(ply: GaussianPly):
    """(keep mask (N,), dropped counts by reason) — the rows decode() keeps."""
    with np.errstate(invalid="ignore", over="ignore"):
        finite = (np.isfinite(ply.xyz).all(1) & np.isfinite(ply.f_dc).all(1)
                  & np.isfinite(ply.f_rest).all((1, 2)) & np.isfinite(ply.opacity)
                  & np.isfinite(ply.scale).all(1) & np.isfinite(ply.rot).all(1))
        zero_q = finite & (np.linalg.norm(ply.rot.astype(np.float64), axis=1) < 1e-12)
        overflow = finite & ~zero_q & ~(np.exp(ply.scale.astype(np.float64)) <= np.finfo(np.float32).max).all(1)
    dropped = {"non_finite": int(len(ply) - finite.sum()), "zero_quaternion": int(zero_q.sum()),
               "scale_overflow": int(overflow.sum())}
    return finite & ~zero_q & ~overflow, {k: v for k, v in dropped.items() if v}


def _decode(ply: GaussianPly) -> Gaussians:
    keep, dropped = valid_rows(ply)
    rot = ply.rot[keep].astype(np.float64)
    q = rot / np.linalg.norm(rot, axis=1, keepdims=True)
    opac = 1.0 / (1.0 + np.exp(-ply.opacity[keep].astype(np.float64)))
    sh = np.concatenate([ply.f_dc[keep][:, None, :], np.swapaxes(ply.f_rest[keep], 1, 2)], axis=1)  # (N, K, 3)
    return Gaussians(means=ply.xyz[keep].copy(), scales=np.exp(ply.scale[keep].astype(np.float64)).astype(np.float32),
                     quats=q.astype(np.float32), opacities=opac.astype(np.float32), sh=sh.astype(np.float32),
                     dropped=dropped)


def encode(g: Gaussians, extra: dict | None = None) -> GaussianPly:
    """Raw file values of decoded Gaussians: log scales, logit opacity (clamped to (1e-7, 1 - 1e-7))."""
    o = np.clip(g.opacities.astype(np.float64), 1e-7, 1 - 1e-7)
    return GaussianPly(xyz=g.means.astype(np.float32), f_dc=g.sh[:, 0].astype(np.float32),
                       f_rest=np.swapaxes(g.sh[:, 1:], 1, 2).astype(np.float32),
                       opacity=np.log(o / (1 - o)).astype(np.float32),
                       scale=np.log(np.maximum(g.scales.astype(np.float64), 1e-30)).astype(np.float32),
                       rot=g.quats.astype(np.float32), extra=dict(extra or {}))


# --------------------------------------------------------------------------------------------------------------
# Spherical harmonics
# --------------------------------------------------------------------------------------------------------------

def sh_basis(dirs, degree: int) -> np.ndarray:
    """Real SH basis values (N, (degree+1)^2) at unit directions (N, 3), in the 3DGS ordering and signs."""
    d = np.asarray(dirs, np.float64)
    terms = _sh.basis(d[:, 0], d[:, 1], d[:, 2], degree)  # core.sh: the one formula (the renderer's too)
    return np.stack([np.broadcast_to(np.asarray(t, np.float64), (len(d),)) for t in terms], axis=1)


def sh_to_rgb(sh, dirs, degree: int | None = None) -> np.ndarray:
    """Colour (N, 3) = max(0.5 + Σ_k basis_k(dir) sh_k, 0) for unit view directions (N, 3).

    ``dirs`` point from the camera to the Gaussian (normalise(mean - camera centre)), in the Gaussians' frame.
    ``degree`` below the data's own uses only the first coefficients.
    """
    sh = np.asarray(sh)
    degree = int(round(np.sqrt(sh.shape[1]))) - 1 if degree is None else degree
    K = num_sh_coefficients(degree)
    if K > sh.shape[1]:
        raise ValueError(f"SH degree {degree} needs {K} coefficients, the data has {sh.shape[1]}")
    B = sh_basis(dirs, degree)
    return np.maximum(np.einsum("nk,nkc->nc", B, sh[:, :K].astype(np.float64)) + 0.5, 0.0)
