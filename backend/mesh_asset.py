"""Car meshes as Gaussian assets: load with trimesh, sample the surface, one flat Gaussian per sample.

Frames and units
----------------
* Output: Z up, right-handed, in the mesh's own units (glTF: metres), the file's origin kept (the Blender import
  puts its data-frame origin at the bottom centre of the means anyway).
* glTF / GLB are +Y up by the glTF 2.0 specification; Blender's glTF importer maps (x, y, z)_gltf to
  (x, -z, y)_blender. OBJ has no stated axes; +Y up is the convention (and Blender's OBJ importer default), so it
  is read the same way. PLY, STL and OFF are read as stored (Z up). ``up="y"``/``"z"`` override the choice:

      p_zup = Y_UP_TO_Z_UP @ p_file = (x, -z, y)      (a +90° turn about X; Y_UP_TO_Z_UP = [[1,0,0],[0,0,-1],[0,1,0]])

* Scenes (glTF nodes, OBJ groups) are flattened: every geometry instance moved by its node's world transform
  (``trimesh.Scene.dump``), then turned to Z up. Parts keep their own materials; they are sampled together, by area.
* TRELLIS (microsoft/TRELLIS): ``trellis/utils/postprocessing_utils.py:to_glb`` writes the GLB with
  ``vertices @ [[1,0,0],[0,0,-1],[0,1,0]]``, i.e. (x, z, -y) of TRELLIS's Z-up frame: plain glTF Y-up, so the
  conversion above returns TRELLIS's own Z-up frame. ``trellis/representations/gaussian/gaussian_model.py:save_ply``
  writes its Gaussians as ``xyz @ T.T`` with the same matrix T, i.e. (x, -z, y) (``core.splats.ZUP_TO_TRELLIS_FILE``),
  which the Gaussian import undoes with ``F = ZUP_TO_TRELLIS_FILE.T``. The two files of one TRELLIS asset
  therefore land in the same pose (``tests/backend/test_mesh_asset.py`` builds both and checks it).

Gaussians
---------
Samples are area-weighted and uniform on each triangle (``trimesh.sample.sample_surface`` with explicit face
weights: zero for triangles with zero or non-finite area, so degenerate faces and NaN vertices never produce a
Gaussian). Each sample gets one flat Gaussian:

* rotation R = [t1, t2, n] (columns): local z = the face normal n = normalise((v1 - v0) x (v2 - v0)) (the winding's
  normal, as trimesh's ``face_normals``), t1 = normalise(v1 - v0), t2 = n x t1;
* in-plane standard deviation σ = c · sqrt(A / N) (A the total area, N the count; ``SIGMA_FACTOR`` = c), along the
  normal ``NORMAL_RATIO`` · σ (flat, but > 0 so Σ stays invertible);
* opacity ``OPACITY``; colour as the SH degree-0 term f_dc = (rgb - 0.5) / C0, rgb sRGB-encoded in [0, 1] (the
  values 3DGS renders and the condition images hold).

Choice of c (``bench/mesh_assets.py``, bench/results/mesh_assets.json). With N/A samples per unit area, the summed
weight Σ o exp(-r²/2σ²) of the Gaussians at a point of the surface is 2π c² o on average, so one layer lets through
about a transmittance of exp(-2π c² o) and a closed surface (two layers on every line of sight) exp(-4π c² o); past a free edge
the mask falls to 0.5 at the distance d where Φ(-d/σ) = ln 2 / (2π c² o). c ≈ 0.5 puts that edge on the outline but
leaves the car a few per cent transparent; c = 1 closes it and moves the edge out by 1.2 σ. Measured on close-ups
(the car 80 % of a 1024 x 576 frame's height) of the procedural car and two real TRELLIS GLBs: c = 0.5 has the
least mean |M_a - silhouette| but shows the background through the car (leak 1.5 % at 20 k Gaussians, speckles to
the eye); c = 0.6 keeps the leak at or under 0.5 % for 20 k and 0.1 % for 200 k at a mask error 0.001-0.014
higher; c >= 0.7 only widens the outline. ``DEFAULT_COUNT`` = 200 k is where those close-ups stop improving
(σ ≈ 0.6-0.9 px, the size of the renderer's own 0.3 px² blur: beyond it more Gaussians only pile blur past the
outline).

Colours (``colour_source``): "texture" (base-colour texture, bilinear at the sample's UV, glTF conventions: texel
centres at (i + 0.5) / size, REPEAT wrap, V as trimesh stores it, i.e. v = 1 at the top row), "vertex" (vertex
colours interpolated barycentrically), "face" (face colours, or the material's base colour when it has no
texture), "none" (nothing in the file: ``NEUTRAL_GREY``). glTF's baseColorFactor and COLOR_0 are linear by the
specification: they are applied in linear light and re-encoded to sRGB; textures and every other format's
colours are taken as sRGB values. Alpha is ignored: car assets are drawn opaque.
trimesh 5.2.0's own ``sample_surface(sample_color=True)`` is not used: it reads ``material.image``, which a
``PBRMaterial`` (every GLB, TRELLIS's included) does not have, and it takes face colours for vertex colours.

Stage-1 size: an upright oriented box (yaw only, Z kept up): ``trimesh.bounds.oriented_bounds_2D`` of the
vertices' horizontal projection gives (length, width) and the yaw, the z range the height. The box follows the
project's box convention (length along the box's local +Y, DESIGN "Removal boxes"): its length axis is
(-sin θ, cos θ, 0), θ in (-90°, 90°]. ``trimesh.bounds.oriented_bounds`` gives the full 3D box for the report.

No bpy. torch only in ``render_mask`` (the evaluation helper).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from scpainter_blender.core import cameras, files, shapes, splats
from scpainter_blender.core.colors import linear_to_srgb, srgb_to_linear

#: p_zup = Y_UP_TO_Z_UP @ p for Y-up files: (x, y, z) -> (x, -z, y), Blender's glTF import.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: File extension -> the up axis ``up="auto"`` assumes.
UP_BY_EXTENSION = {".glb": "y", ".gltf": "y", ".obj": "y", ".ply": "z", ".stl": "z", ".off": "z"}
MESH_EXTENSIONS = tuple(UP_BY_EXTENSION)

SIGMA_FACTOR = 0.6       # c in σ = c sqrt(A / N); see "Choice of c" above
NORMAL_RATIO = 1e-3      # σ along the normal / σ in the plane
OPACITY = 0.99
NEUTRAL_GREY = 0.5       # sRGB value for meshes without any colour (f_dc = 0)
DEFAULT_COUNT = 200_000
MAX_COUNT = 10_000_000


class MeshAssetError(files.InputError):
    """A mesh file that cannot be made into Gaussians; the message names the file and what to do. ``field``: the
    part of the file at fault ("(file)" for the file as a whole; an element, or a texture/buffer the file names)."""

    def __init__(self, path, message, field=None, hint=None):
        files.InputError.__init__(self, path, field, message, hint)
        self.args = (f"{os.path.basename(self.path)}: {message} ({self.path})",)  # the text it has always had


def _file_error(path, field, message):
    """``files``' error callback: its messages as MeshAssetError."""
    return MeshAssetError(path, "file not found" if message == "not found" else message, field)


