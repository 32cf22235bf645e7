"""Gaussian files, one entry point: ``read(path)`` picks the reader by content (``detect``), the extension
deciding only for headerless ``.splat``; ``load(path) = decode(read(path))``; mesh files are told apart from
Gaussian ones (``is_mesh``: ``MESH_EXTENSIONS``, a mesh PLY, a glTF without ``KHR_gaussian_splatting``) and refused
with a message that says where they go.

``detect`` looks at the bytes first, so a file named for another format is read as what it is (a ``.ksplat`` or
an SPZ saved as ``.splat`` included): ``ply`` (starts with "ply"), ``spz`` (gzip whose stream starts with SPZ's
"NGSP", or a plain "NGSP" version-4 header), ``gltf_splats`` (a GLB, or a ``.gltf``'s JSON, with
``KHR_gaussian_splatting``), ``sog`` (a zip holding ``meta.json``, or a SOG ``meta.json`` itself), ``ksplat`` (a
consistent GaussianSplats3D header: ``ksplat.looks_like_ksplat``) and, by extension only, ``splat`` (the records'
``by_extension``). ``READERS`` maps each name to its reader.

The formats, their extensions and readers are the records of ``core.splats.formats`` (every reader returns a
``core.splats.gaussians.GaussianPly`` of raw INRIA values; the PLY ones sit on ``core.splats.ply_format``, the PLY
header and elements). Only regular files are opened (a FIFO or a directory is refused at once, not waited
on). Unusable files raise ``core.splats.gaussians.SplatsError`` naming the file and what is wrong.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import importlib
import json
import os
import zipfile

from .. import glb
from . import compressed, formats, gltf_splats, inria, ksplat, ply_format, spz
from .gaussians import ACCEPTED, GaussianPly, Gaussians, SplatsError, decode, open_file, read_bytes

#: Mesh files: not splats, but what the car-asset import converts to Gaussians (backend ``mesh-asset``, trimesh);
#: a ``.ply`` is a mesh when ``is_mesh_ply`` says so, a ``.glb``/``.gltf`` when it has no
#: ``KHR_gaussian_splatting`` primitive (``is_mesh`` decides both by content).
MESH_EXTENSIONS = (".glb", ".gltf", ".obj", ".stl", ".off")
#: The file extensions each Gaussian format (a key of ``READERS``) is saved under (``formats.FORMATS``' records):
#: what the file browsers filter on and what the README's format table names (tests/test_docs.py). ``detect``
#: decides by content, by these names only for headerless ``.splat``; a SOG may also be an unbundled ``meta.json``
#: (``sog.META_NAME``).
FORMAT_EXTENSIONS = {f.key: f.extensions for f in formats.FORMATS}
#: Gaussian-only file extensions (``.ply``, ``.glb`` and ``.gltf`` may be either, by content).
SPLAT_EXTENSIONS = tuple(e for exts in FORMAT_EXTENSIONS.values() for e in exts if e not in MESH_EXTENSIONS)
#: Every file a car asset may be: Gaussian files and meshes (what the import's file browser and a variation
#: library take).
ASSET_EXTENSIONS = SPLAT_EXTENSIONS + MESH_EXTENSIONS
#: Bytes ``detect`` reads first: enough for every magic and for the start of a gzip stream.
_HEAD = ksplat.MAIN_HEADER
ZIP_MAGIC = b"PK\x03\x04"


def read(path: str | os.PathLike) -> GaussianPly:
    """Read any accepted Gaussian file (module docstring) into raw float32 arrays; SplatsError if unusable.

    The format is decided by content (``detect``); headerless ``.splat`` files by their extension. Only regular
    files are opened (a FIFO or a directory is refused at once, not waited on).
    """
    path = os.fspath(path)
    return READERS[detect(path)](path)


def load(path: str | os.PathLike) -> Gaussians:
    """read + decode: decoded Gaussians of any accepted file."""
    return decode(read(path))


def detect(path: str | os.PathLike) -> str:
    """The Gaussian format of a file by its content (a key of ``READERS``); SplatsError naming the file when it is
    none (a mesh, another format, damaged): see the module docstring for the order of the checks."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    try:
        with open_file(path) as f:
            size = os.fstat(f.fileno()).st_size
            if size == 0:  # every format has a header or at least one record
                raise SplatsError(path, "the file is empty (0 bytes): saved or copied incompletely? Export or copy "
                                        "it again")
            head = f.read(_HEAD)
            if head.startswith(b"ply"):
                return "ply"
            if spz.is_spz(head):
                return "spz"
            if head.startswith(glb.MAGIC) or (head.lstrip()[:1] == b"{"):
                return _json_kind(path, head, ext)
            if head.startswith(ZIP_MAGIC):
                return _zip_kind(path, f, ext)
            if len(head) == ksplat.MAIN_HEADER and head[0] == 0 and head[1] >= 1:  # GaussianSplats3D 0.1+
                more = ksplat.MAIN_HEADER + ksplat.SECTION_HEADER * min(int.from_bytes(head[4:8], "little"),
                                                                         ksplat.MAX_SECTIONS)
                full = head + f.read(max(0, min(more, size) - len(head)))
                problem = ksplat.header_problem(full, size)
                if problem is None:
                    return "ksplat"
                if ext == ".ksplat":
                    raise SplatsError(path, f"not a GaussianSplats3D .ksplat file: {problem}", "header")
            if ext == ".ksplat" and len(head) < ksplat.MAIN_HEADER:   # cut short: say so, not "another format"
                raise SplatsError(path, f"not a GaussianSplats3D .ksplat file: {ksplat.header_problem(head, size)}: "
                                        "truncated?", "header")
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None
    if ext == ".spz" and head.startswith(spz.GZIP_MAGIC):
        raise SplatsError(path, "a gzip stream that does not inflate to an SPZ header ('NGSP'): truncated or "
                                "damaged SPZ file, or another gzip file renamed", "header")
    for fmt in formats.FORMATS:
        if fmt.by_extension and ext in fmt.extensions:
            return fmt.key
    raise SplatsError(path, _not_accepted(head, ext))


