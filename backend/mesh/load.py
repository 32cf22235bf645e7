"""Mesh files (GLB, glTF, OBJ, PLY, STL, OFF) read with trimesh into Z-up parts for the ``mesh-asset`` command
(``backend.mesh.asset``), and refused with a ``MeshAssetError`` naming the file when they are not a usable mesh.

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
  writes its Gaussians as ``xyz @ T.T`` with the same matrix T, i.e. (x, -z, y)
  (``core.splats.trellis.ZUP_TO_TRELLIS_FILE``),
  which the Gaussian import undoes with ``F = ZUP_TO_TRELLIS_FILE.T``. The two files of one TRELLIS asset
  therefore land in the same pose (``tests/backend/mesh/test_asset.py`` builds both and checks it).

Hostile files (issue 30; the bounds and the checks before trimesh are ``backend.mesh.checks``): only regular files
are opened, the mesh and every file it names (glTF buffers and images, OBJ materials and textures, a PLY's
``TextureFile``), each exactly as named, inside the mesh's folder (``_exact_resolver``: trimesh's own resolver
would take another file of the same base name); a missing, outside or unreadable one is refused naming it, though
trimesh would go on without it. A PLY's header (``core.splats.ply_format``), a glTF/GLB's buffers, views and
accessors and an OFF's counts are checked against the bytes before trimesh allocates what they claim, an OBJ's
face indices (never 0) and its MTL (``checks.check_obj``: ``map_Kd`` options parsed, ``-clamp on`` applied, the
options not applied a ``TEXTURE_OPTIONS_IGNORED`` warning); textures against ``checks.MAX_TEXTURE_PIXELS`` each and
``checks.MAX_TOTAL_TEXTURE_PIXELS`` together, from their headers. The scene is flattened without copying materials
(``_instances``: ``Scene.dump`` deep-copies, i.e. decodes, every texture), each texture decoded once
(``_decode_textures``: a failure names it). After reading: face indices against the vertex count,
the texture coordinates textured faces use (finite), the car's extent (``checks.check_extent``). numpy's warnings
inside trimesh are silenced (``np.errstate``). trimesh's log records are kept, not printed
(``_trimesh_records``): a texture it could not read is an error, anything else it went on past a ``warning``
(``MeshAsset.warnings``, ``READER_WARNING``), as are faces with a non-finite corner (``NONFINITE_FACES``).

glTF that trimesh 5.2.0 would misread (issue 31: ``KHR_texture_transform`` / ``texCoord`` on the base-colour
texture, normalized or quantized accessors, sparse accessors, Draco) is rewritten plain first and trimesh reads
that (``backend.mesh.gltf.plain_glb``); ``extensionsRequired`` not read here is refused by name
(``gltf.check_required``, from ``checks.check_gltf``).

No bpy, no torch.

(Over 400 lines: one loader per mesh family (glTF, OBJ/MTL, PLY/STL/OFF) around trimesh, each with the
warnings and checks that make trimesh's silent choices visible; split further, each piece would import the others.)
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from scpainter_blender.core import errors, files
from scpainter_blender.core.geometry import cameras
from scpainter_blender.core.splats import ply_format, gaussians as splats

from . import checks, gltf as gltf_plain

if TYPE_CHECKING:
    import trimesh

#: p_zup = Y_UP_TO_Z_UP @ p for Y-up files (``core.geometry.cameras``, where the axis conventions live)
Y_UP_TO_Z_UP = cameras.Y_UP_TO_Z_UP
#: File extension -> the up axis ``up="auto"`` assumes.
UP_BY_EXTENSION = {".glb": "y", ".gltf": "y", ".obj": "y", ".ply": "z", ".stl": "z", ".off": "z"}


class MeshAssetError(errors.InputError):
    """A mesh file that cannot be made into Gaussians; the message names the file and what to do. ``field``: the
    part of the file at fault ("(file)" for the file as a whole; an element, or a texture/buffer the file names)."""

    def __init__(self, path: str | os.PathLike, message: str, field: str | None = None,
                 hint: str | None = None) -> None:
        errors.InputError.__init__(self, path, field, message, hint)
        self.args = (f"{os.path.basename(self.path)}: {message} ({self.path})",)  # the text it has always had


def _file_error(path, field, message):
    """``files``' error callback: its messages as MeshAssetError."""
    return MeshAssetError(path, "file not found" if message == "not found" else message, field)


