"""glTF 2.0 Gaussian splats (``KHR_gaussian_splatting``, .glb or .gltf) read as the raw INRIA values of
``core.splats.gaussians.GaussianPly`` (``format`` = "gltf_splats"), turned from glTF's +Y up to the import's +Z up.

The extension (KhronosGroup/glTF ``extensions/2.0/Khronos/KHR_gaussian_splatting``; playcanvas/splat-transform
``src/lib/writers/write-glb.ts`` writes it): a mesh primitive (mode 0, points) carrying
``extensions.KHR_gaussian_splatting`` and the attributes

* ``POSITION`` (VEC3): the means;
* ``KHR_gaussian_splatting:ROTATION`` (VEC4, x y z w: glTF's quaternion order, INRIA's is w x y z);
* ``KHR_gaussian_splatting:SCALE`` (VEC3): σ itself (linear; read as log σ, with log 1e-30 for 0 as ``encode``);
* ``KHR_gaussian_splatting:OPACITY`` (SCALAR) in [0, 1] (read as its logit, clamped to (1e-7, 1 - 1e-7));
* ``KHR_gaussian_splatting:SH_DEGREE_l_COEF_n`` (VEC3, r g b) for l = 0..3, n = 0..2l: SH coefficient l² + n
  (``SH_DEGREE_0_COEF_0`` is f_dc). Without it, ``COLOR_0``'s rgb is taken as 0.5 + SH_C0 f_dc.

Accessors may be float or integer (``normalized`` as glTF defines it; ``KHR_mesh_quantization``), interleaved
(``byteStride``), in the GLB's BIN chunk, a ``data:`` URI or a file beside the model (percent-decoded, inside its
folder). Every offset, stride and count is checked against the bytes before an array is made. Refused by name:
sparse accessors, any ``extensionsRequired`` not read here (meshopt, Draco, SPZ-compressed splats...), a node
transform that mirrors or flattens (determinant <= 0: the extension leaves negative scales undefined).

Frames: node transforms (matrix or TRS, parents first) are applied, then glTF's +Y up is turned to +Z up with
``Y_UP_TO_Z_UP`` ((x, y, z) -> (x, -z, y), what Blender's glTF importer and the mesh-car import do), so a glTF car
stands as its mesh export would: means by the whole affine map L x + t; covariances Σ' = L Σ Lᵀ (Khronos README,
"Splat Reconstruction"): for a rotation times a uniform scale, quaternions by its rotation and log σ plus the log
of its scale; for any other L (a non-uniform scale, a shear) each Σ' is decomposed again (``_general_linear``);
SH degree >= 1 coefficients rotated by L's rotation (its polar factor, ``sh_rotation``), as the README says. A glTF with no
``KHR_gaussian_splatting`` primitive is a mesh (``has_gaussian_splatting``), converted like other mesh cars.

No bpy, no torch: numpy only.

(Over 400 lines: a glTF's accessors, views, buffers and node tree must each be bounds-checked before an
array is made, and that reader is this format's alone; the splat attributes and their frames follow it.)
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import urllib.parse

import numpy as np

from .. import glb
from ..geometry import cameras
from .gaussians import GaussianPly, SplatsError, open_file, read_bytes, sh_basis
from .sh import SH_C0

EXTENSION = "KHR_gaussian_splatting"
#: p_zup = Y_UP_TO_Z_UP @ p_gltf (``core.geometry.cameras``, where the axis conventions live)
Y_UP_TO_Z_UP = cameras.Y_UP_TO_Z_UP
#: Required extensions a splat glTF may list and still be read here.
READ_EXTENSIONS = (EXTENSION, "KHR_mesh_quantization")
_COMPONENTS = {5120: np.dtype("i1"), 5121: np.dtype("u1"), 5122: np.dtype("<i2"), 5123: np.dtype("<u2"),
               5125: np.dtype("<u4"), 5126: np.dtype("<f4")}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_OPACITY_EPS = 1e-7
_MIN_SCALE = 1e-30
#: How far a node's linear map's singular values may be from their geometric mean (relative) for it to be taken as a
#: rotation times a uniform scale (the exact fast path); beyond, each covariance is decomposed again.
_SIMILARITY_TOLERANCE = 1e-4


def has_gaussian_splatting(tree: dict) -> bool:
    """True when a parsed glTF lists ``KHR_gaussian_splatting`` or has a primitive carrying it."""
    if not isinstance(tree, dict):
        return False
    if EXTENSION in _as_list(tree.get("extensionsUsed")):
        return True
    for mesh in _as_list(tree.get("meshes")):
        for prim in _as_list(mesh.get("primitives")) if isinstance(mesh, dict) else ():
            if isinstance(prim, dict) and isinstance(prim.get("extensions"), dict) and EXTENSION in prim["extensions"]:
                return True
    return False


def _as_list(value) -> list:
    """``value`` when it is a JSON list, else an empty list (a damaged field is judged where it is read)."""
    return value if isinstance(value, list) else []


def read_tree(path: str | os.PathLike, data: bytes | None = None) -> tuple[dict, bytes | None]:
    """(glTF JSON dict, GLB BIN chunk or None) of a .glb (by its magic) or a .gltf (JSON); SplatsError if neither."""
    path = os.fspath(path)
    if data is None:
        data = read_bytes(path)
    bin_chunk = None
    if data.startswith(glb.MAGIC):
        container = glb.Glb(data)
        for problem in container.problems:  # a header length past the file's end is tolerated: read what is there
            if problem.code == glb.SHORT:
                raise SplatsError(path, "a GLB shorter than its 20-byte header: truncated", "header")
            if problem.code == glb.BAD_VERSION:
                raise SplatsError(path, f"GLB version {problem.claimed}: only glTF 2.0 is read", "header")
        chunks = []
        for chunk in container.chunks():
            problem = container.problem(chunk)  # past the header's length but in the file: tolerated
            if problem is not None and problem.code == glb.CHUNK_PAST_END:
                raise SplatsError(path, f"GLB chunk at byte {chunk.at} claims {chunk.length:,} bytes, the file ends "
                                        f"at {container.size:,}: truncated", "chunks")
            chunks.append(chunk)
        if any(p.code == glb.NO_JSON_FIRST for p in glb.order_problems(chunks)):
            raise SplatsError(path, "a GLB without its JSON chunk first", "chunks")
        text = container.data_of(chunks[0])
        # a BIN chunk out of its place (second) is tolerated: the first one after the JSON
        bin_chunk = next((container.data_of(c) for c in chunks[1:] if c.kind == glb.BIN_CHUNK), None)
    else:
        text = data
    try:
        tree = json.loads(text.decode("utf-8-sig"))
    except (UnicodeDecodeError, ValueError, RecursionError) as e:
        raise SplatsError(path, f"not a glTF: its JSON does not parse ({e})", "json") from None
    if not isinstance(tree, dict) or not isinstance(tree.get("asset"), dict):
        raise SplatsError(path, "not a glTF: its JSON has no 'asset' object", "asset")
    return tree, bin_chunk


def peek_tree(path: str | os.PathLike) -> dict:
    """A glTF's JSON without reading a GLB's binary chunk (to tell splats from meshes cheaply); SplatsError as
    ``read_tree``."""
    path = os.fspath(path)
    try:
        with open_file(path) as f:
            size = os.fstat(f.fileno()).st_size
            data = f.read(glb.MIN_BYTES)  # the header and the JSON chunk's header: then the JSON chunk alone
            if data.startswith(glb.MAGIC) and len(data) == glb.MIN_BYTES:
                json_size = glb.Glb(data).chunk_at(glb.HEADER_BYTES).length
                data += f.read(min(json_size, max(0, size - glb.MIN_BYTES)))
            else:
                data += f.read()
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None
    return read_tree(path, data)[0]


def read(path: str | os.PathLike) -> GaussianPly:
    """Read a ``KHR_gaussian_splatting`` glTF/GLB (module docstring) as raw INRIA values in +Z up; SplatsError
    naming the file and the glTF field if unusable."""
    path = os.fspath(path)
    tree, bin_chunk = read_tree(path)
    required = tree.get("extensionsRequired") or []
    if not isinstance(required, list) or not all(isinstance(e, str) for e in required):
        raise SplatsError(path, f"extensionsRequired is {json.dumps(required)[:60]}, not a list of extension names",
                          "extensionsRequired")
    unread = [e for e in required if e not in READ_EXTENSIONS]
    if unread:
        raise SplatsError(path, f"requires glTF extensions {unread}, which are not read here (only "
                                f"{list(READ_EXTENSIONS)}): export the splats again without compression "
                                "(e.g. splat-transform IN OUT.glb), or as .ply / .spz", "extensionsRequired")
    g = _Gltf(path, tree, bin_chunk)
    parts = []
    for world, mesh_index, node_field in g.mesh_nodes():
        mesh = g.item("meshes", mesh_index, node_field + ".mesh")
        for j, prim in enumerate(g.list(mesh, "primitives", f"meshes[{mesh_index}].primitives")):
            if isinstance(prim, dict) and isinstance(prim.get("extensions"), dict) \
                    and EXTENSION in prim["extensions"]:
                parts.append(_primitive(g, prim, f"meshes[{mesh_index}].primitives[{j}]", world, node_field))
    if not parts:
        raise SplatsError(path, f"no mesh primitive in its scene carries {EXTENSION}: a mesh, not Gaussian splats",
                          "meshes")
    degree = max(p.sh_degree for p in parts)
    for p in parts:  # primitives of lower SH degree get zero higher coefficients
        if p.sh_degree < degree:
            pad = np.zeros((len(p), 3, (degree + 1) ** 2 - 1), np.float32)
            pad[:, :, :p.f_rest.shape[2]] = p.f_rest
            p.f_rest = pad
    cat = {k: np.concatenate([getattr(p, k) for p in parts]) for k in ("xyz", "f_dc", "f_rest", "opacity",
                                                                      "scale", "rot")}
    return GaussianPly(**cat, format="gltf_splats")


class _Gltf:
    """Bounds-checked access to a parsed glTF's buffers, views, accessors and nodes."""

    def __init__(self, path, tree, bin_chunk):
        self.path, self.tree, self.bin_chunk, self._buffers = path, tree, bin_chunk, {}

    def fail(self, field, message):
        return SplatsError(self.path, f"{field}: {message}", field)

    def list(self, node: dict, key: str, field: str) -> list:
        """``node[key]``, a JSON list (absent: empty); SplatsError naming ``field`` when it is something else."""
        value = node.get(key) or []
        if not isinstance(value, list):
            raise self.fail(field, f"is {json.dumps(value)[:60]}, not a list")
        return value

    def item(self, key, index, field):
        items = self.tree.get(key)
        if not isinstance(items, list) or isinstance(index, bool) or not isinstance(index, int) \
                or not 0 <= index < len(items) or not isinstance(items[index], dict):
            raise self.fail(field, f"names {key}[{index!r}], which the file does not have")
        return items[index]

    def buffer(self, index, field) -> bytes:
        if index in self._buffers:
            return self._buffers[index]
        b = self.item("buffers", index, field)
        uri = b.get("uri")
        if uri is None:
            if index != 0 or self.bin_chunk is None:
                raise self.fail(f"buffers[{index}]", "has no uri and there is no GLB BIN chunk")
            data = self.bin_chunk
        elif not isinstance(uri, str):
            raise self.fail(f"buffers[{index}].uri", "is not a string")
        elif uri.startswith("data:"):
            try:
                data = base64.b64decode(uri.split(",", 1)[1], validate=True)
            except (IndexError, binascii.Error, ValueError):
                raise self.fail(f"buffers[{index}].uri", "is a data: URI that is not base64") from None
        else:
            data = self._external(uri, f"buffers[{index}].uri")
        length = b.get("byteLength")
        if not isinstance(length, int) or isinstance(length, bool) or length < 0 or length > len(data):
            raise self.fail(f"buffers[{index}].byteLength", f"is {length!r}, the data holds {len(data):,} bytes")
        self._buffers[index] = data
        return data

    def _external(self, uri, field) -> bytes:
        """A buffer file named by ``uri``, percent-decoded, inside the model's folder."""
        name = urllib.parse.unquote(uri)
        folder = os.path.dirname(os.path.abspath(self.path))
        full = os.path.normpath(os.path.join(folder, name))
        if "://" in uri or os.path.isabs(name) or os.path.commonpath([folder, full]) != folder:
            raise self.fail(field, f"{uri!r} is outside the model's folder: only files beside it are read")
        try:
            with open_file(full) as f:
                return f.read()
        except SplatsError as e:
            raise self.fail(field, f"{uri!r}: {e.args[0]}") from None
        except OSError as e:
            raise self.fail(field, f"{uri!r} cannot be read: {e}") from None

    def accessor(self, index, field) -> np.ndarray:
        """Accessor ``index`` as float64 (count, width), normalised integers mapped as glTF defines."""
        a = self.item("accessors", index, field)
        af = f"accessors[{index}]"
        if "sparse" in a:
            raise self.fail(f"{af}.sparse", "sparse accessors are not read: export the splats again without them")
        dtype = _COMPONENTS.get(a.get("componentType"))
        width = _WIDTH.get(a.get("type"))
        count = a.get("count")
        if dtype is None or width is None:
            raise self.fail(af, f"componentType {a.get('componentType')!r} / type {a.get('type')!r} is no "
                                "glTF vertex attribute")
        if not isinstance(count, int) or isinstance(count, bool) or count < 0:
            raise self.fail(f"{af}.count", f"is {count!r}, not a count")
        elem = dtype.itemsize * width
        if "bufferView" not in a:
            out = np.zeros((count, width))
        else:
            v = self.item("bufferViews", a["bufferView"], f"{af}.bufferView")
            vf = f"bufferViews[{a['bufferView']}]"
            data = self.buffer(v.get("buffer"), f"{vf}.buffer")
            v_off, v_len = v.get("byteOffset", 0), v.get("byteLength")
            a_off, stride = a.get("byteOffset", 0), v.get("byteStride") or elem
            for name, x in (("byteOffset", v_off), ("byteLength", v_len), ("byteStride", stride)):
                if not isinstance(x, int) or isinstance(x, bool) or x < 0:
                    raise self.fail(f"{vf}.{name}", f"is {x!r}, not a byte count")
            if not isinstance(a_off, int) or isinstance(a_off, bool) or a_off < 0:
                raise self.fail(f"{af}.byteOffset", f"is {a_off!r}, not a byte count")
            if v_off + v_len > len(data):
                raise self.fail(vf, f"bytes {v_off:,}-{v_off + v_len:,} lie beyond its buffer ({len(data):,} bytes)")
            if stride < elem:
                raise self.fail(f"{vf}.byteStride", f"{stride} is less than the element's {elem} bytes")
            need = a_off + (stride * (count - 1) + elem if count else 0)
            if need > v_len:
                raise self.fail(af, f"{count:,} elements of {elem} bytes every {stride} from byte {a_off} need "
                                    f"{need:,} bytes, its view holds {v_len:,}")
            raw = np.ndarray((count, width), dtype, data, v_off + a_off, (stride, dtype.itemsize))
            out = raw.astype(np.float64)
            if a.get("normalized") and dtype.kind in "iu":
                top = float(np.iinfo(dtype).max)
                out = out / top if dtype.kind == "u" else np.maximum(out / top, -1.0)
        return out

    def mesh_nodes(self):
        """(world matrix 4×4, mesh index, node field) for every node with a mesh in the default scene (every
        root node's tree when the file names no scene), parents' transforms applied."""
        tree, nodes = self.tree, _as_list(self.tree.get("nodes"))
        scenes = tree.get("scenes")
        if isinstance(scenes, list) and scenes:
            scene = self.item("scenes", tree.get("scene", 0), "scene")
            roots = self.list(scene, "nodes", f"scenes[{tree.get('scene', 0)}].nodes")
        else:  # no scene: every node no other node names as a child
            children = {c for n in nodes if isinstance(n, dict) for c in (n.get("children") or ())
                        if isinstance(c, int)}
            roots = [i for i in range(len(nodes)) if i not in children]
        stack, seen, out = [(r, np.eye(4)) for r in reversed(roots)], set(), []
        while stack:
            i, parent = stack.pop()
            field = f"nodes[{i}]"
            node = self.item("nodes", i, field)
            if i in seen:
                raise self.fail(field, "is reached twice: the node hierarchy has a cycle or a shared child")
            seen.add(i)
            world = parent @ self._local(node, field)
            if "mesh" in node:
                out.append((world, node["mesh"], field))
            stack.extend((c, world) for c in reversed(self.list(node, "children", field + ".children")))
        return out

    def _local(self, node, field) -> np.ndarray:
        try:
            if "matrix" in node:
                m = np.asarray(node["matrix"], np.float64)
                if m.shape != (16,):
                    raise ValueError
                return m.reshape(4, 4).T  # column-major
            m = np.eye(4)
            q = np.asarray(node.get("rotation", [0, 0, 0, 1]), np.float64)
            s = np.asarray(node.get("scale", [1, 1, 1]), np.float64)
            t = np.asarray(node.get("translation", [0, 0, 0]), np.float64)
            if q.shape != (4,) or s.shape != (3,) or t.shape != (3,):
                raise ValueError
            m[:3, :3] = cameras.quaternion_to_rotation(q[[3, 0, 1, 2]]) * s
            m[:3, 3] = t
        except (TypeError, ValueError, OverflowError):
            raise self.fail(field, "has a matrix / translation / rotation / scale that is not glTF's 16 / 3 / 4 / 3 "
                                   "numbers (or a zero rotation)") from None
        if not np.isfinite(m).all():
            raise self.fail(field, "has a non-finite transform")
        return m