@dataclass
class MeshAsset:
    """A mesh file read into Z-up parts.

    ``parts``: ``trimesh.Trimesh`` objects in the Z-up output frame, node transforms applied, each with its own
    visual (texture / colours); ``up``: the axis read as up in the file ("y" or "z"); ``gltf``: colours follow
    glTF's rules (linear factors and vertex colours).
    """

    path: str
    parts: list
    up: str
    gltf: bool = False

    @property
    def vertices(self) -> np.ndarray:
        """(V, 3) float64: every part's vertices, concatenated."""
        return np.concatenate([np.asarray(p.vertices, np.float64) for p in self.parts]) if self.parts \
            else np.zeros((0, 3))

    @property
    def faces(self) -> np.ndarray:
        """(F, 3) int64 into ``vertices``."""
        out, base = [], 0
        for p in self.parts:
            out.append(np.asarray(p.faces, np.int64) + base)
            base += len(p.vertices)
        return np.concatenate(out) if out else np.zeros((0, 3), np.int64)


@dataclass
class MeshGaussians:
    """``mesh_to_gaussians``' result with what the command reports: total ``area`` (units²), ``sigma`` (in-plane σ,
    units), ``colour_source`` (the source of most samples) and ``colour_counts`` (samples per source),
    ``dropped`` (samples left out for non-finite values: normally none)."""

    gaussians: splats.Gaussians
    area: float
    sigma: float
    colour_source: str
    colour_counts: dict = field(default_factory=dict)
    dropped: int = 0


# --------------------------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------------------------

