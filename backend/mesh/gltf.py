"""glTF 2.0 content that trimesh 5.2.0 reads wrong or not at all, made plain before it reads the file (issue 31),
and the required extensions refused by name.

What trimesh 5.2.0 (``trimesh/exchange/gltf``) does itself, and what is done here instead:

* Accessors: trimesh takes every accessor's values as stored: a ``normalized`` integer accessor (core glTF 2.0
  allows UNSIGNED_BYTE / UNSIGNED_SHORT texture coordinates; ``KHR_mesh_quantization`` BYTE / SHORT positions,
  normals and texture coordinates) comes out as raw counts (a UV of 65535 instead of 1), and ``sparse`` is
  ignored. Here: ``dequantize`` (glTF 2.0 §3.11: c / 255, c / 65535, max(c / 127, -1), max(c / 32767, -1); an
  unnormalized integer is its value, the node transform dequantizes it) and the sparse substitution.
* The base-colour texture's texture coordinates: trimesh always reads ``TEXCOORD_0`` and ignores the textureInfo's
  ``texCoord`` and ``KHR_texture_transform``. Here: the set the textureInfo names (the extension's ``texCoord``
  overriding it), moved by ``texture_transform``.
* ``KHR_draco_mesh_compression``: trimesh decodes it with DracoPy (a placeholder of zeros and a log line when that
  fails, and data of the wrong shape surfaces as a reshape error inside trimesh). Here: decoded with DracoPy
  (``DRACOPY``, pinned in requirements.txt) into the plain accessors and checked against them (every attribute the
  extension names present, the accessor type's number of components, finite positions, face indices within the
  decoded vertices and as many as the indices accessor declares); a failure is an error naming
  ``KHR_draco_mesh_compression`` and the primitive (``meshes[m].primitives[p]``); without DracoPy installed the file
  is refused (``check_required``).

* Samplers: trimesh keeps no sampler, and the colours were read with REPEAT whatever ``wrapS`` / ``wrapT`` said.
  Here: a material whose base-colour texture wraps otherwise (``base_colour_wrap``) is renamed in the plain GLB
  (``WRAP_TAG`` + its index), and ``part_wraps`` gives each part read from it its (wrapS, wrapT), restoring the
  name (``backend.mesh.colors`` applies the wrap to each sample's UV).

``plain_glb`` writes a primitive's POSITION, indices, the base-colour texture's UVs (as TEXCOORD_0, the transform
applied) and COLOR_0 as float32 / uint32 accessors in an added buffer (GLB: after the BIN chunk's bytes; glTF: a
new buffer 0, the others shifted), drops its other attributes and its Draco extension, and strips ``texCoord`` and
``KHR_texture_transform`` from the base-colour textureInfos: trimesh then reads plain glTF, with the file's own
images, buffers and node tree. A file without anything of the above is given to trimesh unchanged.

Texture coordinates are in glTF's convention throughout this module: (u, v) with the origin at the image's top-left
corner, u right, v down (trimesh flips v afterwards, as for any glTF).

No bpy, no torch.

(Just over 400 lines: the glTF features trimesh does not apply (quantization, texture transforms, UV sets,
sparse accessors, Draco, samplers) are rewritten in one pass over the same accessors.)
"""

from __future__ import annotations

import base64
import copy
import json
import math
import os
import struct
from typing import TYPE_CHECKING

import numpy as np

from scpainter_blender.core import glb

from . import checks
from .colors import DEFAULT_WRAP

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from typing import BinaryIO
    import trimesh

DRACO = "KHR_draco_mesh_compression"
TRANSFORM = "KHR_texture_transform"
#: the name prefix that marks a material with a non-default wrap in the plain GLB (``part_wraps`` removes it)
WRAP_TAG = "scpainter-wrap:"
DRACOPY = "DracoPy==2.2.0"      # what requirements.txt pins; named in the refusal when it is not installed
#: What to do about Draco data that does not decode into the primitive's accessors.
DRACO_HINT = "export the car again (without Draco, or with another exporter): its Draco data is damaged"
#: Required extensions read here, or read as absent without changing the geometry or the base colour (material
#: extensions change shading only; unlit keeps the base colour; lights, XMP and variants' default are harmless).
READ_EXTENSIONS = frozenset({
    TRANSFORM, "KHR_mesh_quantization", DRACO, "EXT_texture_webp", "KHR_materials_pbrSpecularGlossiness",
    "KHR_materials_unlit", "KHR_materials_emissive_strength", "KHR_materials_ior", "KHR_materials_specular",
    "KHR_materials_clearcoat", "KHR_materials_transmission", "KHR_materials_volume", "KHR_materials_sheen",
    "KHR_materials_iridescence", "KHR_materials_anisotropy", "KHR_materials_dispersion",
    "KHR_materials_diffuse_transmission", "KHR_materials_variants", "KHR_lights_punctual", "KHR_xmp_json_ld",
})
_MESHOPT = ("meshopt-compressed geometry", "decompress it with gltfpack 0.21 or later: `gltfpack -i IN.glb -o "
                                          "OUT.glb -noq` (without -c), or export the car again without meshopt "
                                          "compression")