def _polar(linear, path, field):
    """(R rotation 3×3, s uniform scale or None) of a linear map L = R P (polar decomposition, P symmetric positive
    definite): s when P is s times the identity (within ``_SIMILARITY_TOLERANCE``), None for any other P. SplatsError
    naming ``field`` for a determinant <= 0 (a mirror or a flattening: the extension leaves them undefined)."""
    linear = np.asarray(linear, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):  # a product of huge node scales: not finite, refused
        det = float(np.linalg.det(linear)) if np.isfinite(linear).all() else float("nan")
    if not (det > 0 and np.isfinite(det)):
        why = "mirrors or flattens the splats" if np.isfinite(det) else "overflows float64"
        raise SplatsError(path, f"{field}: its transform {why} (determinant {det:.3g}), which KHR_gaussian_splatting "
                                "leaves undefined: apply it to the splats before export, or export without it", field)
    U, S, Vt = np.linalg.svd(linear)
    R = U @ Vt  # det(L) > 0: a rotation
    s = float(np.cbrt(det))
    return R, (s if np.abs(S / s - 1).max() <= _SIMILARITY_TOLERANCE else None)


def _general_linear(linear, q_wxyz, scale):
    """(quaternions (n, 4) w x y z, σ (n, 3)) of Σ' = L Σ Lᵀ for Gaussians of Σ = R(q) diag(σ²) R(q)ᵀ and any
    invertible L (3, 3): the eigen-decomposition of each Σ' (float64), eigenvector columns made a right-handed
    rotation. The reference is the product itself (tested): a Gaussian mapped by L is exactly the Gaussian of Σ'.
    Rows that decoding drops (a non-finite value, a zero quaternion, a negative σ) come back NaN: dropped still."""
    q = np.asarray(q_wxyz, np.float64)
    scale = np.asarray(scale, np.float64)
    ok = np.isfinite(q).all(1) & (np.linalg.norm(q, axis=1) >= 1e-12) & np.isfinite(scale).all(1) & \
        (scale >= 0).all(1)
    q_out, sigma = np.full((len(q), 4), np.nan), np.full((len(q), 3), np.nan)
    C = np.einsum("ij,njk->nik", np.asarray(linear, np.float64),
                  cameras.quaternion_to_rotation(q[ok]) * scale[ok][:, None, :])
    w, V = np.linalg.eigh(C @ np.swapaxes(C, 1, 2))
    V[np.linalg.det(V) < 0, :, 0] *= -1  # eigenvectors up to sign: keep det +1
    q_out[ok], sigma[ok] = cameras.rotation_to_quaternion(V), np.sqrt(np.maximum(w, _MIN_SCALE ** 2))
    return q_out, sigma