def _check_ply(path, size: int) -> None:
    """Refuse, before trimesh reads it, a PLY that holds Gaussians, or whose header promises more than the file
    holds (trimesh would allocate what the counts claim). A header our parser cannot read is left to trimesh,
    which reads more PLY dialects and says what it thinks is wrong."""
    try:
        fmt, elements, start = splats.read_ply_header(path)
    except splats.SplatsError:
        return
    vertex = next((props for name, _, props in elements if name == "vertex"), [])
    names = {p for p, _ in vertex}
    if "f_dc_0" in names or {"scale_0", "rot_0"} <= names or "packed_position" in names:
        raise MeshAssetError(path, "this is a Gaussian-splat PLY, not a mesh: import it as Gaussians directly")
    binary = fmt in ("binary_little_endian", "binary_big_endian")
    for name, count, props in elements:
        # the fewest bytes a row can take: its fixed properties, each list's count; ASCII: one digit and a space each
        least = sum(np.dtype(t).itemsize if t is not None else 1 for _, t in props) if binary else 2 * len(props)
        if count * least > size - start:
            raise MeshAssetError(path, f"the header promises {count} {name} rows (at least {count * least:,} bytes) "
                                       f"but the file has {size - start:,} bytes after it: truncated or corrupt", name)


def _regular_resolver(path):
    """trimesh's resolver for the files a mesh names (glTF buffers and images, OBJ materials and textures), opening
    only regular files: a FIFO named as a texture would block the read forever. trimesh swallows some of its
    resolver's errors (a texture it cannot read is dropped), so each refusal is also kept in ``.refused`` for the
    caller to raise."""
    from trimesh import resolvers

    refused = []

    class RegularFiles(resolvers.FilePathResolver):
        def get(self, name):
            for candidate in (name.strip(), name.strip().lstrip("/"), os.path.split(name)[-1]):
                try:
                    where = self.absolute(candidate)  # trimesh keeps names inside the mesh's folder
                except ValueError:
                    continue
                if os.path.lexists(where):
                    def error(p, f, m):
                        refused.append(MeshAssetError(path, f"{name!r} (named by the mesh) {m}", name,
                                                      hint="replace it with the file itself"))
                        return refused[-1]

                    with files.open_regular(where, error) as f:
                        return f.read()
            return super().get(name)

        def namespaced(self, namespace):
            child = RegularFiles(os.path.join(self.parent, namespace), allow_anywhere=self.allow_anywhere)
            child.refused = refused
            return child

    resolver = RegularFiles(path)
    resolver.refused = refused
    return resolver


def load_mesh(path, up: str = "auto") -> MeshAsset:
    """Read a mesh file (GLB, glTF, OBJ, PLY, STL, OFF) into Z-up parts (see the module docstring).

    ``up``: "auto" (by extension: glTF/GLB/OBJ Y up, the rest Z up), "y" or "z". Raises ``MeshAssetError``
    (an InputError naming the file) for a missing or unreadable file, an unsupported format, a Gaussian-splat PLY,
    a point cloud, or a file without triangles.
    """
    import trimesh

    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if up not in ("auto", "y", "z"):
        raise ValueError(f"up must be 'auto', 'y' or 'z', got {up!r}")
    size = files.check_regular(path, _file_error)  # trimesh opens by name: a FIFO would block it forever
    if ext not in UP_BY_EXTENSION:
        raise MeshAssetError(path, f"{ext or 'no extension'} is not a mesh format read here: export the car as "
                                   "GLB, glTF, OBJ, PLY, STL or OFF")
    if size == 0:
        raise MeshAssetError(path, "the file is empty (0 bytes)")
    if ext == ".ply":
        _check_ply(path, size)
    resolver = _regular_resolver(path)
    try:
        scene = trimesh.load(path, force="scene", process=False, resolver=resolver)
        parts = scene.dump()
    except MeshAssetError:
        raise
    except Exception as e:  # trimesh raises anything from struct.error to KeyError on a broken file
        if resolver.refused:
            raise resolver.refused[0] from None
        raise MeshAssetError(path, f"trimesh cannot read it as a mesh ({type(e).__name__}: {e}); check the file "
                                   "opens in Blender, or export it again as GLB") from None
    if resolver.refused:  # trimesh went on without it (a texture): still the user's file to fix
        raise resolver.refused[0]
    meshes = [p for p in parts if isinstance(p, trimesh.Trimesh) and len(p.faces)]
    if not meshes:
        points = sum(len(getattr(p, "vertices", ())) for p in parts)
        what = (f"{points} points but no faces (a point cloud)" if points else "no geometry")
        raise MeshAssetError(path, f"it has {what}: a car asset needs a triangle mesh (or a Gaussian-splat PLY)")
    axis = UP_BY_EXTENSION[ext] if up == "auto" else up
    if axis == "y":
        y_up_to_z_up = np.eye(4)
        y_up_to_z_up[:3, :3] = Y_UP_TO_Z_UP
        for m in meshes:
            m.apply_transform(y_up_to_z_up)
    asset = MeshAsset(path, meshes, axis, gltf=ext in (".glb", ".gltf"))
    if not np.any(_face_areas(asset.vertices, asset.faces) > 0):
        raise MeshAssetError(path, f"its {len(asset.faces)} faces all have zero (or non-finite) area: nothing "
                                   "to sample")
    return asset