@dataclass
class MeshAsset:
    """A mesh file read into Z-up parts.

    ``parts``: ``trimesh.Trimesh`` objects in the Z-up output frame, node transforms applied, each with its own
    visual (texture / colours); ``up``: the axis read as up in the file ("y" or "z"); ``gltf``: colours follow
    glTF's rules (linear factors and vertex colours);
    ``warnings``: ``warning`` events (dicts: message, code) for what the file had that was left out or went past;
    ``wraps``: (wrapS, wrapT) of each part's base-colour texture (``colors.WRAP_MODES``: glTF samplers, an MTL
    ``-clamp on``), one per part, or empty: REPEAT for all.
    """

    path: str
    parts: list
    up: str
    gltf: bool = False
    warnings: list = field(default_factory=list)
    wraps: list = field(default_factory=list)

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


#: What to do with a Gaussian-splat file given to ``mesh-asset`` (the splats need no conversion).
SPLATS_HINT = ("use it as it is: `Import Gaussian Asset` in Blender reads it, or `python -m backend splat-asset FILE "
               "--out PLY` writes it as an INRIA PLY")


def _splats_error(path, what) -> MeshAssetError:
    return MeshAssetError(path, f"it holds Gaussian splats ({what}), not a mesh: there is nothing to convert",
                          "(file)", hint=SPLATS_HINT)


def _check_not_splats(path, ext) -> None:
    """Refuse a Gaussian-splat file that is no PLY (any other format of ``core.splats.formats``) by content
    (``reader.detect``), with what to do (``SPLATS_HINT``); a PLY is ``_check_ply``'s."""
    from scpainter_blender.core.splats import reader

    if ext == ".ply" or reader.is_mesh(path):
        return
    try:
        kind = reader.detect(path)
    except splats.SplatsError:
        return  # no Gaussian file: the mesh checks say what it is
    raise _splats_error(path, f"{kind} format")


def _check_ply(path, size: int) -> None:
    """Refuse, before trimesh reads it, a PLY that holds Gaussians, or whose header promises more than the file
    holds (trimesh would allocate what the counts claim). A header our parser cannot read is left to trimesh,
    which reads more PLY dialects and says what it thinks is wrong."""
    try:
        fmt, elements, start = ply_format.read_ply_header(path)
    except splats.SplatsError:
        return
    vertex = next((props for name, _, props in elements if name == "vertex"), [])
    names = {p for p, _ in vertex}
    if "f_dc_0" in names or {"scale_0", "rot_0"} <= names or "packed_position" in names:
        raise _splats_error(path, "a Gaussian-splat PLY")
    binary = fmt in ("binary_little_endian", "binary_big_endian")
    for name, count, props in elements:
        # the fewest bytes a row can take: its fixed properties, each list's count; ASCII: one digit and a space each
        least = sum(np.dtype(t).itemsize if t is not None else 1 for _, t in props) if binary else 2 * len(props)
        if count * least > size - start:
            raise MeshAssetError(path, f"the header promises {count} {name} rows (at least {count * least:,} bytes) "
                                       f"but the file has {size - start:,} bytes after it: truncated or corrupt", name)