def _quat_multiply(a, b) -> np.ndarray:
    """Hamilton products a ⊗ b of (w, x, y, z) quaternions (broadcasting)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def sh_rotation(R: np.ndarray, degree: int) -> np.ndarray:
    """(K, K) matrix M, K = (degree + 1)², with Σ_k (M c)_k Y_k(R d) = Σ_k c_k Y_k(d) for every direction d: SH
    coefficients c (coefficient-major) of a colour in one frame, rotated into the frame p' = R p. Found from the
    basis itself (``gaussians.sh_basis``) at 64 directions by least squares, exact to rounding since each degree's
    span is closed under rotation."""
    K = (degree + 1) ** 2
    d = np.random.default_rng(0).normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    B_new = sh_basis(d, degree)                        # Y(d') at directions d' of the new frame
    B_old = sh_basis(d @ np.asarray(R, np.float64), degree)  # Y(R^T d') in the old frame
    return np.linalg.lstsq(B_new, B_old, rcond=None)[0][:K, :K]


#: The values of the extension's properties the renderer draws as the file means (Khronos README: the ``ellipse``
#: kernel, 3DGS's; colours in sRGB display space, blended before any transfer function, as 3DGS trains; perspective
#: projection). An older draft's file without them means the same. ``sortingMethod`` is the renderer's own choice
#: (it sorts by depth) and is not checked.
KERNELS, COLOR_SPACES, PROJECTIONS = ("ellipse",), ("srgb_rec709_display",), ("perspective",)


def _check_kernel(path, ext, field) -> None:
    """Refuse a primitive's ``KHR_gaussian_splatting`` object whose kernel, colour space or projection is not what
    the renderer draws, naming the property (a linear colour space would be read as sRGB: every colour wrong)."""
    if not isinstance(ext, dict):
        raise SplatsError(path, f"{field} is {json.dumps(ext)[:60]}, not an object", field)
    for key, known, why in (("kernel", KERNELS, "the renderer draws 3D Gaussian ellipsoids (3DGS's kernel)"),
                            ("colorSpace", COLOR_SPACES, "the renderer blends colours in sRGB display space, as 3DGS "
                                                         "trains; a linear field would need blending before the "
                                                         "transfer function"),
                            ("projection", PROJECTIONS, "the renderer projects Gaussians with a perspective camera")):
        value = ext.get(key, known[0])
        if value not in known:
            raise SplatsError(path, f"{field}.{key} is {json.dumps(value)[:60]}, not {' or '.join(known)}: {why}",
                              f"{field}.{key}")


def _primitive(g: _Gltf, prim, field, world, node_field) -> GaussianPly:
    attrs = prim.get("attributes") or {}
    path = g.path
    if not isinstance(attrs, dict):
        raise SplatsError(path, f"{field}.attributes is {json.dumps(attrs)[:60]}, not an object of accessor indices",
                          f"{field}.attributes")

    def get(name, width, required=True):
        if name not in attrs:
            if required:
                raise SplatsError(path, f"{field}.attributes: {name} is missing (every {EXTENSION} primitive has "
                                        "POSITION, ROTATION, SCALE, OPACITY and a colour)", f"{field}.attributes")
            return None
        a = g.accessor(attrs[name], f"{field}.attributes.{name}")
        if a.shape[1] < width:
            raise SplatsError(path, f"{field}.attributes.{name} has {a.shape[1]} components, {width} needed",
                              f"{field}.attributes.{name}")
        return a[:, :width]

    _check_kernel(path, prim["extensions"][EXTENSION], f"{field}.extensions.{EXTENSION}")
    pfx = EXTENSION + ":"
    xyz = get("POSITION", 3)
    n = len(xyz)
    rot_xyzw, scale, opacity = get(pfx + "ROTATION", 4), get(pfx + "SCALE", 3), get(pfx + "OPACITY", 1)[:, 0]
    dc = get(pfx + "SH_DEGREE_0_COEF_0", 3, required=False)
    if dc is None:
        color = get("COLOR_0", 3, required=False)
        if color is None:
            raise SplatsError(path, f"{field}.attributes: neither {pfx}SH_DEGREE_0_COEF_0 nor COLOR_0: no colour",
                              f"{field}.attributes")
        dc = (color - 0.5) / SH_C0
    degree, coeffs = 0, [dc]
    for d in (1, 2, 3):
        names = [f"{pfx}SH_DEGREE_{d}_COEF_{c}" for c in range(2 * d + 1)]
        present = [nm in attrs for nm in names]
        if not any(present):
            break
        if not all(present):
            raise SplatsError(path, f"{field}.attributes: SH degree {d} needs {names}, missing "
                                    f"{[nm for nm, p in zip(names, present) if not p]}", f"{field}.attributes")
        coeffs += [get(nm, 3) for nm in names]
        degree = d
    for name, a in (("ROTATION", rot_xyzw), ("SCALE", scale), ("OPACITY", opacity)):
        if len(a) != n:
            raise SplatsError(path, f"{field}.attributes.{pfx}{name} has {len(a):,} elements, POSITION {n:,}",
                              f"{field}.attributes")
    if any(len(c) != n for c in coeffs):
        raise SplatsError(path, f"{field}.attributes: an SH attribute's count differs from POSITION's {n:,}",
                          f"{field}.attributes")
    sh = np.stack(coeffs, axis=1)  # (n, K, 3) coefficient-major
    M = np.eye(4)
    M[:3, :3] = Y_UP_TO_Z_UP
    M = M @ world
    R, s = _polar(M[:3, :3], path, node_field)
    xyz = xyz @ M[:3, :3].T + M[:3, 3]
    if degree:
        sh[:, 1:] = np.einsum("kj,njc->nkc", sh_rotation(R, degree)[1:, 1:], sh[:, 1:])
    with np.errstate(divide="ignore", invalid="ignore"):  # negative σ or opacity: NaN, dropped on decoding
        if s is not None:
            q = _quat_multiply(cameras.rotation_to_quaternion(R), rot_xyzw[:, [3, 0, 1, 2]])
            log_scale = np.log(np.where(scale == 0, _MIN_SCALE, scale)) + np.log(s)
        else:
            q, sigma = _general_linear(M[:3, :3], rot_xyzw[:, [3, 0, 1, 2]], scale)
            log_scale = np.log(sigma)
        o = np.clip(opacity, _OPACITY_EPS, 1 - _OPACITY_EPS)
        logit = np.log(o / (1 - o))
    return GaussianPly(xyz=xyz.astype(np.float32), f_dc=sh[:, 0].astype(np.float32),
                       f_rest=np.ascontiguousarray(np.swapaxes(sh[:, 1:], 1, 2)).astype(np.float32),
                       opacity=logit.astype(np.float32), scale=log_scale.astype(np.float32),
                       rot=q.astype(np.float32), format="gltf_splats")