def _as_parts(mesh):
    """(list of trimesh.Trimesh, gltf colour rules?) from a MeshAsset, a Trimesh or a sequence of them."""
    if isinstance(mesh, MeshAsset):
        return list(mesh.parts), mesh.gltf
    if isinstance(mesh, (list, tuple)):
        return list(mesh), False
    return [mesh], False


# --------------------------------------------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------------------------------------------

def _face_areas(vertices, faces) -> np.ndarray:
    """(F,) float64 triangle areas; 0 where a corner is not finite."""
    if not len(faces):
        return np.zeros(0)
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    with np.errstate(invalid="ignore", over="ignore"):
        a = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    a[~np.isfinite(a)] = 0.0
    return a


def upright_box(vertices) -> dict:
    """Upright oriented bounding box of points (N, 3), Z up: yaw only.

    Returns ``size`` [length, width, height] (length >= width, horizontal; height the z range), ``yaw_deg`` θ in
    (-90, 90] (the box's rotation about +Z; its length along the box's local +Y, so the length axis is
    (-sin θ, cos θ, 0)), ``center`` [x, y, z], and ``aabb_size`` [length, width, height] of the axis-aligned box for
    comparison. Non-finite points are ignored; degenerate footprints (a line, a point) fall back to PCA axes.
    """
    import trimesh

    v = np.asarray(vertices, np.float64)
    v = v[np.isfinite(v).all(axis=1)]
    if not len(v):
        raise ValueError("upright_box: no finite points")
    xy = v[:, :2]
    try:
        T2, rect = trimesh.bounds.oriented_bounds_2D(xy)
        d = T2[0, :2]                      # the box's long (x after trimesh's flip) axis, in world xy
        centre = -T2[:2, :2].T @ T2[:2, 2]
        length, width = float(rect[0]), float(rect[1])
    except Exception:  # qhull: fewer than 3 points or all on a line
        c = xy.mean(axis=0)
        _, _, vt = np.linalg.svd(xy - c, full_matrices=True)
        d = vt[0]
        proj = (xy - c) @ vt.T
        lo, hi = proj.min(axis=0), proj.max(axis=0)
        length, width = float(hi[0] - lo[0]), float(hi[1] - lo[1])
        centre = c + vt.T @ ((lo + hi) / 2)
    theta = math.degrees(math.atan2(-d[0], d[1]))   # Rz(θ) (0, 1) = (-sin θ, cos θ) = ±d
    theta = (theta + 90.0) % 180.0 - 90.0
    if theta == -90.0:
        theta = 90.0
    zlo, zhi = float(v[:, 2].min()), float(v[:, 2].max())
    ext = v.max(axis=0) - v.min(axis=0)
    return {"size": [length, width, zhi - zlo], "yaw_deg": theta,
            "center": [float(centre[0]), float(centre[1]), (zlo + zhi) / 2],
            "aabb_size": [float(max(ext[0], ext[1])), float(min(ext[0], ext[1])), float(ext[2])]}


def oriented_box_3d(vertices) -> list:
    """Extents (3,), largest first, of trimesh's minimum-volume-ish 3D oriented box (``oriented_bounds``)."""
    import trimesh

    v = np.asarray(vertices, np.float64)
    v = v[np.isfinite(v).all(axis=1)]
    try:
        _, ext = trimesh.bounds.oriented_bounds(v)
    except Exception:  # degenerate (fewer than 4 points, all on a line): the axis-aligned extents
        ext = v.max(axis=0) - v.min(axis=0)
    return sorted((float(e) for e in ext), reverse=True)


# --------------------------------------------------------------------------------------------------------------
# Colours
# --------------------------------------------------------------------------------------------------------------

