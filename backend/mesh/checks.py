"""Mesh files checked before trimesh reads them (issue 30): every count a file declares is bounded by the bytes
the file (and the files it names) hold, every texture's pixel count by its image header, and every file a mesh names
is opened exactly as named, inside the mesh's folder, as a regular file. trimesh allocates what a header claims and
decodes every texture it finds (``scene.dump`` copies them), so these run first; what trimesh still dislikes it
raises, and ``load.load_mesh`` turns that into a ``MeshAssetError``.

The bounds, in one place:

* ``MAX_TEXTURE_PIXELS`` (8192², 64 Mpx): a texture's width × height from its header; a larger one is refused
  before anything decodes it (decoded as 8-bit RGB it is 192 MB; the sampler never copies it to float).
* ``MAX_TOTAL_TEXTURE_PIXELS`` (2 × 8192²): the pixels of all the textures a mesh names together (glTF: every image;
  OBJ: every ``map_Kd``), from their headers, before anything decodes them (each is held decoded while sampling).
* ``MIN_EXTENT``, ``MAX_EXTENT`` (1e-6, 1e6 in the mesh's units): the largest side of the box around the car's
  vertices (node transforms applied) and every coordinate's magnitude (``check_extent``). Beyond them the car does
  not survive float32 (1e39 is inf) or is no car in any unit (mm to km): a glTF node's scale is the usual cause.
* ``ZERO_ACCESSOR_ELEMENTS_PER_BYTE`` (1): a glTF accessor without a ``bufferView`` (zeros, sparse values or an
  extension's output such as Draco) may declare at most one element per byte of the mesh file and its buffers; one
  with a ``bufferView`` must fit in it (its last element ends within the view: offset + stride × (count − 1) +
  element size ≤ byteLength), as every ``bufferView`` in its buffer and every buffer's ``byteLength`` in the bytes
  it has; every attribute of a primitive has as many elements as its POSITION.
* OFF: the header's vertex and face counts must have as many lines after it. PLY: ``load._check_ply``.
* OBJ: no face index of 0 (indices count from 1; negative ones are relative); its MTL (``mtllib``) defines a
  material and every ``map_Kd`` names a file (trimesh drops an MTL it reads nothing from, and a ``map_Kd`` without
  a value, without a word). A ``map_Kd`` value is options, then the file name (the MTL specification's options:
  ``MTL_TEXTURE_OPTIONS``; ``mtl_texture`` parses them and ``load``'s resolver opens the name it finds, as trimesh
  5.2 passes the whole value). ``-clamp on`` is applied (CLAMP_TO_EDGE both ways, ``MtlMap.clamp``); the other
  options that change the colours read (``-o``, ``-s``, ``-t``, ``-mm``, ``-cc on``) are not: a ``warning``.
* A backslash in a name a mesh gives is a path separator (Windows-made files: ``textures\\tex.png``).

glTF / GLB (the glTF 2.0 specification): a GLB (its container read by ``core.glb``) holds a JSON chunk and an
optional BIN chunk (buffer 0 without a ``uri``). URIs are percent-decoded (RFC 3986, as the specification says),
``data:`` URIs base64-decoded; a ``file:`` URI is refused (an absolute path); any other URI names a file relative
to the mesh's folder. ``extensionsRequired`` is
checked first (``gltf.check_required``: a meshopt file's fallback buffer has no bytes of its own). ``image/ktx2`` textures are
refused (trimesh skips them: the car would lose its colours without a word).

No bpy, no torch. Longer than most modules because every format's pre-read checks and their bounds belong
together: one place says what a mesh file may claim before any reader allocates for it.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import re
import struct
import warnings
from typing import NamedTuple, TYPE_CHECKING
from urllib.parse import unquote

from scpainter_blender.core import files, glb

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator, Sequence
    from typing import BinaryIO
    import numpy as np

MAX_TEXTURE_PIXELS = 8192 * 8192
MAX_TOTAL_TEXTURE_PIXELS = 2 * MAX_TEXTURE_PIXELS
MIN_EXTENT, MAX_EXTENT = 1e-6, 1e6
ZERO_ACCESSOR_ELEMENTS_PER_BYTE = 1

#: glTF componentType -> bytes (5124, int32, is not glTF 2.0 but trimesh reads it)
COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5124: 4, 5125: 4, 5126: 4}
#: glTF accessor type -> components
TYPE_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: File extensions read as images when a mesh names them (OBJ ``map_Kd``, a PLY's ``TextureFile``).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tga", ".tif", ".tiff", ".webp", ".gif", ".ppm", ".pgm")


def _pixels(n: int) -> str:
    return f"{n:,} pixels"


@contextlib.contextmanager
def pixel_limit(limit: int | None) -> Iterator[None]:
    """PIL's own decompression-bomb limit set to ``limit`` pixels (None: off) for the block, its warning an error:
    ``Image.open`` then refuses more than ``limit`` pixels before decoding (the check reads the header only)."""
    from PIL import Image

    old = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = limit
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            yield
    finally:
        Image.MAX_IMAGE_PIXELS = old


def check_image(stream: BinaryIO, error: Callable[..., Exception], name: str) -> tuple:
    """(width, height) of the image in ``stream`` (a binary file object), read from its header only; ``error(field,
    message, hint)`` (the caller's MeshAssetError) when it is not an image PIL reads or has more than
    ``MAX_TEXTURE_PIXELS``. ``name``: the texture as the mesh names it (the error's field)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with pixel_limit(None):
            with Image.open(stream) as img:
                w, h = img.size
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError, struct.error) as e:
        why = "not an image format PIL reads" if isinstance(e, UnidentifiedImageError) else f"{type(e).__name__}: {e}"
        raise error(name, f"texture {name!r} cannot be read as an image ({why})",
                    "fix or replace the texture file (PNG or JPEG), or fix the name the mesh gives it") from None
    if w * h > MAX_TEXTURE_PIXELS:
        raise error(name, f"texture {name!r} is {w} × {h} = {_pixels(w * h)}, more than the "
                          f"{_pixels(MAX_TEXTURE_PIXELS)} (8192 × 8192) read here",
                    "scale the texture down (8192 × 8192 at most)")
    return w, h


def named_file(mesh_path: str | os.PathLike, name: str, error: Callable[..., Exception], gltf: bool) -> str:
    """The absolute path of the file ``name`` (as the mesh names it: a glTF URI percent-decoded) relative to the
    mesh's folder, exactly: no other file of the same base name, nothing outside the folder (symbolic links
    resolved). ``error(field, message, hint)`` when it leads outside or does not exist; the caller opens it with
    ``files.open_regular`` (a FIFO or folder is refused there)."""
    from pathlib import Path

    if gltf and name.strip().lower().startswith("file:"):  # RFC 8089: an absolute path, maybe on another machine
        raise error(name, f"{name!r} (named by the mesh) is a file:// URI, which is not read here: only paths "
                          "relative to the mesh, within its folder", "copy the file next to the mesh (or into a "
                                                                     "folder below it) and name it relative to the "
                                                                     "mesh (e.g. 'textures/paint.png')")
    target = (unquote(name) if gltf else name).replace("\\", "/")   # Windows-made: textures\\tex.png
    folder = Path(os.path.dirname(os.path.abspath(mesh_path))).resolve()
    if not target.strip():
        raise error(name, "names a file with an empty name", "fix the file name in the mesh")
    try:
        where = (folder / target.strip()).resolve()
    except (OSError, RuntimeError, ValueError) as e:  # a link loop, a NUL in the name
        raise error(name, f"{name!r} (named by the mesh) cannot be resolved: {e}", "fix the file name in the mesh") \
            from None
    if not where.is_relative_to(folder):
        raise error(name, f"{name!r} (named by the mesh) lies outside the mesh's folder {str(folder)!r}",
                    "copy the file next to the mesh (or into a folder below it) and name it relative to the mesh")
    if not os.path.lexists(where):
        raise error(name, f"{name!r} (named by the mesh) not found in {str(folder)!r}",
                    "put the file there, or fix the name the mesh gives it")
    return str(where)


# ------------------------------------------------------------------------------------------------------- glTF

def _glb(path, data: bytes, error):
    """(JSON dict, BIN chunk length or None, BIN chunk's data offset or None) of a GLB container (``core.glb``), its
    lengths checked against the file's bytes: the header's length within the file, the JSON chunk first and within
    that length, a BIN chunk (trimesh's buffer 0) looked for right at the JSON chunk's end, where trimesh reads it."""
    container = glb.Glb(data)
    for problem in container.problems:  # in the header's order: magic or size, version, length
        if problem.code in (glb.NOT_GLB, glb.SHORT):
            raise error("(file)", "is not a GLB file (no 'glTF' header)", "export the car again as GLB")
        if problem.code == glb.BAD_VERSION:
            raise error("(file)", f"is GLB version {problem.claimed}; only glTF 2.0 is read",
                        "export the car again as glTF 2.0")
        if problem.code == glb.LENGTH_PAST_END:
            raise error("(file)", f"the GLB header promises {problem.claimed:,} bytes but the file has "
                                  f"{problem.bound:,}: truncated", "copy or export the file again")
    first = container.chunk_at(glb.HEADER_BYTES)  # read even where the header's length ends before it
    if first.kind != glb.JSON_CHUNK or container.problem(first) is not None:
        raise error("(file)", f"the GLB's first chunk is not a JSON chunk of {first.length:,} bytes within the file",
                    "export the car again as GLB")
    try:
        tree = json.loads(container.data_of(first).decode("utf-8"))
    except (ValueError, RecursionError) as e:
        raise error("(file)", f"the GLB's JSON chunk is not JSON ({type(e).__name__}: {e})",
                    "export the car again as GLB") from None
    after = container.next_chunk(first, aligned=False)  # trimesh reads on at the JSON's end, unpadded
    if after is None or after.kind != glb.BIN_CHUNK:
        return tree, None, None
    problem = container.problem(after)  # past the header's length (checked above to lie within the file)
    if problem is not None:
        raise error("(file)", f"the GLB's BIN chunk promises {after.length:,} bytes but only "
                              f"{container.length - after.data_at:,} follow: truncated",
                    "copy or export the file again")
    return tree, after.length, after.data_at


def _index(node, key, field, error, count=None, required=True, minimum=0):
    """An integer member of a glTF object (bools and floats refused), at least ``minimum`` and below ``count``."""
    if key not in node:
        if required:
            raise error(field, f"{field} is missing", "export the car again (the glTF is incomplete)")
        return None
    v = node[key]
    if isinstance(v, bool) or not isinstance(v, int) or v < minimum or (count is not None and v >= count):
        bound = f" and below {count}" if count is not None else ""
        raise error(f"{field}", f"{field} = {v!r} is not an integer of at least {minimum}{bound}",
                    "export the car again (the glTF is corrupt)")
    return v


def _list(tree, key, error):
    v = tree.get(key, [])
    if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
        raise error(key, f"{key} is not a list of objects", "export the car again (the glTF is corrupt)")
    return v


def check_gltf(path: str | os.PathLike, size: int, error: Callable[..., Exception],
               open_named: Callable[[str], BinaryIO]) -> dict:
    """Check a .gltf/.glb before trimesh reads it (see the module docstring): buffers, buffer views, accessors,
    images (each, and their total: ``check_total_pixels``). ``error(field, message, hint)`` makes the caller's error;
    ``open_named(name)`` opens a file the mesh names (``named_file`` + ``files.open_regular``, the caller's errors).
    Returns the glTF JSON (``check_extent`` reads its nodes)."""
    glb = path.lower().endswith(".glb")
    if glb:
        with files.open_regular(path, lambda p, f, m: error("(file)", m, None)) as f:
            data = f.read()
        tree, bin_len, bin_at = _glb(path, data, error)
    else:
        tree = files.read_json(path, lambda p, f, m: error(f, m, "export the car again (the glTF is not valid JSON)"))
        data, bin_len, bin_at = None, None, None
    if not isinstance(tree, dict):
        raise error("(file)", "the glTF JSON is not an object", "export the car again")
    from .gltf import check_required

    check_required(tree, error)  # first: a meshopt file's fallback buffer has no bytes, and is no error of its own
    buffers, views = _list(tree, "buffers", error), _list(tree, "bufferViews", error)
    accessors, images = _list(tree, "accessors", error), _list(tree, "images", error)

    # buffers: what each really holds, and its declared byteLength within that
    held, total = [], size
    for i, b in enumerate(buffers):
        field = f"buffers[{i}]"
        declared = _index(b, "byteLength", f"{field}.byteLength", error)
        uri = b.get("uri")
        if uri is None:
            if not glb or i != 0 or bin_len is None:
                raise error(field, f"{field} has no uri and there is no GLB BIN chunk for it",
                            "export the car again (the glTF is incomplete)")
            have = bin_len
        elif not isinstance(uri, str):
            raise error(f"{field}.uri", f"{field}.uri is not a string", "export the car again")
        elif uri.startswith("data:"):
            comma = uri.find(",")
            have = (len(uri) - comma - 1) * 3 // 4 if comma >= 0 else 0
        else:
            with open_named(uri) as f:
                have = os.fstat(f.fileno()).st_size
            total += have
        if declared > have:
            raise error(field, f"{field} declares {declared:,} bytes but {uri or 'the BIN chunk'!r} holds "
                               f"{have:,}: truncated or the wrong file", "copy or export the car again, with its "
                                                                         "buffer files")
        held.append(declared)

    # buffer views inside their buffers
    view_len = []
    for i, v in enumerate(views):
        field = f"bufferViews[{i}]"
        b = _index(v, "buffer", f"{field}.buffer", error, len(buffers))
        off = _index(v, "byteOffset", f"{field}.byteOffset", error, required=False) or 0
        n = _index(v, "byteLength", f"{field}.byteLength", error)
        _index(v, "byteStride", f"{field}.byteStride", error, required=False, minimum=1)
        if off + n > held[b]:
            raise error(field, f"{field} spans bytes {off:,}–{off + n:,} of buffers[{b}], which has "
                               f"{held[b]:,}", "export the car again (the glTF is corrupt)")
        view_len.append(n)

    # accessors: every count bounded by the bytes behind it
    def fits(field, view, offset, count, elem):
        if count == 0:
            return
        stride = views[view].get("byteStride") or elem
        need = offset + (count - 1) * stride + elem
        if need > view_len[view]:
            raise error(field, f"{field} declares {count:,} elements ({need:,} bytes) but bufferViews[{view}] has "
                               f"{view_len[view]:,} bytes", "export the car again (the glTF is corrupt)")

    for i, a in enumerate(accessors):
        field = f"accessors[{i}]"
        count = _index(a, "count", f"{field}.count", error)
        ctype, kind = a.get("componentType"), a.get("type")
        if ctype not in COMPONENT_BYTES or isinstance(ctype, bool):
            raise error(f"{field}.componentType", f"{field}.componentType {ctype!r} is not a glTF component type",
                        "export the car again (the glTF is corrupt)")
        if kind not in TYPE_COMPONENTS:
            raise error(f"{field}.type", f"{field}.type {kind!r} is not a glTF accessor type",
                        "export the car again (the glTF is corrupt)")
        elem = COMPONENT_BYTES[ctype] * TYPE_COMPONENTS[kind]
        view = _index(a, "bufferView", f"{field}.bufferView", error, len(views), required=False)
        if view is not None:
            fits(field, view, _index(a, "byteOffset", f"{field}.byteOffset", error, required=False) or 0, count,
                 elem)
        elif count > ZERO_ACCESSOR_ELEMENTS_PER_BYTE * total:
            raise error(f"{field}.count", f"{field} has no bufferView and declares {count:,} elements, more than "
                                          f"the {total:,} bytes of the file and its buffers could fill",
                        "export the car again (the glTF is corrupt)")
        sparse = a.get("sparse")
        if sparse is not None:
            if not isinstance(sparse, dict) or not isinstance(sparse.get("indices"), dict) \
                    or not isinstance(sparse.get("values"), dict):
                raise error(f"{field}.sparse", f"{field}.sparse is not a sparse accessor", "export the car again")
            n = _index(sparse, "count", f"{field}.sparse.count", error, count + 1, minimum=1)
            ind, val = sparse["indices"], sparse["values"]
            ityp = ind.get("componentType")
            if ityp not in (5121, 5123, 5125):
                raise error(f"{field}.sparse.indices", f"{field}.sparse.indices.componentType {ityp!r} is not an "
                                                       "unsigned integer type", "export the car again")
            for what, node, e in (("indices", ind, COMPONENT_BYTES[ityp]), ("values", val, elem)):
                vw = _index(node, "bufferView", f"{field}.sparse.{what}.bufferView", error, len(views))
                fits(f"{field}.sparse.{what}", vw,
                     _index(node, "byteOffset", f"{field}.sparse.{what}.byteOffset", error, required=False) or 0, n, e)

    _check_attribute_counts(tree, accessors, error)
    _check_texture_indices(tree, images, error)

    # images: readable, within the pixel bound, named exactly
    sizes = []
    for i, img in enumerate(images):
        field = f"images[{i}]"
        if img.get("mimeType") == "image/ktx2":
            raise error(field, f"{field} is a KTX2 texture, which is not read here (the car would lose its colours)",
                        "export the car with PNG or JPEG textures")
        if "bufferView" in img:
            vw = _index(img, "bufferView", f"{field}.bufferView", error, len(views))
            blob = _view_bytes(path, data, bin_at, buffers, views[vw], open_named)
            sizes.append((f"{field} (bufferViews[{vw}])",
                          check_image(io.BytesIO(blob), error, f"{field} (bufferViews[{vw}])")))
        elif isinstance(img.get("uri"), str):
            uri = img["uri"]
            if uri.startswith("data:"):
                comma = uri.find(",")
                try:
                    blob = base64.b64decode(uri[comma + 1:], validate=False) if comma >= 0 else b""
                except ValueError as e:
                    raise error(field, f"{field}'s data URI is not base64 ({e})", "export the car again") from None
                sizes.append((f"{field} (data URI)", check_image(io.BytesIO(blob), error, f"{field} (data URI)")))
            else:
                with open_named(uri) as f:
                    sizes.append((uri, check_image(f, error, uri)))
        else:
            raise error(field, f"{field} has neither a uri nor a bufferView", "export the car again (the glTF is "
                                                                            "incomplete)")
    check_total_pixels(sizes, error)
    return tree


def check_total_pixels(sizes: Sequence[tuple[str, tuple[int, int]]], error: Callable[..., Exception]) -> None:
    """``sizes``: [(texture name, (width, height))] of one mesh; ``error("(textures)", ...)`` when their pixels
    together exceed ``MAX_TOTAL_TEXTURE_PIXELS`` (every one is held decoded while the mesh is sampled)."""
    total = sum(w * h for _, (w, h) in sizes)
    if total > MAX_TOTAL_TEXTURE_PIXELS:
        listed = ", ".join(f"{name!r} {w} × {h}" for name, (w, h) in sizes)
        raise error("(textures)", f"its {len(sizes)} textures hold {_pixels(total)} together ({listed}), more than "
                                  f"the {_pixels(MAX_TOTAL_TEXTURE_PIXELS)} (2 × 8192 × 8192) read for one mesh",
                    "scale the textures down, or bake them into fewer")


def _scale_of(node) -> float:
    """The largest factor by which a glTF node's own transform (``scale`` or ``matrix``) scales lengths, or None."""
    import numpy as np

    try:
        if isinstance(node.get("matrix"), list) and len(node["matrix"]) == 16:
            m = np.array(node["matrix"], np.float64).reshape(4, 4)[:3, :3]
            return float(np.linalg.norm(m, axis=0).max())
        if isinstance(node.get("scale"), list) and node["scale"]:
            return float(np.abs(np.array(node["scale"], np.float64)).max())
    except (TypeError, ValueError):
        return None
    return None


def check_extent(vertices: np.ndarray, error: Callable[..., Exception], tree: dict | None = None) -> None:
    """The car's size: the largest side of the box around ``vertices`` ((N, 3), finite ones; node transforms
    applied) within [``MIN_EXTENT``, ``MAX_EXTENT``] and every coordinate within ±``MAX_EXTENT`` (float32 keeps
    them, with detail). ``error(field, message, hint)``: the field is the glTF node whose scale is furthest from 1
    in the offending direction (``nodes[i].scale`` / ``.matrix``, from ``tree``, the glTF JSON), else "(extent)"."""
    import numpy as np

    v = np.asarray(vertices, np.float64)
    v = v[np.isfinite(v).all(axis=1)]
    if not len(v):
        return
    with np.errstate(over="ignore", invalid="ignore"):
        extent = float((v.max(axis=0) - v.min(axis=0)).max())
    reach = float(np.abs(v).max())
    if MIN_EXTENT <= extent <= MAX_EXTENT and reach <= MAX_EXTENT:
        return
    large = not extent < MIN_EXTENT
    field = "(extent)"
    nodes = tree.get("nodes") if isinstance(tree, dict) else None
    if isinstance(nodes, list):
        scales = [(s, i) for i, n in enumerate(nodes) if isinstance(n, dict)
                  for s in [_scale_of(n)] if s is not None and s > 0 and s != 1.0]
        if scales:
            s, i = max(scales) if large else min(scales)
            if (s > 1) == large:
                field = f"nodes[{i}].{'matrix' if 'matrix' in nodes[i] else 'scale'}"
    what = (f"the car is {extent:.3g} units across and reaches {reach:.3g} from the origin: more than the "
            f"{MAX_EXTENT:g} read here (float32 positions)" if large else
            f"the car is {extent:.3g} units across: less than the {MIN_EXTENT:g} read here (no car in any unit)")
    raise error(field, f"{what} (extent of its vertices, node transforms applied)",
                f"check the {'scale of ' + field if field != '(extent)' else 'units and scale of the mesh'} and "
                "export the car again in metres, near the origin")


def _check_attribute_counts(tree, accessors, error) -> None:
    """Every attribute of a primitive has as many elements as its POSITION (glTF 2.0, 3.7.2.1: "All attribute
    accessors for a given primitive MUST have the same count"). An accessor without a bufferView is zeros of any
    count the file's bytes allow: one that does not match its vertices gave a car whose texture coordinates were all
    0, without a word. Structure this does not understand is left to trimesh (which raises, or goes on: a warning)."""
    meshes = tree.get("meshes")
    for m, mesh in enumerate(meshes if isinstance(meshes, list) else []):
        prims = mesh.get("primitives") if isinstance(mesh, dict) else None
        for p, prim in enumerate(prims if isinstance(prims, list) else []):
            attrs = prim.get("attributes") if isinstance(prim, dict) else None
            if not isinstance(attrs, dict):
                continue
            counts = {name: (i, accessors[i]["count"]) for name, i in attrs.items()
                      if isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(accessors)}
            if "POSITION" not in counts:
                continue
            pi, n = counts["POSITION"]
            for name, (i, c) in sorted(counts.items()):
                if c != n:
                    field = f"meshes[{m}].primitives[{p}].attributes.{name}"
                    raise error(field, f"{field}: {name} (accessors[{i}]) has {c:,} elements but POSITION "
                                       f"(accessors[{pi}]) has {n:,}: every attribute of a primitive has one "
                                       "element per vertex", "export the car again (the glTF is corrupt)")


def _check_texture_indices(tree, images, error) -> None:
    """Every material's base-colour texture names a texture (``materials[i].pbrMetallicRoughness.baseColorTexture
    .index``), every texture an image (``source``, or an extension's ``source``: ``EXT_texture_webp``) and a
    sampler (``sampler``) the file has, and every sampler's ``wrapS`` / ``wrapT`` is a glTF wrap mode
    (``colors.WRAP_MODES``). trimesh went on past an index out of range with a log line: a white car."""
    from .colors import WRAP_MODES

    textures, samplers = _list(tree, "textures", error), _list(tree, "samplers", error)
    corrupt = "export the car again (the glTF is corrupt)"

    def names(field, v, what, count):
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < count:
            have = (f"{count} {what}{'' if count == 1 else 's'} (indices 0 to {count - 1})" if count
                    else f"no {what}s")
            raise error(field, f"{field} = {v!r} names no {what}: the file has {have}", corrupt)

    for i, s in enumerate(samplers):
        for key in ("wrapS", "wrapT"):
            if key in s and (isinstance(s[key], bool) or s[key] not in WRAP_MODES):
                field = f"samplers[{i}].{key}"
                raise error(field, f"{field} = {s[key]!r} is not a glTF wrap mode ("
                                   + ", ".join(f"{k} {n}" for k, n in WRAP_MODES.items()) + ")", corrupt)
    for j, t in enumerate(textures):
        if "source" in t:
            names(f"textures[{j}].source", t["source"], "image", len(images))
        for name, ext in (t.get("extensions") or {}).items() if isinstance(t.get("extensions"), dict) else ():
            if isinstance(ext, dict) and "source" in ext:
                names(f"textures[{j}].extensions.{name}.source", ext["source"], "image", len(images))
        if "sampler" in t:
            names(f"textures[{j}].sampler", t["sampler"], "sampler", len(samplers))
    for i, m in enumerate(_list(tree, "materials", error)):
        pbr = m.get("pbrMetallicRoughness")
        info = pbr.get("baseColorTexture") if isinstance(pbr, dict) else None
        if isinstance(info, dict):
            names(f"materials[{i}].pbrMetallicRoughness.baseColorTexture.index", info.get("index"), "texture",
                  len(textures))


def _view_bytes(path, data, bin_at, buffers, view, open_named) -> bytes:
    """The bytes of a (checked) buffer view: from the GLB's BIN chunk, a data URI or the buffer's file."""
    b = buffers[view["buffer"]]
    off, n = view.get("byteOffset", 0), view["byteLength"]
    uri = b.get("uri")
    if uri is None:
        return data[bin_at + off:bin_at + off + n]
    if uri.startswith("data:"):
        return base64.b64decode(uri[uri.find(",") + 1:])[off:off + n]
    with open_named(uri) as f:
        f.seek(off)
        return f.read(n)


# -------------------------------------------------------------------------------------------------------- OFF

def check_off(path: str | os.PathLike, error: Callable[..., Exception]) -> None:
    """An OFF file's header counts against its lines (trimesh reads the vertices it promises, but takes fewer
    faces than promised without a word). Comments (``#``) and blank lines do not count."""
    with files.open_regular(path, lambda p, f, m: error("(file)", m, None)) as f:
        text = f.read().decode("utf-8", errors="replace")
    lines = [ln.split("#", 1)[0].strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    if not lines:
        return
    words = lines[0].split()
    if not words[0].upper().endswith("OFF"):
        return  # trimesh says what it thinks of it
    counts = words[1:] or (lines[1].split() if len(lines) > 1 else [])
    body = lines[1:] if len(words) > 1 else lines[2:]
    try:
        nv, nf = int(counts[0]), int(counts[1])
    except (IndexError, ValueError):
        raise error("(header)", "the OFF header has no vertex and face counts", "export the mesh again") from None
    if nv < 0 or nf < 0:
        raise error("(header)", f"the OFF header's counts ({nv} vertices, {nf} faces) are negative",
                    "export the mesh again")
    if nv + nf > len(body):
        raise error("(header)", f"the OFF header promises {nv:,} vertices and {nf:,} faces ({nv + nf:,} lines) "
                                f"but {len(body):,} lines follow: truncated", "copy or export the mesh again")


# -------------------------------------------------------------------------------------------------------- OBJ

#: a face line holding an index of 0 somewhere (a candidate: ``_zero_index_line`` reads the line itself)
_ZERO_INDEX = re.compile(rb"(?m)^[ \t]*f(?=[ \t])[^\n]*?[ \t/][-+]?0+(?![^ \t/\r\n#])")


def _zero_index_line(text: bytes):
    """The 1-based line number of the first face (``f``) line with a vertex, texture-coordinate or normal index of
    0, or None. OBJ indices count from 1 (negative ones count back from the last element read): 0 names nothing,
    and trimesh read it as the first vertex."""
    for match in _ZERO_INDEX.finditer(text):
        start = text.rfind(b"\n", 0, match.start()) + 1
        end = text.find(b"\n", match.start())
        line = text[start:end if end >= 0 else len(text)].split(b"#", 1)[0]
        for word in line.split()[1:]:
            for part in word.split(b"/"):
                try:
                    if part and int(part) == 0:
                        return text.count(b"\n", 0, start) + 1
                except ValueError:
                    pass  # not an index: trimesh says what it thinks of it
    return None


def _mtl_name(text: str):
    """The MTL file trimesh reads for an OBJ, found as trimesh finds it (``trimesh.exchange.obj.load_obj``: the rest
    of the line after the first ``mtllib`` in the text), or None when there is none."""
    at = text.find("mtllib")
    if at < 0:
        return None
    end = text.find("\n", at)
    return text[at + 6:end if end >= 0 else len(text)].strip()


#: The MTL specification's texture-map options -> (fewest, most) values each takes (``-o``/``-s``/``-t``: u [v [w]]).
MTL_TEXTURE_OPTIONS = {"-blendu": (1, 1), "-blendv": (1, 1), "-bm": (1, 1), "-boost": (1, 1), "-cc": (1, 1),
                       "-clamp": (1, 1), "-imfchan": (1, 1), "-mm": (2, 2), "-o": (1, 3), "-s": (1, 3), "-t": (1, 3),
                       "-texres": (1, 1)}
#: options that change the colours read from a diffuse map and are not applied, with the values that change nothing
#: (``-clamp`` is applied: ``MtlMap.clamp``)
_MTL_NEUTRAL = {"-o": 0.0, "-s": 1.0, "-t": 0.0, "-mm": (0.0, 1.0), "-cc": "off"}


class MtlMap(NamedTuple):
    """A ``map_Kd`` of an MTL: its texture file name, the options not applied (``ignored_options``), the material
    it belongs to (the ``newmtl`` name, as trimesh names the material) and whether ``-clamp on`` clamps it (texture
    coordinates beyond [0, 1] read the edge texels: CLAMP_TO_EDGE; off by default, i.e. REPEAT)."""

    file: str
    ignored: list
    material: str
    clamp: bool


def _number(word):
    try:
        float(word)
        return True
    except ValueError:
        return False


def mtl_texture(value: str) -> tuple[str, list[tuple[str, list[str]]]]:
    """(file name, [(option, [values])]) of an MTL ``map_*`` value: options first (``MTL_TEXTURE_OPTIONS``; a
    variable-length one takes the numbers that follow, up to its most), then the file name, the rest of the value
    (spaces kept). A name that does not start with a known option is all file name. The file name is "" when the
    options leave nothing."""
    import re

    words = [(m.group(), m.start()) for m in re.finditer(r"\S+", value)]
    options, k = [], 0
    while k < len(words) and words[k][0].lower() in MTL_TEXTURE_OPTIONS:
        opt = words[k][0].lower()
        least, most = MTL_TEXTURE_OPTIONS[opt]
        args = [w for w, _ in words[k + 1:k + 1 + most]]
        if most > least:   # u [v [w]]: the numbers that follow
            n = next((j for j, w in enumerate(args) if not _number(w)), len(args))
            args = args[:max(n, least)]
        if len(args) < least:
            return "", options + [(opt, args)]
        options.append((opt, args))
        k += 1 + len(args)
    return (value[words[k][1]:].strip() if k < len(words) else ""), options


def ignored_options(options: Iterable[tuple[str, list[str]]]) -> list:
    """The options of ``mtl_texture`` that would change a diffuse map's colours (not applied here), as written."""
    out = []
    for opt, args in options:
        if opt not in _MTL_NEUTRAL:
            continue
        neutral = _MTL_NEUTRAL[opt]
        if isinstance(neutral, str):
            changes = [a.lower() for a in args] != [neutral]
        else:
            try:
                vals = [float(a) for a in args]
            except ValueError:
                changes = True
            else:
                changes = (vals != list(neutral)) if isinstance(neutral, tuple) else any(x != neutral for x in vals)
        if changes:
            out.append(" ".join([opt, *args]))
    return out


def check_mtl(name: str, data: bytes, error: Callable[..., Exception]) -> list:
    """An OBJ's MTL file (as ``trimesh.exchange.obj.parse_mtl`` reads it: a line is its words, the first a key,
    any case): it must define a material (a ``newmtl`` with a name; random bytes, an empty file or a file of
    comments define none, and trimesh then drops every material and texture without a word), and every ``map_Kd``
    must name a file after its options (``mtl_texture``; trimesh skips one without a value: the car would lose its
    texture). Returns an ``MtlMap`` for every ``map_Kd``."""
    text = data.decode("utf-8", errors="replace")
    defined, maps, material = False, [], ""
    for number, line in enumerate(text.splitlines(), 1):
        words = line.split()
        key = words[0].lower() if words else ""
        if key == "newmtl" and len(words) > 1:
            defined, material = True, " ".join(words[1:])   # as trimesh names it
        elif key == "map_kd":
            file_name, options = mtl_texture(line[line.lower().index("map_kd") + 6:])  # as trimesh takes the value
            if not file_name:
                raise error("map_Kd", f"{name!r} (named by the mesh) line {number}: map_Kd names no file, so the "
                                      "material's texture would be dropped", f"name the texture file in {name!r} "
                                                                             "(or remove the map_Kd line)")
            clamp = any(opt == "-clamp" and [a.lower() for a in args] == ["on"] for opt, args in options)
            maps.append(MtlMap(file_name, ignored_options(options), material, clamp))
    if not defined:
        raise error(name, f"{name!r} (named by the mesh) defines no material (no 'newmtl' line): it is not an MTL "
                          "file or it is empty, and the car would lose its materials and textures",
                    "export the car again with its MTL file (or remove the mtllib line for an untextured car)")
    return maps


def check_obj(path: str | os.PathLike, error: Callable[..., Exception], open_named: Callable[[str], BinaryIO]) -> list:
    """An OBJ before trimesh reads it: no face index of 0 (``_zero_index_line``; the field is ``f``), and its MTL
    file (``_mtl_name``, opened with ``open_named``, the caller's named-file rules) checked by ``check_mtl``, its
    textures from their headers (``check_image``, ``check_total_pixels``). Indices beyond the vertices raise in
    trimesh (``load.load_mesh`` refuses them). Returns its ``MtlMap``s (``check_mtl``)."""
    with files.open_regular(path, lambda p, f, m: error("(file)", m, None)) as f:
        data = f.read()
    data = data.replace(b"\r\n", b"\n")  # as trimesh reads it
    line = _zero_index_line(data)
    if line is None and b"\\\n" in data:  # trimesh joins continued lines (the number is then of the joined text)
        line = _zero_index_line(data.replace(b"\\\n", b""))
    if line is not None:
        raise error("f", f"line {line}: face index 0: OBJ indices count from 1 (negative ones back from the last "
                         "vertex), so 0 names no vertex", "export the mesh again")
    name = _mtl_name(data.decode("utf-8", errors="replace"))
    if not name:
        return []
    with open_named(name) as f:
        maps = check_mtl(name, f.read(), error)
    sizes = []
    for tex in (m.file for m in maps):
        if os.path.splitext(tex)[1].lower() in IMAGE_EXTENSIONS:  # others: trimesh opens them, PIL's bound holds
            with open_named(tex) as f:
                sizes.append((tex, check_image(f, error, tex)))
    check_total_pixels(sizes, error)
    return maps