#: The field naming a mesh's faces / texture coordinates in each format's own terms (errors name them).
FACE_FIELD = {".glb": "indices", ".gltf": "indices", ".obj": "f", ".ply": "face", ".stl": "facet", ".off": "faces"}
UV_FIELD = {".glb": "TEXCOORD_0", ".gltf": "TEXCOORD_0", ".obj": "vt", ".ply": "texture coordinates"}
#: ``warning`` event codes of ``mesh-asset`` (an honest acceptance: the PLY is written, the event says what was off)
READER_WARNING = "mesh_reader_warning"      # trimesh went on past something in the file it could not read
NONFINITE_FACES = "mesh_nonfinite_faces"    # faces with a NaN/infinite corner: never sampled
TEXTURE_OPTIONS_IGNORED = "mesh_texture_options_ignored"  # an MTL map_Kd's -o/-s/-t/-mm/-cc, not applied


def _error_for(path):
    """``error(field, message, hint)`` -> MeshAssetError about ``path`` (what ``checks`` takes)."""
    return lambda field, message, hint=None: MeshAssetError(path, message, field, hint)


def _exact_resolver(path, gltf: bool):
    """trimesh's resolver for the files a mesh names (glTF buffers and images, OBJ materials and textures, a PLY's
    texture), opening exactly the name given (``checks.named_file``: inside the mesh's folder, no other file of the
    same base name, as trimesh's own resolver would try), only as a regular file (a FIFO named as a texture would
    block the read forever), images checked from their header (``checks.check_image``). trimesh swallows its
    resolver's errors for textures and materials (it goes on without them), so each refusal is also kept in
    ``.refused`` for the caller to raise."""
    from trimesh import resolvers

    refused = []
    error = _error_for(path)

    class ExactFiles(resolvers.FilePathResolver):
        def get(self, name):
            if not gltf and name.strip().startswith("-"):  # an MTL map_Kd value with options: trimesh 5.2 passes
                name = checks.mtl_texture(name)[0] or name  # it whole; the file is what follows the options
            try:
                where = checks.named_file(path, name, error, gltf)
                with files.open_regular(where, lambda p, f, m: error(
                        name, f"{name!r} (named by the mesh) {'not found' if m == 'not found' else m}",
                        "replace it with the file itself")) as f:
                    if os.path.splitext(name)[1].lower() in checks.IMAGE_EXTENSIONS:
                        checks.check_image(f, error, name)
                        f.seek(0)
                    return f.read()
            except MeshAssetError as e:
                refused.append(e)
                raise

        def namespaced(self, namespace):
            return self  # names stay relative to the mesh's folder

    resolver = ExactFiles(path)
    resolver.refused = refused
    return resolver


@contextlib.contextmanager
def _trimesh_records():
    """The log records trimesh makes in the block, kept instead of printed: trimesh logs the exceptions it goes on
    after (with their tracebacks, which Python's last-resort handler would print on a run that exits 0)."""
    import logging

    records = []

    class Keep(logging.Handler):
        def emit(self, record):
            records.append(record)

    logger = logging.getLogger("trimesh")
    handler, saved = Keep(logging.DEBUG), (logger.level, logger.propagate)
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    logger.propagate = False
    try:
        yield records
    finally:
        logger.removeHandler(handler)
        logger.setLevel(saved[0])
        logger.propagate = saved[1]


def _reader_outcome(path, records, refused) -> list:
    """What trimesh's log records mean: a refusal the resolver made (raised), a texture beyond PIL's (our) pixel
    bound (raised), or a ``warning`` (dict: message, code) for each other thing it went on past (records with an
    exception, or at WARNING and above). Debug chatter without an exception is dropped."""
    import logging

    from PIL import Image

    if refused:
        raise refused[0]
    out = []
    for r in records:
        exc = r.exc_info[1] if r.exc_info else None
        if isinstance(exc, (Image.DecompressionBombError, Image.DecompressionBombWarning)):
            raise MeshAssetError(path, f"a texture it holds is larger than {checks.MAX_TEXTURE_PIXELS:,} pixels "
                                       f"({exc})", "(texture)", hint="scale the texture down (8192 × 8192 at most)")
        if exc is None and r.levelno < logging.WARNING:
            continue
        text = r.getMessage() + (f" ({type(exc).__name__}: {exc})" if exc is not None else "")
        if exc is not None and "image" in r.getMessage().lower():  # trimesh's "unable to load image!" & co
            raise MeshAssetError(path, f"a texture it names cannot be read as an image: {text}", "(texture)",
                                 hint="fix or replace the texture file (PNG or JPEG), or fix the name the mesh "
                                      "gives it")
        out.append({"message": f"{os.path.basename(path)}: trimesh went on past a problem: {text}",
                    "code": READER_WARNING})
    return out