#: What a required extension not read here holds, and what to do about it (others: the generic hint).
FIX = {
    "EXT_meshopt_compression": _MESHOPT,
    "KHR_meshopt_compression": _MESHOPT,
    "EXT_mesh_gpu_instancing": ("GPU instances: only one copy would be read", "expand them with glTF-Transform: "
                                "`gltf-transform uninstance IN.glb OUT.glb`"),
    "KHR_texture_basisu": ("KTX2 textures", "export the car with PNG or JPEG textures"),
    "EXT_texture_avif": ("AVIF textures", "export the car with PNG or JPEG textures"),
    DRACO: ("Draco-compressed geometry, decoded with DracoPy, which is not installed", f"`pip install {DRACOPY}`"),
}
_COMPONENT_DTYPE = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
                    5124: np.int32, 5126: np.float32}
_TRIANGLES = (4, 5, 6)           # TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN (others: trimesh's, as they are)


def _dracopy():
    """The DracoPy module, or None where it is not installed."""
    try:
        import DracoPy
    except ImportError:
        return None
    return DracoPy


def _uses_draco(tree) -> bool:
    return any(isinstance(p, dict) and DRACO in (p.get("extensions") or {})
               for m in tree.get("meshes") or [] if isinstance(m, dict)
               for p in m.get("primitives") or [])


def check_required(tree: dict, error: Callable[..., Exception]) -> None:
    """Refuse a glTF whose ``extensionsRequired`` names extensions not read here (``READ_EXTENSIONS``), each named
    with what to do (``FIX``), and one compressed with Draco where DracoPy is not installed. ``error(field,
    message, hint)``: the caller's MeshAssetError. trimesh would read such a file as placeholder zeros ("faces all
    have zero area") or with a missing buffer."""
    required = tree.get("extensionsRequired", [])
    if not isinstance(required, list) or not all(isinstance(e, str) for e in required):
        raise error("extensionsRequired", "extensionsRequired is not a list of names", "export the car again")
    missing = [e for e in dict.fromkeys(required) if e not in READ_EXTENSIONS]
    if (DRACO in required or _uses_draco(tree)) and _dracopy() is None:
        missing.append(DRACO)
    if not missing:
        return
    rest = [e for e in missing if e not in FIX]
    fixes = [f"{e}: {FIX[e][1]}" for e in missing if e in FIX]
    if rest:
        fixes.append(f"{', '.join(rest)}: export the car again without "
                     f"{'this extension' if len(rest) == 1 else 'these extensions'} (e.g. from Blender)")
    named = ", ".join(f"{e} ({FIX[e][0]})" if e in FIX else e for e in missing)
    many = len(missing) > 1
    raise error("extensionsRequired", f"it requires glTF extension{'s' if many else ''} not read here: {named}; "
                                      f"the car cannot be read without {'them' if many else 'it'}",
                "; ".join(fixes))


def dequantize(values: np.ndarray, normalized: bool) -> np.ndarray:
    """float64 values of an accessor's components (glTF 2.0 §3.11): a normalized UNSIGNED_BYTE c / 255,
    UNSIGNED_SHORT c / 65535, BYTE max(c / 127, -1), SHORT max(c / 32767, -1); anything else its value."""
    a = np.asarray(values)
    if not normalized or not np.issubdtype(a.dtype, np.integer):
        return a.astype(np.float64)
    info = np.iinfo(a.dtype)
    out = a.astype(np.float64) / info.max
    return np.maximum(out, -1.0) if info.min < 0 else out


