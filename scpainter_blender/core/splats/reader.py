"""Gaussian files, one entry point: ``read(path)`` picks the reader by content (PLY magic, then the header's
elements) or, for headerless ``.splat``, by extension; ``load(path) = decode(read(path))``; mesh files are told
apart from Gaussian ones (``is_mesh_ply``, ``MESH_EXTENSIONS``) and refused with a message that says where they go.

The readers (every one returns a ``core.splats.gaussians.GaussianPly`` of raw INRIA values): ``core.splats.inria``
(INRIA, TRELLIS/Amodal3R and half-float PLY), ``core.splats.compressed`` (SuperSplat compressed PLY, antimatter15
``.splat``), on top of ``core.splats.ply_format`` (the PLY header and elements). Only regular files are opened (a
FIFO or a directory is refused at once, not waited on). Unusable files raise ``core.splats.gaussians.SplatsError``
naming the file and what is wrong.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import os

from . import compressed, inria, ply_format, sog
from .gaussians import ACCEPTED, GaussianPly, Gaussians, SplatsError, decode, open_file

#: Mesh files: not splats, but what the car-asset import converts to Gaussians (backend ``mesh-asset``, trimesh);
#: a ``.ply`` is a mesh when ``is_mesh_ply`` says so.
MESH_EXTENSIONS = (".glb", ".gltf", ".obj", ".stl", ".off")
#: Every file a car asset may be: Gaussian files and meshes (what the import's file browser and a variation
#: library take).
ASSET_EXTENSIONS = (".ply", ".splat", sog.EXTENSION) + MESH_EXTENSIONS


def read(path) -> GaussianPly:
    """Read any accepted Gaussian file (module docstring) into raw float32 arrays; SplatsError if unusable.

    PLY files (INRIA, half-float, SuperSplat compressed) are recognised by content; headerless ``.splat`` files by
    their extension. Only regular files are opened (a FIFO or a directory is refused at once, not waited on).
    """
    path = os.fspath(path)
    head = _head(path, 4)
    if head.startswith(b"ply"):
        return read_ply(path)
    if sog.is_sog(path, head):  # a zip bundle (whatever its name), *.sog, meta.json: decoded by core.splats.sog
        return sog.read(path)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".splat":
        return compressed.read_splat(path)
    raise SplatsError(path, _not_accepted(head, ext))


def load(path) -> Gaussians:
    """read + decode: decoded Gaussians of any accepted file."""
    return decode(read(path))


def _head(path, n: int) -> bytes:
    """The first ``n`` bytes of a regular file; SplatsError naming the file otherwise."""
    try:
        with open_file(path) as f:
            return f.read(n)
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None


def _not_accepted(head: bytes, ext: str) -> str:
    """Why a file that is neither PLY nor ``.splat`` is refused, and what to do, from its first bytes and extension."""
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


def is_mesh_ply(path) -> bool:
    """True for a readable PLY (binary or ASCII) whose header has faces and no Gaussian property (a mesh to
    convert); never raises."""
    try:
        _, elements, _ = ply_format.read_ply_header(path)
    except (OSError, SplatsError):
        return False
    face = ply_format.element(elements, "face")
    return face is not None and face[0] > 0 and _mesh_message(elements) is not None


def read_ply(path) -> GaussianPly:
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