def _instances(scene) -> list:
    """Every geometry of ``scene`` moved to its instance position, as ``trimesh.Scene.dump`` makes them, but
    sharing each textured part's material instead of deep-copying it (a copy decodes the texture, and holds it
    twice: 700 MB for one 8192² texture). Other geometry (points, paths) is returned as stored: only counted."""
    import trimesh
    from trimesh.visual import TextureVisuals

    out = []
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        g = scene.geometry[name]
        if not isinstance(g, trimesh.Trimesh):
            out.append(g)
            continue
        vis = g.visual
        visual = (TextureVisuals(uv=vis.uv, material=vis.material, face_materials=vis.face_materials)
                  if isinstance(vis, TextureVisuals) else vis.copy())
        m = trimesh.Trimesh(vertices=np.array(g.vertices), faces=np.array(g.faces), visual=visual, process=False,
                            validate=False)
        m.apply_transform(transform)
        out.append(m)
    return out


def _decode_textures(path, meshes, texture_names) -> None:
    """Decode each part's base-colour texture once, here (PIL decodes lazily: a texture whose data does not match
    its header would otherwise fail while sampling). A failure is a ``MeshAssetError`` naming the texture (OBJ:
    the name trimesh records; glTF: the one image, when the file has one), field "(texture)" otherwise."""
    from .colors import material_image

    seen = set()
    for m in meshes:
        image = material_image(getattr(m.visual, "material", None)) if hasattr(m.visual, "material") else None
        if image is None or id(image) in seen:
            continue
        seen.add(id(image))
        try:
            image.load()
        except Exception as e:  # PIL: OSError, SyntaxError, ValueError, zlib errors ...
            name = image.info.get("file_path") or (texture_names[0] if len(texture_names) == 1 else None)
            what = f"texture {name!r}" if name else "a texture it names"
            raise MeshAssetError(path, f"{what} cannot be decoded ({type(e).__name__}: {e}): its data does not "
                                       "match its header, or it is cut short", name or "(texture)",
                                 hint="fix or replace the texture file (PNG or JPEG)") from None


def _check_parts(path, ext, meshes, warnings_out) -> None:
    """Faces against their part's vertex count (a negative index would wrap around, a large one fail later), the
    texture coordinates a textured part's faces use (NaN UVs gave samples without a colour), and a warning for
    faces with a non-finite corner (left out of the sampling)."""
    from trimesh.visual import TextureVisuals

    from .colors import material_image

    bad_corner = 0
    for k, m in enumerate(meshes):
        F, nv = np.asarray(m.faces), len(m.vertices)
        name = f"part {k} of {len(meshes)}" if len(meshes) > 1 else "the mesh"
        if len(F) and (F.min() < 0 or F.max() >= nv):
            raise MeshAssetError(path, f"{name}: its faces name vertices {int(F.min())} to {int(F.max())}, but it has "
                                       f"{nv} (0 to {nv - 1}): corrupt face indices", FACE_FIELD.get(ext, "faces"),
                                 hint="export the mesh again")
        vis = m.visual
        if isinstance(vis, TextureVisuals) and vis.uv is not None and material_image(vis.material) is not None \
                and len(vis.uv) == nv and len(F):
            used = np.asarray(vis.uv, np.float64)[np.unique(F)]
            bad = int((~np.isfinite(used).all(axis=1)).sum())
            if bad:
                raise MeshAssetError(path, f"{name}: {bad:,} of the {len(used):,} texture coordinates its faces use "
                                           "are not finite numbers (NaN or infinite): no colour can be read there",
                                     UV_FIELD.get(ext, "texture coordinates"),
                                     hint="fix the mesh's UVs (unwrap it again) and export it again")
        V = np.asarray(m.vertices, np.float64)
        if len(F):
            bad_corner += int((~np.isfinite(V[F]).all(axis=(1, 2))).sum())
    if bad_corner:
        total = sum(len(m.faces) for m in meshes)
        warnings_out.append({"message": f"{os.path.basename(path)}: {bad_corner:,} of {total:,} faces have a corner "
                                        "that is not a finite number; they are left out of the car",
                             "code": NONFINITE_FACES})