def sample_texture(image, uv) -> np.ndarray:
    """Bilinear RGB in [0, 1] (n, 3) of an image (PIL image or (H, W[, C]) array, 8 or 16 bit) at trimesh UVs (n, 2).

    glTF sampling: texel (i, j) has its centre at u = (i + 0.5) / W, and trimesh stores v flipped (v = 1 at the
    top row: row = (1 - v) H - 0.5); coordinates wrap (REPEAT). Non-finite UVs give NaN.
    """
    if hasattr(image, "convert"):
        img = np.asarray(image.convert("RGB"), np.float64) / 255.0
    else:
        img = np.asarray(image)
        scale = 65535.0 if img.dtype == np.uint16 else 255.0 if np.issubdtype(img.dtype, np.integer) else 1.0
        img = img.astype(np.float64) / scale
        if img.ndim == 2:
            img = img[..., None]
        img = np.repeat(img[..., :1], 3, axis=2) if img.shape[2] < 3 else img[..., :3]
    H, W = img.shape[:2]
    uv = np.asarray(uv, np.float64)
    ok = np.isfinite(uv).all(axis=1)
    x = np.where(ok, uv[:, 0], 0.0) * W - 0.5
    y = (1.0 - np.where(ok, uv[:, 1], 0.0)) * H - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64) % W, y0.astype(np.int64) % H
    x1, y1 = (x0 + 1) % W, (y0 + 1) % H
    out = ((1 - fx) * (1 - fy) * img[y0, x0] + fx * (1 - fy) * img[y0, x1]
           + (1 - fx) * fy * img[y1, x0] + fx * fy * img[y1, x1])
    out[~ok] = np.nan
    return out


def _factor(value, default=(255, 255, 255, 255)) -> np.ndarray:
    """A material colour (uint8 0..255 or float 0..1, RGB or RGBA) as RGB floats in [0, 1]."""
    c = np.asarray(default if value is None else value)
    c = c.astype(np.float64) / 255.0 if np.issubdtype(c.dtype, np.integer) or c.max() > 1.0 else c.astype(np.float64)
    return np.clip(c.reshape(-1)[:3], 0.0, 1.0)


def _material_colour(material):
    """(base-colour texture or None, base colour factor RGB [0, 1]) of a trimesh material."""
    from trimesh.visual import material as mat

    if isinstance(material, mat.PBRMaterial):
        return material.baseColorTexture, _factor(material.baseColorFactor)
    if isinstance(material, mat.SimpleMaterial):
        return material.image, _factor(material.diffuse)
    image = getattr(material, "image", None) or getattr(material, "baseColorTexture", None)
    try:
        main = material.main_color
    except Exception:
        main = None
    return image, _factor(main)


def _part_colours(part, local_faces, bary, gltf: bool):
    """sRGB RGB (n, 3) in [0, 1] at samples on ``part`` (face indices (n,), barycentric (n, 3)), and the source."""
    from trimesh.visual import ColorVisuals, TextureVisuals

    n = len(local_faces)
    vis = part.visual
    faces = np.asarray(part.faces)[local_faces]
    if isinstance(vis, TextureVisuals):
        image, factor = _material_colour(vis.material)
        uv = None if vis.uv is None else np.asarray(vis.uv, np.float64)
        if image is not None and uv is not None and len(uv) == len(part.vertices):
            tex = sample_texture(image, np.einsum("nk,nkc->nc", bary, uv[faces]))
            # glTF: base colour = texture (sRGB-decoded) x factor (linear); OBJ/MTL: the map replaces Kd
            rgb = linear_to_srgb(srgb_to_linear(tex) * factor) if gltf else tex
            return rgb, "texture"
        rgb = linear_to_srgb(factor) if gltf else factor
        return np.tile(rgb, (n, 1)), "face"
    if isinstance(vis, ColorVisuals) and vis.kind == "vertex":
        vc = np.asarray(vis.vertex_colors, np.float64)[:, :3] / 255.0
        rgb = np.einsum("nk,nkc->nc", bary, vc[faces])
        return (linear_to_srgb(rgb) if gltf else rgb), "vertex"
    if isinstance(vis, ColorVisuals) and vis.kind == "face":
        rgb = np.asarray(vis.face_colors, np.float64)[local_faces, :3] / 255.0
        return (linear_to_srgb(rgb) if gltf else rgb), "face"
    return np.full((n, 3), NEUTRAL_GREY), "none"


# --------------------------------------------------------------------------------------------------------------
# Gaussians
# --------------------------------------------------------------------------------------------------------------