def texture_transform(uv: np.ndarray, ext: dict) -> np.ndarray:
    """UVs (n, 2) (glTF convention: origin top-left, v down) moved by a ``KHR_texture_transform`` object:
    uv' = T R S uv (the extension's README), rotation counter-clockwise in this UV space (an image turned clockwise
    on screen; the README's example, offset (0, 1), rotation π/2, scale 0.5, reads the lower-left quadrant):

        u' = ox + cos(r) sx u + sin(r) sy v,   v' = oy - sin(r) sx u + cos(r) sy v

    ValueError naming the property when ``offset`` / ``scale`` are not two finite numbers or ``rotation`` not one.
    """
    def numbers(key, default, n):
        value = ext.get(key, default)
        one = [value] if n == 1 else value
        if not (isinstance(one, list) and len(one) == n and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in one)):
            want = "a finite number" if n == 1 else f"{n} finite numbers"
            raise ValueError(f"{key} is {str(value)[:40]}, not {want}")
        return [float(x) for x in one]

    if not isinstance(ext, dict):
        raise ValueError(f"is {str(ext)[:40]}, not an object")
    off, scale, (r,) = numbers("offset", [0.0, 0.0], 2), numbers("scale", [1.0, 1.0], 2), numbers("rotation", 0.0, 1)
    c, s = math.cos(r), math.sin(r)
    u, v = uv[:, 0] * scale[0], uv[:, 1] * scale[1]
    return np.stack([off[0] + c * u + s * v, off[1] - s * u + c * v], axis=1)


def _base_colour_info(tree, prim):
    """The base-colour textureInfo of a primitive's material, or None."""
    mats = tree.get("materials") or []
    k = prim.get("material")
    if not isinstance(k, int) or isinstance(k, bool) or not 0 <= k < len(mats) or not isinstance(mats[k], dict):
        return None
    info = (mats[k].get("pbrMetallicRoughness") or {}).get("baseColorTexture")
    return info if isinstance(info, dict) else None


def _uv_set(info) -> int:
    """The texture-coordinate set a textureInfo samples: the extension's ``texCoord`` overrides its own."""
    ext = (info.get("extensions") or {}).get(TRANSFORM) or {}
    k = ext.get("texCoord", info.get("texCoord", 0))
    return k if isinstance(k, int) and not isinstance(k, bool) and k >= 0 else 0


def base_colour_wrap(tree: dict, k: int) -> tuple:
    """(wrapS, wrapT) of material ``k``'s base-colour texture's sampler (glTF enums; ``checks.check_gltf``
    checked the indices and values); REPEAT where the texture has no sampler or the sampler no wrap."""
    info = _base_colour_info(tree, {"material": k})
    if info is None:
        return DEFAULT_WRAP
    tex = tree["textures"][info["index"]]
    if "sampler" not in tex:
        return DEFAULT_WRAP
    sampler = tree["samplers"][tex["sampler"]]
    return sampler.get("wrapS", DEFAULT_WRAP[0]), sampler.get("wrapT", DEFAULT_WRAP[1])


def _wrapped(tree) -> list:
    """Indices of the materials whose base-colour texture wraps other than REPEAT both ways."""
    return [k for k in range(len(tree.get("materials") or [])) if base_colour_wrap(tree, k) != DEFAULT_WRAP]


def part_wraps(parts: Sequence[trimesh.Trimesh], tree: dict) -> list:
    """(wrapS, wrapT) of each part (trimesh meshes read from ``plain_glb``'s output): its material's, found by the
    ``WRAP_TAG`` name ``plain_glb`` gave it, whose own name (or none) is restored; REPEAT for every other part."""
    found = {}
    for part in parts:
        material = getattr(part.visual, "material", None)
        name = getattr(material, "name", None)
        if isinstance(name, str) and name.startswith(WRAP_TAG):
            found[id(material)] = (material, int(name[len(WRAP_TAG):]))
    for material, k in found.values():  # after all are found: parts share their material
        material.name = tree["materials"][k].get("name")
    return [base_colour_wrap(tree, found[id(m)][1]) if id(m) in found else DEFAULT_WRAP
            for m in (getattr(p.visual, "material", None) for p in parts)]