def _json_kind(path, head: bytes, ext: str) -> str:
    """A GLB or JSON file: ``sog`` (a SOG meta.json), ``gltf_splats``; a mesh glTF or other JSON is refused. A SOG
    meta.json is tried first: it is a JSON object too, which a glTF reader would take for a glTF without meshes."""
    data = None  # a GLB: peek_tree reads its JSON chunk alone; a JSON file: read once, for both questions
    if not head.startswith(glb.MAGIC):
        data = read_bytes(path)
        try:
            meta = json.loads(data.decode("utf-8-sig"))
        except (UnicodeDecodeError, ValueError, RecursionError):
            meta = None
        if is_sog_meta(meta):
            return "sog"
    try:
        tree = gltf_splats.peek_tree(path) if data is None else gltf_splats.read_tree(path, data)[0]
    except SplatsError as e:
        if head.startswith(glb.MAGIC) or ext in (".gltf", ".glb"):
            # a damaged glTF is neither a mesh nor splats yet: its own problem first
            reason = e.args[0].split(": ", 1)[-1].removesuffix(f" ({e.path})")
            raise SplatsError(path, f"its glTF cannot be read ({reason}): a damaged or truncated file, export it "
                                    f"again (a mesh car, or Gaussian splats with {gltf_splats.EXTENSION})",
                              e.field) from None
        raise SplatsError(path, f"a JSON file that is neither a glTF nor a SOG meta.json ({e.args[0]}): accepted "
                                f"are {ACCEPTED}") from None
    if gltf_splats.has_gaussian_splatting(tree):
        return "gltf_splats"
    raise SplatsError(path, _not_accepted(head, ext or ".gltf"))


def is_sog_meta(meta: object) -> bool:
    """True for a parsed SOG ``meta.json`` (PlayCanvas: an object with ``means`` and ``quats``/``scales``)."""
    return isinstance(meta, dict) and "means" in meta and ("quats" in meta or "scales" in meta)


def _zip_kind(path, f, ext: str) -> str:
    """A zip: ``sog`` when it holds ``meta.json``; other zips are refused."""
    try:
        f.seek(0)
        names = zipfile.ZipFile(f).namelist()
    except (zipfile.BadZipFile, OSError, ValueError) as e:
        raise SplatsError(path, f"a damaged zip file ({e}): if it is a SOG bundle, export it again") from None
    if "meta.json" in names:
        return "sog"
    raise SplatsError(path, f"a zip without meta.json (it holds {names[:5]}): not a SOG bundle; accepted are "
                            f"{ACCEPTED}")