def sample_gaussians(mesh, count: int, seed: int = 0, sigma_factor: float = SIGMA_FACTOR,
                     opacity: float = OPACITY, normal_ratio: float = NORMAL_RATIO) -> MeshGaussians:
    """``count`` flat surface Gaussians of ``mesh`` (a MeshAsset, a trimesh.Trimesh, or a list of them), with
    what the command reports (``MeshGaussians``). See the module docstring for the rules; same seed, same result.

    Raises ValueError when the mesh has no face with a positive finite area (``MeshAssetError`` naming the file
    for a ``MeshAsset``: a file whose areas overflow float64) or ``count`` < 1 (the caller's to check).
    """
    import trimesh

    count = int(count)
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    parts, gltf = _as_parts(mesh)
    verts = [np.asarray(p.vertices, np.float64) for p in parts]
    faces = [np.asarray(p.faces, np.int64) for p in parts]
    offsets = np.cumsum([0] + [len(v) for v in verts])
    face_offsets = np.cumsum([0] + [len(f) for f in faces])
    V = np.concatenate(verts) if verts else np.zeros((0, 3))
    F = np.concatenate([f + o for f, o in zip(faces, offsets[:-1])]) if faces else np.zeros((0, 3), np.int64)
    area = _face_areas(V, F)
    total = float(area.sum())
    if not total > 0 or not math.isfinite(total):
        what = "the mesh has no face with a positive, finite area (in sum): nothing to sample"
        if isinstance(mesh, MeshAsset):  # read from the user's file: bad input, not our bug
            raise MeshAssetError(mesh.path, what, hint="check the mesh's units and that its faces are not all "
                                                       "degenerate")
        raise ValueError(what)
    # geometry only (no visuals, NaN corners replaced: zero-weight faces are never sampled anyway)
    geom = trimesh.Trimesh(np.nan_to_num(V, nan=0.0, posinf=0.0, neginf=0.0), F, process=False, validate=False)
    means, fidx, bary = trimesh.sample.sample_surface(geom, count, face_weight=area, return_barycentric=True,
                                                      seed=seed)
    R = shapes.face_frames(V[F[fidx]])                # columns: local x, y, z in the output frame
    rgb = np.empty((count, 3))
    sources = np.empty(count, object)
    part_of = np.searchsorted(face_offsets, fidx, side="right") - 1
    for k, part in enumerate(parts):
        sel = np.nonzero(part_of == k)[0]
        if len(sel):
            rgb[sel], sources[sel] = _part_colours(part, fidx[sel] - face_offsets[k], bary[sel], gltf)
    rgb = np.clip(rgb, 0.0, 1.0)
    sigma = float(sigma_factor) * math.sqrt(total / count)
    ok = (np.isfinite(means).all(1) & np.isfinite(R).all((1, 2)) & np.isfinite(rgb).all(1) & (area[fidx] > 0))
    quats = np.zeros((count, 4))
    quats[ok] = cameras.rotation_to_quaternion(R[ok])
    m = int(ok.sum())
    sh = ((rgb[ok] - 0.5) / splats.SH_C0)[:, None, :]
    g = splats.Gaussians(means=means[ok].astype(np.float32),
                         scales=np.tile([sigma, sigma, normal_ratio * sigma], (m, 1)).astype(np.float32),
                         quats=quats[ok].astype(np.float32), opacities=np.full(m, opacity, np.float32),
                         sh=sh.astype(np.float32))
    kinds, counts = np.unique(sources[ok].astype(str), return_counts=True) if m else (np.array([]), np.array([]))
    colour_counts = {str(k): int(c) for k, c in zip(kinds, counts)}
    main = max(colour_counts, key=colour_counts.get) if colour_counts else "none"
    return MeshGaussians(g, total, sigma, main, colour_counts, count - m)


def mesh_to_gaussians(mesh, count: int, seed: int = 0, sigma_factor: float = SIGMA_FACTOR) -> splats.Gaussians:
    """``count`` flat Gaussians on the surface of ``mesh`` (MeshAsset, trimesh.Trimesh or a list of them), in the
    mesh's frame and units: means (N, 3), scales (σ, σ, NORMAL_RATIO σ) with σ = sigma_factor sqrt(area / count),
    quaternions whose local z is the face normal, opacity OPACITY, SH degree 0. ValueError for a mesh with no area."""
    return sample_gaussians(mesh, count, seed, sigma_factor).gaussians


# --------------------------------------------------------------------------------------------------------------
# The command
# --------------------------------------------------------------------------------------------------------------

