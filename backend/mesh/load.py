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
  therefore land in the same pose (``tests/backend/test_mesh_asset.py`` builds both and checks it).

Only regular files are opened, the mesh and every file it names (glTF buffers and images, OBJ materials and
textures): a FIFO would block trimesh's read forever. A PLY's header is checked before trimesh reads it
(``core.splats.ply_format``): a Gaussian-splat PLY, or counts the file cannot hold, are refused at once.

No bpy, no torch.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from scpainter_blender.core import errors, files
from scpainter_blender.core.splats import ply_format, gaussians as splats

#: p_zup = Y_UP_TO_Z_UP @ p for Y-up files: (x, y, z) -> (x, -z, y), Blender's glTF import.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: File extension -> the up axis ``up="auto"`` assumes.
UP_BY_EXTENSION = {".glb": "y", ".gltf": "y", ".obj": "y", ".ply": "z", ".stl": "z", ".off": "z"}


class MeshAssetError(errors.InputError):
    """A mesh file that cannot be made into Gaussians; the message names the file and what to do. ``field``: the
    part of the file at fault ("(file)" for the file as a whole; an element, or a texture/buffer the file names)."""

    def __init__(self, path, message, field=None, hint=None):
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
    if not np.any(face_areas(asset.vertices, asset.faces) > 0):
        raise MeshAssetError(path, f"its {len(asset.faces)} faces all have zero (or non-finite) area: nothing "
                                   "to sample")
    return asset


def as_parts(mesh):
    """(list of trimesh.Trimesh, gltf colour rules?) from a MeshAsset, a Trimesh or a sequence of them."""
    if isinstance(mesh, MeshAsset):
        return list(mesh.parts), mesh.gltf
    if isinstance(mesh, (list, tuple)):
        return list(mesh), False
    return [mesh], False


def face_areas(vertices, faces) -> np.ndarray:
    """(F,) float64 triangle areas of ``faces`` (F, 3) into ``vertices`` (V, 3); 0 where a corner is not finite."""
    if not len(faces):
        return np.zeros(0)
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    with np.errstate(invalid="ignore", over="ignore"):
        a = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    a[~np.isfinite(a)] = 0.0
    return a