def needs_plain(tree: dict) -> bool:
    """Whether trimesh would misread ``tree``: a triangle primitive with Draco, a non-float or sparse POSITION or
    base-colour UV set, or a base-colour texture whose UVs are not TEXCOORD_0 untransformed; or a base-colour
    texture that does not wrap with REPEAT (its material is marked for ``part_wraps``)."""
    if _wrapped(tree):
        return True
    acc = tree.get("accessors") or []

    def odd(i):
        if not isinstance(i, int) or isinstance(i, bool) or not 0 <= i < len(acc):
            return False
        return acc[i].get("componentType") != 5126 or "sparse" in acc[i]

    for m in tree.get("meshes") or []:
        for p in (m.get("primitives") or []) if isinstance(m, dict) else []:
            if not isinstance(p, dict) or p.get("mode", 4) not in _TRIANGLES:
                continue
            attrs = p.get("attributes") or {}
            if DRACO in (p.get("extensions") or {}) or odd(attrs.get("POSITION")):
                return True
            info = _base_colour_info(tree, p)
            if info is not None and (TRANSFORM in (info.get("extensions") or {}) or _uv_set(info) != 0
                                     or odd(attrs.get("TEXCOORD_0"))):
                return True
    return False


class _Reader:
    """Accessors of a checked glTF read into numpy (``checks.check_gltf`` bounded every count by the bytes)."""

    def __init__(self, path, tree, error, open_named):
        self.tree, self.error, self.buffers = tree, error, []
        self.bin = b""
        if path.lower().endswith(".glb"):
            with open(path, "rb") as f:
                data = f.read()
            _, bin_len, bin_at = checks._glb(path, data, error)
            self.bin = data[bin_at:bin_at + bin_len] if bin_len is not None else b""
        for b in tree.get("buffers") or []:
            uri = b.get("uri")
            if uri is None:
                self.buffers.append(self.bin)
            elif uri.startswith("data:"):
                self.buffers.append(base64.b64decode(uri[uri.find(",") + 1:]))
            else:
                with open_named(uri) as f:
                    self.buffers.append(f.read())
        self._draco = {}

    def view(self, k) -> bytes:
        v = self.tree["bufferViews"][k]
        off = v.get("byteOffset", 0)
        return self.buffers[v["buffer"]][off:off + v["byteLength"]]

    def _strided(self, view, offset, count, dtype, width):
        """(count, width) values of ``dtype`` from a buffer view, at ``offset``, rows ``byteStride`` apart."""
        data = self.view(view)
        elem = np.dtype(dtype).itemsize * width
        stride = self.tree["bufferViews"][view].get("byteStride") or elem
        if count == 0:
            return np.zeros((0, width), dtype)
        rows = np.lib.stride_tricks.as_strided(np.frombuffer(data, np.uint8, offset=offset,
                                                             count=(count - 1) * stride + elem),
                                               (count, elem), (stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, width)

    def accessor(self, i, draco=None) -> np.ndarray:
        """(count, components) of accessor ``i`` in its stored type, sparse values substituted; ``draco``: the
        decoded values that replace an accessor without a bufferView."""
        a = self.tree["accessors"][i]
        dtype = _COMPONENT_DTYPE[a["componentType"]]
        width = checks.TYPE_COMPONENTS[a["type"]]
        if draco is not None:
            out = np.asarray(draco).reshape(len(draco), -1)
        elif "bufferView" in a:
            out = self._strided(a["bufferView"], a.get("byteOffset", 0), a["count"], dtype, width)
        else:
            out = np.zeros((a["count"], width), dtype)
        sparse = a.get("sparse")
        if sparse:
            out = out.copy()
            ind, val = sparse["indices"], sparse["values"]
            where = self._strided(ind["bufferView"], ind.get("byteOffset", 0), sparse["count"],
                                  _COMPONENT_DTYPE[ind["componentType"]], 1)[:, 0].astype(np.int64)
            if len(where) and where.max() >= len(out):
                raise self.error(f"accessors[{i}].sparse", f"accessors[{i}].sparse names element {where.max()} of "
                                                           f"{len(out)}", "export the car again (the glTF is corrupt)")
            out[where] = self._strided(val["bufferView"], val.get("byteOffset", 0), sparse["count"], dtype, width)
        return out

    def draco(self, where, prim) -> dict:
        """{glTF attribute name or "indices": decoded values} of a Draco-compressed primitive, checked against the
        accessors it replaces (``_check_draco``): every error names ``KHR_draco_mesh_compression`` and the
        primitive, never a reshape deep in trimesh."""
        DracoPy = _dracopy()
        ext = prim["extensions"][DRACO]
        try:
            decoded = DracoPy.decode(self.view(ext["bufferView"]))
            ids = {v: k for k, v in (ext.get("attributes") or {}).items()}
            out = {ids[a["unique_id"]]: np.asarray(a["data"]) for a in decoded.attributes if a["unique_id"] in ids}
            out["indices"] = np.asarray(decoded.faces).reshape(-1)
        except Exception as e:  # DracoPy raises its own errors (and KeyError/TypeError on a malformed extension)
            raise self.error(f"{where}.extensions.{DRACO}", f"{where}: {DRACO}: its Draco-compressed data cannot be "
                                                            f"decoded ({type(e).__name__}: {e})", DRACO_HINT) from None
        self._check_draco(where, prim, ext, out)
        return out

    def _check_draco(self, where, prim, ext, out) -> None:
        """Refuse decoded Draco data that cannot be the accessors it stands for (a damaged payload decodes into
        any shape, or an extension whose ``attributes`` name the wrong ids): an attribute it lacks, another number
        of components than the accessor's type, non-finite positions, face indices past its vertices."""
        field = f"{where}.extensions.{DRACO}"
        attrs = prim.get("attributes") or {}
        acc = self.tree["accessors"]
        for name, uid in (ext.get("attributes") or {}).items():
            if name not in attrs:
                continue
            if name not in out:
                raise self.error(f"{field}.attributes.{name}", f"{where}: {DRACO}: its Draco data has no attribute "
                                                               f"{uid}, which the extension names for {name}: a "
                                                               "damaged payload or extension", DRACO_HINT)
            if out[name].size == 0:   # (nothing to reshape: numpy cannot infer a width from no values)
                raise self.error(f"{field}.attributes.{name}", f"{where}: {DRACO}: its Draco data holds no {name} "
                                                               "values: a damaged payload", DRACO_HINT)
            values = out[name] = out[name].reshape(len(out[name]), -1)
            i = attrs[name]
            want = checks.TYPE_COMPONENTS.get(acc[i].get("type"))
            if values.shape[1] != want:
                raise self.error(f"{field}.attributes.{name}", f"{where}: {DRACO}: its Draco data gives {name} "
                                                               f"{values.shape[1]} components per vertex, "
                                                               f"accessors[{i}] ({acc[i].get('type')}) {want}: a "
                                                               "damaged payload or extension", DRACO_HINT)
        positions = out.get("POSITION")
        if positions is not None and not np.isfinite(positions).all():
            raise self.error(f"{field}.attributes.POSITION", f"{where}: {DRACO}: its Draco data decodes to "
                                                             "non-finite positions: a damaged payload", DRACO_HINT)
        indices = out["indices"]
        if positions is not None and len(indices) and int(indices.max()) >= len(positions):
            raise self.error(field, f"{where}: {DRACO}: its Draco data's faces name vertex {int(indices.max()):,}, "
                                    f"it decodes {len(positions):,} vertices: a damaged payload", DRACO_HINT)
        if "indices" in prim and len(indices) != acc[prim["indices"]].get("count"):
            raise self.error(field, f"{where}: {DRACO}: its Draco data holds {len(indices):,} face indices but "
                                    f"accessors[{prim['indices']}] declares {acc[prim['indices']].get('count'):,}: "
                                    "a damaged payload", DRACO_HINT)


def plain_glb(path: str | os.PathLike, tree: dict, error: Callable[..., Exception],
              open_named: Callable[[str], BinaryIO]) -> bytes | None:
    """A GLB (bytes) of ``tree`` made plain as the module docstring says, or None when trimesh reads the file
    right as it is (``needs_plain``). ``error(field, message, hint)``: the caller's MeshAssetError (a base-colour
    texture whose UV set the primitive lacks; Draco data that does not decode); ``open_named(name)`` opens a file
    the glTF names (its buffers)."""
    if not needs_plain(tree):
        return None
    src = _Reader(os.fspath(path), tree, error, open_named)
    new = copy.deepcopy(tree)
    buffers = tree.get("buffers") or []
    # the added data goes into the GLB's BIN chunk: after a GLB's own (buffer 0), else as a new buffer 0
    own_bin = path.lower().endswith(".glb") and bool(buffers) and "uri" not in buffers[0]
    blob = bytearray(src.bin if own_bin else b"")

    def add(values, ctype, kind):
        blob.extend(b"\0" * (-len(blob) % 4))
        arr = np.ascontiguousarray(values, _COMPONENT_DTYPE[ctype])
        new["bufferViews"].append({"buffer": 0, "byteOffset": len(blob), "byteLength": arr.nbytes})
        blob.extend(arr.tobytes())
        acc = {"bufferView": len(new["bufferViews"]) - 1, "componentType": ctype, "count": len(arr), "type": kind}
        if kind == "VEC3" and len(arr):
            acc["min"], acc["max"] = arr.min(0).tolist(), arr.max(0).tolist()
        new["accessors"].append(acc)
        return len(new["accessors"]) - 1

    new.setdefault("bufferViews", [])
    new.setdefault("accessors", [])
    if not own_bin:  # the file's own buffers move up by one
        for v in new["bufferViews"]:
            v["buffer"] += 1
    for m, mesh in enumerate(tree.get("meshes") or []):
        for p, prim in enumerate(mesh.get("primitives") or []):
            if prim.get("mode", 4) not in _TRIANGLES:
                continue
            where = f"meshes[{m}].primitives[{p}]"
            attrs = prim.get("attributes") or {}
            acc = tree["accessors"]
            dec = src.draco(where, prim) if DRACO in (prim.get("extensions") or {}) else {}

            def values(name, i):
                if name in dec and len(dec[name]) != acc[i]["count"]:
                    raise error(f"{where}.attributes.{name}", f"{where}: {DRACO}: its Draco data holds "
                                                              f"{len(dec[name]):,} {name} values but accessors[{i}] "
                                                              f"declares {acc[i]['count']:,}", DRACO_HINT)
                return dequantize(src.accessor(i, dec.get(name)), acc[i].get("normalized", False))

            out = new["meshes"][m]["primitives"][p]
            plain = {"POSITION": add(values("POSITION", attrs["POSITION"]), 5126, "VEC3")}
            info = _base_colour_info(tree, prim)
            k = _uv_set(info) if info is not None else 0
            if f"TEXCOORD_{k}" in attrs:
                uv = values(f"TEXCOORD_{k}", attrs[f"TEXCOORD_{k}"])[:, :2]
                ext = ((info or {}).get("extensions") or {}).get(TRANSFORM)
                try:
                    moved = texture_transform(uv, ext) if ext else uv
                except ValueError as e:
                    field = (f"materials[{prim.get('material')}].pbrMetallicRoughness.baseColorTexture.extensions."
                             f"{TRANSFORM}")
                    raise error(field, f"{where}: its base-colour texture's {TRANSFORM}: {e}",
                                "export the car again (the glTF is corrupt)") from None
                plain["TEXCOORD_0"] = add(moved, 5126, "VEC2")
            elif info is not None and k != 0:
                raise error(f"{where}.attributes", f"{where}: its base-colour texture reads TEXCOORD_{k} "
                                                   f"(texCoord {k}), which the primitive does not have",
                            "export the car again (the glTF is corrupt)")
            if "COLOR_0" in attrs:
                c = acc[attrs["COLOR_0"]]
                plain["COLOR_0"] = add(values("COLOR_0", attrs["COLOR_0"]), 5126, c["type"])
            out["attributes"] = plain
            if "indices" in prim:
                idx = src.accessor(prim["indices"], dec.get("indices")).reshape(-1)
                out["indices"] = add(idx.astype(np.int64), 5125, "SCALAR")
            out.pop("targets", None)
            (out.get("extensions") or {}).pop(DRACO, None)
    for k in _wrapped(tree):
        new["materials"][k]["name"] = f"{WRAP_TAG}{k}"
    for mat in new.get("materials") or []:
        info = (mat.get("pbrMetallicRoughness") or {}).get("baseColorTexture") if isinstance(mat, dict) else None
        if isinstance(info, dict):
            info.pop("texCoord", None)
            (info.get("extensions") or {}).pop(TRANSFORM, None)
    blob.extend(b"\0" * (-len(blob) % 4))
    if own_bin:
        new["buffers"][0]["byteLength"] = len(blob)
    else:
        new["buffers"] = [{"byteLength": len(blob)}, *new.get("buffers", [])]
    # a Draco extension no primitive holds any more is neither used nor required
    for key in ("extensionsRequired", "extensionsUsed"):
        if key in new and not _uses_draco(new):
            new[key] = [e for e in new[key] if e != DRACO]
    text = json.dumps(new).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), glb.JSON_CHUNK) + text + struct.pack("<II", len(blob), glb.BIN_CHUNK) \
        + bytes(blob)
    return glb.MAGIC + struct.pack("<II", glb.VERSION, glb.HEADER_BYTES + len(body)) + body