def convert(path, out, count: int = DEFAULT_COUNT, up: str = "auto", seed: int = 0,
            sigma_factor: float = SIGMA_FACTOR, progress=None) -> dict:
    """``python -m backend mesh-asset``: mesh file -> INRIA-layout Gaussian PLY (Z up, the mesh's units, SH 0, no
    normals), written atomically. ``progress(stage, done, total)`` is called between steps. Returns the ``done``
    event's result (see the backend docs). Raises MeshAssetError (the mesh, ``--out``) or ``files.ArgumentError``
    (``--count``) on bad input."""
    progress = progress or (lambda *a: None)
    path, out = os.fspath(path), os.fspath(out)
    if not 1 <= int(count) <= MAX_COUNT:
        raise files.ArgumentError("--count", f"must be between 1 and {MAX_COUNT:,}, got {count}")
    if os.path.exists(out) and os.path.exists(path) and os.path.samefile(path, out):
        raise MeshAssetError(out, "--out is the input mesh itself: choose another file", "--out")
    if not out.lower().endswith(".ply"):
        raise MeshAssetError(out, "--out must be a .ply file", "--out")
    if os.path.isdir(out):
        raise MeshAssetError(out, "--out is a folder: name the .ply file to write", "--out")
    progress("load", 0, 3)
    asset = load_mesh(path, up)
    progress("sample", 1, 3)
    res = sample_gaussians(asset, count, seed, sigma_factor)
    V = asset.vertices
    used = V[np.unique(asset.faces)]
    used = used[np.isfinite(used).all(axis=1)]
    box = upright_box(used)
    progress("write", 2, 3)
    files.make_folder(os.path.dirname(os.path.abspath(out)), "--out")
    name = "".join(ch if " " <= ch <= "~" else "?" for ch in os.path.basename(path))  # the header is ASCII
    try:
        splats.write_ply(out, splats.encode(res.gaussians), comment=f"scpainter mesh-asset {name} up={asset.up}")
    except PermissionError as e:
        raise MeshAssetError(out, f"--out cannot be written: {e.strerror}", "--out") from None
    progress("write", 3, 3)
    return {"ply": out, "count": len(res.gaussians), "up": asset.up, "area": res.area, "sigma": res.sigma,
            "colour_source": res.colour_source, "colour_counts": res.colour_counts, "dropped": res.dropped,
            "parts": len(asset.parts), "faces": int(len(asset.faces)),
            "obb": {"size": box["size"], "yaw_deg": box["yaw_deg"], "center": box["center"]},
            "obb_3d": oriented_box_3d(used),
            "bounds": [used.min(axis=0).tolist(), used.max(axis=0).tolist()]}


# --------------------------------------------------------------------------------------------------------------
# Evaluation: the rendered asset mask against the mesh's own silhouette
# --------------------------------------------------------------------------------------------------------------

def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """4x4 world_to_camera (OpenCV: x right, y down, z forward) of a camera at ``eye`` looking at ``target``."""
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, (0.0, 1.0, 0.0))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    w2c = np.eye(4)
    w2c[:3, :3] = np.stack([x, y, z])
    w2c[:3, 3] = -w2c[:3, :3] @ eye
    return w2c


def orbit_cameras(center, radius: float, width: int, height: int, views: int = 6, elevation_deg: float = 15.0,
                  fov_x_deg: float = 50.0, azimuth0_deg: float = 20.0):
    """``views`` cameras (K, world_to_camera) evenly around ``center`` at ``radius``, ``elevation_deg`` above the
    horizon, looking at it; square pixels, principal point at the image centre."""
    fx = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2)
    K = np.array([[fx, 0.0, width / 2], [0.0, fx, height / 2], [0.0, 0.0, 1.0]])
    c = np.asarray(center, np.float64)
    out = []
    for i in range(views):
        a = math.radians(azimuth0_deg + 360.0 * i / views)
        e = math.radians(elevation_deg)
        eye = c + radius * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
        out.append((K, look_at(eye, c)))
    return out