def _mtl_wraps(meshes, maps) -> list:
    """(wrapS, wrapT) of each OBJ part: CLAMP_TO_EDGE both ways where its material's ``map_Kd`` has ``-clamp on``
    (``checks.MtlMap``; trimesh names the material as the ``newmtl`` line does), else REPEAT; [] when none does."""
    from .colors import CLAMP_TO_EDGE, DEFAULT_WRAP

    clamped = {m.material for m in maps if m.clamp}
    if not clamped:
        return []
    return [(CLAMP_TO_EDGE, CLAMP_TO_EDGE) if getattr(getattr(p.visual, "material", None), "name", None) in clamped
            else DEFAULT_WRAP for p in meshes]


def load_mesh(path: str | os.PathLike, up: str = "auto") -> MeshAsset:
    """Read a mesh file (GLB, glTF, OBJ, PLY, STL, OFF) into Z-up parts (see the module docstring).

    ``up``: "auto" (by extension: glTF/GLB/OBJ Y up, the rest Z up), "y" or "z". Raises ``MeshAssetError``
    (an InputError naming the file and field) for a missing or unreadable file, an unsupported format, a
    Gaussian-splat PLY, counts the file cannot hold or indices it cannot mean (``checks``: glTF attributes of
    unequal length, required glTF extensions not read here, a base-colour UV set the primitive lacks, Draco data
    that does not decode, an OBJ face index of 0, an MTL without a material or with an empty ``map_Kd``), a file it names
    that is missing, outside its folder or unreadable, a texture beyond ``checks.MAX_TEXTURE_PIXELS`` (or textures
    beyond ``checks.MAX_TOTAL_TEXTURE_PIXELS`` together) or that does not decode, face indices outside the vertices,
    non-finite texture coordinates, a point cloud, a file without triangles, or a car whose extent is outside
    [``checks.MIN_EXTENT``, ``checks.MAX_EXTENT``]. What trimesh
    went on past is in ``MeshAsset.warnings``.
    """
    import trimesh

    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if up not in ("auto", "y", "z"):
        raise ValueError(f"up must be 'auto', 'y' or 'z', got {up!r}")
    size = files.check_regular(path, _file_error)  # trimesh opens by name: a FIFO would block it forever
    if size:
        _check_not_splats(path, ext)
    if ext not in UP_BY_EXTENSION:
        raise MeshAssetError(path, f"{ext or 'no extension'} is not a mesh format read here: export the car as "
                                   "GLB, glTF, OBJ, PLY, STL or OFF")
    if size == 0:
        raise MeshAssetError(path, "the file is empty (0 bytes)")
    gltf = ext in (".glb", ".gltf")
    resolver = _exact_resolver(path, gltf)
    error = _error_for(path)

    def open_named(name):
        return files.open_regular(checks.named_file(path, name, error, gltf), lambda p, f, m: error(
            name, f"{name!r} (named by the mesh) {m}", "replace it with the file itself"))

    tree, maps, warned, plain = None, [], [], None
    if ext == ".ply":
        _check_ply(path, size)
    elif gltf:
        tree = checks.check_gltf(path, size, error, open_named)
        plain = gltf_plain.plain_glb(path, tree, error, open_named)  # what trimesh would misread, made plain
    elif ext == ".off":
        checks.check_off(path, error)
    elif ext == ".obj":
        maps = checks.check_obj(path, error, open_named)
    # numpy's warnings (trimesh divides by a flat mesh's zero volume, casts NaN) are not ours to print
    with _trimesh_records() as records, np.errstate(all="ignore"):
        try:
            with checks.pixel_limit(checks.MAX_TEXTURE_PIXELS):  # a texture nothing above checked (none known)
                if plain is not None:
                    import io

                    scene = trimesh.load(io.BytesIO(plain), file_type="glb", force="scene", process=False,
                                         resolver=resolver)
                else:
                    scene = trimesh.load(path, force="scene", process=False, resolver=resolver)
                parts = _instances(scene)
        except MeshAssetError:
            raise
        except Exception as e:  # trimesh raises anything from struct.error to KeyError on a broken file
            if resolver.refused:
                raise resolver.refused[0] from None
            if isinstance(e, IndexError):
                raise MeshAssetError(path, f"a face names a vertex that does not exist ({e})",
                                     FACE_FIELD.get(ext, "faces"), hint="export the mesh again") from None
            raise MeshAssetError(path, f"trimesh cannot read it as a mesh ({type(e).__name__}: {e}); check the file "
                                       "opens in Blender, or export it again as GLB") from None
    warned = _reader_outcome(path, records, resolver.refused)
    warned += [{"message": f"{os.path.basename(path)}: texture {m.file!r}: MTL options not applied here: "
                           f"{', '.join(m.ignored)} (the texture is read as if they were absent)",
                "code": TEXTURE_OPTIONS_IGNORED} for m in maps if m.ignored]
    meshes = [p for p in parts if isinstance(p, trimesh.Trimesh) and len(p.faces)]
    if not meshes:
        points = sum(len(getattr(p, "vertices", ())) for p in parts)
        what = (f"{points} points but no faces (a point cloud)" if points else "no geometry")
        raise MeshAssetError(path, f"it has {what}: a car asset needs a triangle mesh (or a Gaussian-splat PLY)")
    _check_parts(path, ext, meshes, warned)
    _decode_textures(path, meshes, [img.get("uri") for img in (tree or {}).get("images", [])
                                    if isinstance(img.get("uri"), str) and not img["uri"].startswith("data:")])
    axis = UP_BY_EXTENSION[ext] if up == "auto" else up
    if axis == "y":
        y_up_to_z_up = np.eye(4)
        y_up_to_z_up[:3, :3] = Y_UP_TO_Z_UP
        for m in meshes:
            m.apply_transform(y_up_to_z_up)
    wraps = gltf_plain.part_wraps(meshes, tree) if plain is not None else _mtl_wraps(meshes, maps)
    asset = MeshAsset(path, meshes, axis, gltf=gltf, warnings=warned, wraps=wraps)
    used = np.unique(asset.faces)
    checks.check_extent(asset.vertices[used], error, tree)
    if not np.any(face_areas(asset.vertices, asset.faces) > 0):
        raise MeshAssetError(path, f"its {len(asset.faces)} faces all have zero (or non-finite) area: nothing "
                                   "to sample")
    return asset


def as_parts(mesh: MeshAsset | trimesh.Trimesh | list | tuple) -> tuple[list, bool]:
    """(list of trimesh.Trimesh, gltf colour rules?) from a MeshAsset, a Trimesh or a sequence of them."""
    if isinstance(mesh, MeshAsset):
        return list(mesh.parts), mesh.gltf
    if isinstance(mesh, (list, tuple)):
        return list(mesh), False
    return [mesh], False


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) float64 triangle areas of ``faces`` (F, 3) into ``vertices`` (V, 3); 0 where a corner is not finite."""
    if not len(faces):
        return np.zeros(0)
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    with np.errstate(invalid="ignore", over="ignore"):
        a = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    a[~np.isfinite(a)] = 0.0
    return a