def is_mesh(path: str | os.PathLike) -> bool:
    """True for a car file the import converts as a mesh: ``.obj``/``.stl``/``.off``, a mesh PLY (``is_mesh_ply``),
    or a ``.glb``/``.gltf`` without ``KHR_gaussian_splatting`` (an unreadable one too: the mesh converter then says
    what is wrong). Never raises."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".ply":
        return is_mesh_ply(path)
    if ext not in MESH_EXTENSIONS:
        return False
    if ext not in (".glb", ".gltf"):
        return True
    try:
        tree = gltf_splats.peek_tree(path)
    except (SplatsError, OSError):
        return True
    return not gltf_splats.has_gaussian_splatting(tree)


def _not_accepted(head: bytes, ext: str) -> str:
    """Why a file of no accepted format is refused, and what to do, from its first bytes and extension."""
    if head.startswith(glb.MAGIC) or ext in MESH_EXTENSIONS:
        return (f"a mesh ({ext or 'glTF'}), not Gaussian splats (no {gltf_splats.EXTENSION}): the car-asset import "
                f"and `python -m backend mesh-asset` turn meshes into Gaussians; Gaussian files accepted are "
                f"{ACCEPTED}")
    if ext in (".fbx", ".blend", ".usd", ".usdz", ".usdc", ".dae", ".3ds"):
        return (f"{ext} files are not read: export the car as GLB, glTF, OBJ, STL or PLY (mesh), or as Gaussian "
                f"splats ({ACCEPTED})")
    if ext in _NAMED_BY_CONTENT:
        return (f"named {ext} but its content is not that format (it starts with {head[:8]!r}): damaged, or "
                f"another file renamed; accepted are {ACCEPTED}")
    return (f"not a PLY file (it does not start with 'ply'), nor another Gaussian format by its content, and not "
            f"named .splat: accepted are {ACCEPTED}")


#: Extensions of formats told by content alone (a file so named that is not that format is refused saying so):
#: those of the records, but PLY's (a ``.ply`` that is not one has ``_not_accepted``'s last message) and the mesh
#: ones (their own message), and those read by name; with ``.sogs`` (SOG version 1) and ``.lcc`` (XGrids), splat
#: formats not read.
_NAMED_BY_CONTENT = tuple(e for f in formats.FORMATS if f.key != "ply" and not f.by_extension
                          for e in f.extensions if e not in MESH_EXTENSIONS) + (".sogs", ".lcc")


#: Vertex properties only Gaussian PLYs have: a PLY with none of them is a mesh or a point cloud.
_GAUSSIAN_HINTS = ("f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1",
                   "rot_2", "rot_3") + compressed.PACKED_PROPS


def _mesh_message(elements):
    """A message when the PLY looks like a mesh or point cloud (no Gaussian property at all), else None."""
    vertex = ply_format.element(elements, "vertex")
    if vertex is None:
        return None
    names = [p for p, _ in vertex[1]]
    if not names or set(names) & set(_GAUSSIAN_HINTS) or ply_format.element(elements, "chunk") is not None:
        return None
    face = ply_format.element(elements, "face")
    what = f"{vertex[0]} vertices ({' '.join(names[:8])}{' ...' if len(names) > 8 else ''})"
    what += f" and {face[0]} faces" if face is not None else ""
    return (f"looks like a mesh without Gaussian properties: it has {what} but none of f_dc_*, opacity, scale_*, "
            "rot_*: import it as a mesh asset (.glb/.obj/.ply mesh)")


def is_mesh_ply(path: str | os.PathLike) -> bool:
    """True for a readable PLY (binary or ASCII) whose header has faces and no Gaussian property (a mesh to
    convert); never raises."""
    try:
        _, elements, _ = ply_format.read_ply_header(path)
    except (OSError, SplatsError):
        return False
    face = ply_format.element(elements, "face")
    return face is not None and face[0] > 0 and _mesh_message(elements) is not None


def read_ply(path: str | os.PathLike) -> GaussianPly:
    """Read a Gaussian-splat PLY (INRIA, TRELLIS/Amodal3R, half-float or SuperSplat compressed) into raw float32
    arrays; SplatsError if unusable."""
    path = os.fspath(path)
    try:
        with open_file(path) as f:
            size = os.fstat(f.fileno()).st_size
            head = f.read(ply_format.MAX_HEADER)
            fmt, elements, start = ply_format.parse_header(head, path, binary_only=False)
            mesh = _mesh_message(elements)
            if mesh:
                raise SplatsError(path, mesh)
            ply_format.check_binary(fmt, path)
            order = "<" if fmt == "binary_little_endian" else ">"
            vertex = ply_format.element(elements, "vertex")
            if vertex is None:
                raise SplatsError(path, "no 'vertex' element", "vertex")
            vnames = [p for p, _ in vertex[1]]
            if ply_format.element(elements, "chunk") is not None or "packed_position" in vnames:
                compressed.check_header(elements, path)
                wanted = ("chunk", "vertex") + (("sh",) if ply_format.element(elements, "sh") is not None else ())
                arrays = ply_format.read_elements(f, path, size, order, elements, start, wanted)
                return compressed.from_elements(arrays, path)
            data = ply_format.read_elements(f, path, size, order, elements, start, ("vertex",))["vertex"]
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None
    return inria.from_vertex(data, vnames, path)


def _reader(name: str):
    """A record's ``read``: ``"module.function"`` in ``core.splats`` (``reader.read_ply``, this module's own, is
    defined above, so the half-imported module already has it)."""
    module, function = name.rsplit(".", 1)
    return getattr(importlib.import_module(f"{__package__}.{module}"), function)


#: The reader of each format ``detect`` names (``formats.FORMATS``' ``read``).
READERS = {f.key: _reader(f.read) for f in formats.FORMATS}