def silhouette(vertices, faces, K, world_to_camera, width: int, height: int, near: float = 1e-3,
               chunk: int = 4_000_000) -> np.ndarray:
    """The mesh's own silhouette: (H, W) bool, pixel centres (u + 0.5, v + 0.5) inside any projected triangle.

    Exact point-in-triangle tests on each triangle's pixel bounding box (edge functions; a centre on an edge
    counts). Triangles with a corner behind ``near`` or a non-finite corner are skipped: keep the camera outside
    the object.
    """
    V = np.asarray(vertices, np.float64)
    Fc = np.asarray(faces, np.int64)
    w2c = np.asarray(world_to_camera, np.float64)
    cam = V @ w2c[:3, :3].T + w2c[:3, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        uv = (cam @ np.asarray(K, np.float64).T)
        uv = uv[:, :2] / uv[:, 2:3]
    z = cam[:, 2]
    tri_ok = (np.isfinite(uv).all(1) & (z > near))[Fc].all(axis=1)
    P = uv[Fc[tri_ok]]                                  # (triangles, 3, 2)
    mask = np.zeros(height * width, bool)
    if not len(P):
        return mask.reshape(height, width)
    lo = np.clip(np.ceil(P.min(axis=1) - 0.5), 0, [width, height]).astype(np.int64)     # first centre >= min
    hi = np.clip(np.floor(P.max(axis=1) - 0.5), -1, [width - 1, height - 1]).astype(np.int64)
    w, h = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    keep = (w > 0) & (h > 0)
    P, lo, w, h = P[keep], lo[keep], w[keep], h[keep]
    counts = w * h
    start = 0
    while start < len(P):  # chunks of triangles with at most ``chunk`` candidate pixels
        cum = np.cumsum(counts[start:])
        stop = start + max(1, int(np.searchsorted(cum, chunk, side="right")))
        sl = slice(start, stop)
        c = counts[sl]
        t = np.repeat(np.arange(stop - start), c)
        k = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        px = lo[sl][t, 0] + k % w[sl][t]
        py = lo[sl][t, 1] + k // w[sl][t]
        q = np.stack([px + 0.5, py + 0.5], axis=1)
        A, B, C = P[sl][t, 0], P[sl][t, 1], P[sl][t, 2]

        def edge(a, b):
            return (b[:, 0] - a[:, 0]) * (q[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (q[:, 0] - a[:, 0])

        e0, e1, e2 = edge(A, B), edge(B, C), edge(C, A)
        inside = ((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0))
        mask[(py * width + px)[inside]] = True
        start = stop
    return mask.reshape(height, width)


def render_mask(g: splats.Gaussians, K, world_to_camera, width: int, height: int, reference: bool = False):
    """The asset mask M_a = 1 - transmittance (H, W) float64 of Gaussians in world coordinates, rendered on the
    CPU by the condition renderer (``backend.render``: tile kernels, or the torch pair rasterizer with
    ``reference``)."""
    import torch

    from .render import gaussians as gs
    from .render import tiles

    t = lambda a: torch.as_tensor(np.asarray(a, np.float64))  # noqa: E731
    proj = gs.project(t(g.means), t(g.quats), t(g.scales), t(g.opacities), t(g.sh), K, world_to_camera,
                      width, height)
    raster = gs.rasterize if reference else tiles.rasterize
    _, asset_mask, _ = raster(proj, width, height)
    return asset_mask.numpy()


def mask_metrics(asset_mask, sil, threshold: float = 0.5) -> dict:
    """Compare a rendered asset mask M_a (H, W) in [0, 1] with a binary silhouette (H, W).

    * ``iou``: of (M_a >= threshold) and the silhouette;
    * ``mean_abs``: mean |M_a - sil| over the pixels of either (M_a > 1/255 or the silhouette);
    * ``leak``: Σ (1 - M_a) over the silhouette, ``spill``: Σ M_a outside it, both divided by the silhouette's
      area (leak: how transparent the car is, spill: how much it bleeds past its outline; their sum is the L1 error
      per silhouette pixel);
    * ``boundary_px``: the mean distance (pixels) from each boundary pixel of one mask to the other's boundary,
      averaged over both directions; ``boundary_p95_px``: the 95th percentile of those distances.
    """
    from scipy import ndimage

    a = np.clip(np.asarray(asset_mask, np.float64), 0.0, 1.0)
    s = np.asarray(sil, bool)
    m = a >= threshold
    union = m | s
    iou = float((m & s).sum() / max(union.sum(), 1))
    region = (a > 1.0 / 255.0) | s
    mean_abs = float(np.abs(a - s)[region].mean()) if region.any() else 0.0
    area = max(int(s.sum()), 1)

    def boundary(x):
        return x & ~ndimage.binary_erosion(x, border_value=0)

    bm, bs = boundary(m), boundary(s)
    if bm.any() and bs.any():
        d_ms = ndimage.distance_transform_edt(~bs)[bm]
        d_sm = ndimage.distance_transform_edt(~bm)[bs]
        bnd = 0.5 * (float(d_ms.mean()) + float(d_sm.mean()))
        p95 = float(np.percentile(np.concatenate([d_ms, d_sm]), 95))
    else:
        bnd = p95 = float("inf") if (bm.any() or bs.any()) else 0.0
    return {"iou": iou, "mean_abs": mean_abs, "leak": float((1.0 - a)[s].sum() / area),
            "spill": float(a[~s].sum() / area), "boundary_px": bnd, "boundary_p95_px": p95}
