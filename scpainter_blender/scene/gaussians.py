"""Gaussian-splat assets as Blender objects: every file value kept, plus a viewport preview for placing cars.

Object data: a mesh with one vertex per (valid) Gaussian, in the asset's *data frame*: Z up, origin at the bottom
centre of the Gaussians' bounds. ``scpainter_file_to_data`` (4x4, on the object) maps the PLY's own coordinates
to it (TRELLIS/Amodal3R files: their axis change undone), so object_to_world of the file = matrix_world @ it.

Point attributes:
* raw, exactly as in the file: ``sh_0`` .. ``sh_{K-1}`` (FLOAT_VECTOR, RGB of SH coefficient k; ``sh_0`` is f_dc),
  ``opacity`` (logit), ``scale`` (log, local axes), ``rot`` (QUATERNION, file frame, as stored), ``ply_<name>``
  for any other property;
* for display, derived: ``gs_rotation`` (unit QUATERNION, data frame), ``gs_scale`` (standard deviations),
  ``gs_color`` (linear RGBA: the DC colour and the opacity).

Its upright 3D box (for labels) is estimated at import and shown as a child cube empty (scene/asset_box.py); its
class is ``scpainter_class``.

The Geometry Nodes preview draws either sprites (points of radius size·mean σ) or oriented ellipsoids (an
icosphere instanced per Gaussian, scaled to size·σ along its axes), both coloured and opacity-blended.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core.geometry import cameras
from ..core import job as job_mod, outputs
from ..core.splats import asset_frame, formats, gaussians as splats, reader as splats_io, sog, trellis
from ..core.output_layout import SceneFolder
from ..runs.client import Invocation
from . import asset_box, keys, kinds, materials, node_groups, paths, props
from .points import linear_rgba

NODE_GROUP = "SCPainter Gaussians"
NODE_GROUP_VERSION = 1
MATERIALS = {"GEOMETRY": "SCPainter Gaussian sprites", "INSTANCER": "SCPainter Gaussian ellipsoids"}


def _material(attribute_type: str) -> bpy.types.Material:
    # points carry gs_color themselves; instances read it from the point they stand on
    return materials.emission_material(MATERIALS[attribute_type], "gs_color", attribute_type, alpha=True)


#: The preview's inputs: sprites or ellipsoids, and their size in standard deviations.
INPUTS = (node_groups.Socket("Ellipsoids", "NodeSocketBool", False),
          node_groups.Socket("Size", "NodeSocketFloat", 2.0, 0.0))


def ensure_node_group() -> bpy.types.NodeTree:
    """Geometry Nodes preview: sprites (points of radius Size · mean σ) or ellipsoids (an icosphere per Gaussian,
    rotated by ``gs_rotation`` and scaled to Size · σ), each with its emission material."""
    return node_groups.ensure_group(NODE_GROUP, NODE_GROUP_VERSION, INPUTS, _build_node_group)


def _build_node_group(b: node_groups.Builder) -> None:
    gi = b.group_input
    scale = b.node("GeometryNodeInputNamedAttribute", {"Name": "gs_scale"}, data_type="FLOAT_VECTOR")
    rot = b.node("GeometryNodeInputNamedAttribute", {"Name": "gs_rotation"}, data_type="QUATERNION")

    # sprites: radius = size · mean σ
    mean_sigma = b.node("ShaderNodeVectorMath", {0: scale.outputs["Attribute"], 1: (1 / 3, 1 / 3, 1 / 3)},
                        operation="DOT_PRODUCT")
    radius = b.math("MULTIPLY", mean_sigma.outputs["Value"], gi.outputs["Size"])
    sprites = b.node("GeometryNodeMeshToPoints", {"Mesh": gi.outputs["Geometry"], "Radius": radius})
    sprite_mat = b.node("GeometryNodeSetMaterial", {"Geometry": sprites.outputs["Points"],
                                                    "Material": _material("GEOMETRY")})

    # ellipsoids: an icosphere per Gaussian, rotated and scaled to size · σ
    ico = b.node("GeometryNodeMeshIcoSphere", {"Radius": 1.0, "Subdivisions": 1})
    ico_mat = b.node("GeometryNodeSetMaterial", {"Geometry": ico.outputs["Mesh"], "Material": _material("INSTANCER")})
    axes = b.node("ShaderNodeVectorMath", {0: scale.outputs["Attribute"], "Scale": gi.outputs["Size"]},
                  operation="SCALE")
    as_points = b.node("GeometryNodeMeshToPoints", {"Mesh": gi.outputs["Geometry"]})
    inst = b.node("GeometryNodeInstanceOnPoints", {"Points": as_points.outputs["Points"],
                                                   "Instance": ico_mat.outputs["Geometry"],
                                                   "Rotation": rot.outputs["Attribute"],
                                                   "Scale": axes.outputs["Vector"]})
    switch = b.node("GeometryNodeSwitch", {"Switch": gi.outputs["Ellipsoids"],
                                           "False": sprite_mat.outputs["Geometry"],
                                           "True": inst.outputs["Instances"]}, input_type="GEOMETRY")
    b.output(switch.outputs[0])


@dataclass
class GaussianImport:
    object: bpy.types.Object
    count: int
    dropped: dict
    axes: str
    axes_reason: str = ""
    format: str = "inria"
    mesh: dict | None = None          # the backend's mesh-asset result when the source was a mesh
    converted: dict | None = None     # the backend's splat-asset result when the source needed the backend (SOG)
    timings: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)

    def report(self) -> str:
        """One line for the operator's report and the CLI summary."""
        dropped = f", dropped {self.dropped}" if self.dropped else ""
        src = splats.FORMAT_NAMES.get(self.format, self.format)
        if self.mesh:
            src = (f"mesh, {self.mesh['count']:,} surface Gaussians, colour from {self.mesh['colour_source']}, "
                   f"{self.mesh['up']} up")
        return (f"Imported {self.count:,} Gaussians ({src}) as {self.object.name!r}{dropped}; axes {self.axes}: "
                f"{self.axes_reason} ({self.timings.get('total', 0.0):.2f} s)")


#: Car meshes are converted to Gaussians by the backend (trimesh); a .ply is a mesh when it has faces and no
#: Gaussian properties (decided by its header). Formats that need the backend go through it too
#: (``is_backend_splat_file``).
ASSET_EXTENSIONS = splats_io.ASSET_EXTENSIONS
#: The file browser's filter: the extensions, and an unbundled SOG's ``meta.json``.
FILE_FILTER = ";".join([f"*{e}" for e in ASSET_EXTENSIONS] + [sog.META_NAME])
DEFAULT_MESH_COUNT = 200_000
#: Lengths (metres) outside which an imported asset is most likely in other units: the import says so.
MIN_CAR_LENGTH, MAX_CAR_LENGTH = asset_frame.CAR_LENGTH_M


def is_mesh_file(filepath: str) -> bool:
    """A car file to convert as a mesh, by content (``core.splats.reader.is_mesh``: a glTF with
    KHR_gaussian_splatting is Gaussians)."""
    return splats_io.is_mesh(filepath)


def is_backend_splat_file(filepath: str) -> bool:
    """A Gaussian file whose decoding needs the backend's Python: its format's record says ``needs_backend``
    (``core.splats.formats``; SOG, whose images are WebP, which Blender's Python cannot decode). Decided by content
    (``reader.detect``); a file it cannot tell is not one (the import's own read then says why)."""
    try:
        return formats.BY_KEY[splats_io.detect(filepath)].needs_backend
    except splats.SplatsError:
        return False


def _display_rotations(rot_raw, F):
    return cameras.rotation_to_quaternion(F @ cameras.quaternion_to_rotation(splats.unit_quaternions(rot_raw)))


def import_gaussians(context, filepath: str, axes: str = "AUTO", target_length: float | None = None,
                     ellipsoids: bool = False, name: str | None = None, mesh_count: int = DEFAULT_MESH_COUNT,
                     backend_python: str = "", gaussians_path: str | None = None) -> GaussianImport:
    """Import a car asset as an object at the 3D cursor; ``target_length`` metres along its longest horizontal
    axis (None: 4.5 m for a TRELLIS/Amodal3R file or a mesh inside their unit cube; file units otherwise).

    Gaussian files (the formats of ``core.splats.formats``, read by ``core.splats.reader``) are read here; meshes
    (GLB, glTF, OBJ, STL, OFF, mesh PLY) are first turned into surface Gaussians by ``python -m backend mesh-asset``
    (trimesh, in the backend's Python) with ``mesh_count`` Gaussians, written to ``gaussians_path`` (default
    ``mesh_gaussians_path``) and imported from there; a format whose record says ``needs_backend``
    (``is_backend_splat_file``: SOG, ``.sog`` or its ``meta.json``, whose WebP images need the backend's decoder)
    is rewritten as an INRIA PLY by ``python -m backend splat-asset``, to ``gaussians_path`` (default
    ``splat_gaussians_path``). Raises SplatsError (an InputError) / BackendError (exit code 2: the file is
    bad input); nothing is created unless the import succeeds.
    """
    t0 = time.perf_counter()
    filepath = os.path.abspath(bpy.path.abspath(filepath))
    if not os.path.isfile(filepath):
        raise splats.SplatsError(filepath, "file not found")
    mesh = None
    if is_mesh_file(filepath):
        out = gaussians_path or mesh_gaussians_path(context.scene, filepath, mesh_count)
        outputs.make_folder(os.path.dirname(out), "assets folder")
        mesh = Invocation("mesh-asset", asset=filepath, out=out, count=int(mesh_count),
                          python=backend_python).run()["result"]
        mesh["source"] = filepath
        filepath = out
    converted = None
    if mesh is None and is_backend_splat_file(filepath):
        out = gaussians_path or splat_gaussians_path(context.scene, filepath)
        outputs.make_folder(os.path.dirname(out), "assets folder")
        converted = Invocation("splat-asset", asset=filepath, out=out, python=backend_python).run()["result"]
        filepath = out
    ply = splats_io.read(filepath)
    fmt = converted["format"] if converted else ply.format
    keep, dropped = splats.valid_rows(ply)
    if not keep.any():
        raise splats.SplatsError(filepath, f"no valid Gaussians ({len(ply)} rows, dropped {dropped})")
    if axes != "AUTO":
        reason = "chosen on import"
    elif mesh:  # the backend already turned the mesh Z up
        axes, reason = "NONE", f"a mesh read {mesh['up'].upper()} up and turned Z up"
    else:
        axes, reason = trellis.detect_axes(ply, keep)
    file_to_data, F, lo, hi = asset_frame.data_frame(ply.xyz[keep], axes)
    pos = (ply.xyz[keep].astype(np.float64) @ file_to_data[:3, :3].T + file_to_data[:3, 3]).astype(np.float32)
    rot_raw = ply.rot[keep]
    # the display attributes are splats.decode's activations of the raw values kept beside them
    sigma = splats.scales_from_logs(ply.scale[keep])
    rgba = linear_rgba(np.minimum(splats.dc_colors(ply.f_dc[keep]), 1.0))
    rgba[:, 3] = splats.opacities_from_logits(ply.opacity[keep])
    t_read = time.perf_counter()

    N = len(pos)
    stem = name or _stem(mesh["source"] if mesh else converted["source"] if converted else filepath)
    mesh_data = bpy.data.meshes.new(stem)
    mesh_data.vertices.add(N)
    mesh_data.attributes["position"].data.foreach_set("vector", pos.ravel())

    def put(attr_name, kind, values, prop):
        a = mesh_data.attributes.new(attr_name, kind, "POINT")  # written at once: a new one may move the others
        a.data.foreach_set(prop, np.ascontiguousarray(values, dtype=np.float32 if kind != "INT" else np.int32).ravel())

    sh = splats.sh_coefficients(ply.f_dc[keep], ply.f_rest[keep])
    for k in range(sh.shape[1]):
        put(f"sh_{k}", "FLOAT_VECTOR", sh[:, k], "vector")
    put("opacity", "FLOAT", ply.opacity[keep], "value")
    put("scale", "FLOAT_VECTOR", ply.scale[keep], "vector")
    put("rot", "QUATERNION", rot_raw, "value")
    for extra, values in ply.extra.items():
        is_int = np.issubdtype(values.dtype, np.integer)
        put(f"ply_{extra}", "INT" if is_int else "FLOAT", values[keep], "value")
    put("gs_rotation", "QUATERNION", _display_rotations(rot_raw, F), "value")
    put("gs_scale", "FLOAT_VECTOR", sigma, "vector")
    col = mesh_data.color_attributes.new("gs_color", "FLOAT_COLOR", "POINT")
    col.data.foreach_set("color", rgba.ravel())
    mesh_data.update()

    obj = bpy.data.objects.new(stem, mesh_data)
    context.scene.collection.objects.link(obj)
    obj.location = context.scene.cursor.location
    extent = max(hi[0] - lo[0], hi[1] - lo[1])
    if target_length is None:  # TRELLIS/Amodal3R make unit-cube objects, as Gaussians and as GLBs
        target_length = asset_frame.default_length(ply, keep, axes, mesh is not None, extent)
    if extent > 0:
        obj.scale = (target_length / extent,) * 3
    node_groups.add_modifier(obj, "SCPainter Gaussians", ensure_node_group(), {"Ellipsoids": bool(ellipsoids)})
    kinds.mark(obj, kinds.GAUSSIAN_ASSET)
    obj[keys.SOURCE] = paths.stored(filepath)  # relative to the saved .blend: a moved project reads its own
    obj[keys.FORMAT] = fmt
    obj[keys.FILE_TO_DATA] = file_to_data.ravel().tolist()
    obj[keys.AXES] = axes
    obj[keys.AXES_REASON] = reason
    obj[keys.SH_DEGREE] = ply.sh_degree
    obj[keys.DROPPED] = int(sum(dropped.values()))
    obj[keys.SIZE] = (hi - lo).tolist()  # data-frame extents (before the object's scale)
    obj[keys.REVIEW] = "unchecked"
    obj[asset_box.CLASS_PROPERTY] = job_mod.DEFAULT_CLASS
    asset_box.estimate(obj, pos)  # its upright box in the data frame, a child cube empty (scene/asset_box.py)
    if mesh:
        obj[keys.MESH_SOURCE] = paths.stored(mesh["source"])
        # trimesh's upright oriented box (length, width, height) of the mesh, for stage 1 (placement.asset_size)
        obj[keys.OBB_SIZE] = [float(v) for v in mesh["obb"]["size"]]
    if converted:
        obj[keys.SPLAT_SOURCE] = paths.stored(converted["source"])
    # what the backend read past in the mesh (an unsupported material, faces with non-finite corners, ...)
    warnings = [w["message"] for w in mesh.get("warnings", [])] if mesh else []
    if extent > 0 and not MIN_CAR_LENGTH <= target_length <= MAX_CAR_LENGTH:
        warnings.append(f"{obj.name} is {target_length:.3g} m long in its file's units (millimetres or centimetres?): "
                        "set Length on import, or use Fit to Car Size")
    t_end = time.perf_counter()
    return GaussianImport(obj, N, dropped, axes, reason, fmt, mesh, converted,
                          {"read_decode": t_read - t0, "object": t_end - t_read, "total": t_end - t0}, warnings)


def _stem(path: str) -> str:
    """The object name a source file gives: its name without extension; an unbundled SOG's folder name."""
    base = os.path.basename(path)
    if base.lower() == sog.META_NAME:
        return os.path.basename(os.path.dirname(path)) or os.path.splitext(base)[0]
    return os.path.splitext(base)[0]


def mesh_gaussians_path(scene, mesh_path: str, count: int) -> str:
    """Where a mesh's surface Gaussians are written: ``<output folder>/assets/`` (the scene's, so the file travels
    with the project), or the user's cache folder (``$XDG_CACHE_HOME/scpainter/assets``, ``~/.cache/...``) while
    the .blend is unsaved. Never beside the mesh: asset libraries are often read-only.

    The name keeps the source's full file name and adds a hash of its absolute path, size and modification time,
    so two meshes (``car.stl``, ``car.ply``, or one edited since) never share a file: ``car.stl.200000.<hash>.ply``.
    """
    return os.path.join(_assets_folder(scene), asset_frame.mesh_gaussians_name(mesh_path, count))


def splat_gaussians_path(scene, splat_path: str) -> str:
    """Where the INRIA PLY of a file the backend rewrites (``splat-asset``: a SOG) is written: the assets folder of
    ``mesh_gaussians_path``, named ``<name>.<hash>.gaussians.ply`` with the hash of ``asset_frame.file_key``; an
    unbundled SOG is named by its folder (``scene-meta.json.<hash>.gaussians.ply``)."""
    base = os.path.basename(splat_path)
    if base.lower() == sog.META_NAME:
        base = f"{os.path.basename(os.path.dirname(os.path.abspath(splat_path)))}-{base}"
    return os.path.join(_assets_folder(scene), f"{base}.{asset_frame.file_key(splat_path)}.gaussians.ply")


def _assets_folder(scene) -> str:
    """The scene's ``<output folder>/assets/``, or the user's cache folder while the .blend is unsaved."""
    try:
        return SceneFolder(props.output_dir(scene)).assets
    except props.SceneError:  # unsaved .blend: its output folder is relative to it
        return outputs.user_cache_dir("assets")


def set_axes(obj, axes: str) -> None:
    """Re-read an imported asset with other file axes ("TRELLIS" or "NONE"): the artist's correction when AUTO
    chose wrong. Positions, display rotations, size and file_to_data are recomputed from the stored file values;
    the object's placement is kept and its scale adjusted so its length stays the same; its box is estimated again
    (an edited box is replaced: it stood in the old data frame)."""
    if axes not in ("TRELLIS", "NONE"):
        raise ValueError(f"axes must be 'TRELLIS' or 'NONE', got {axes!r}")
    me = obj.data
    n = len(me.vertices)
    pos = np.empty(n * 3, np.float32)
    me.attributes["position"].data.foreach_get("vector", pos)
    old = props.matrix_property(obj, keys.FILE_TO_DATA)
    xyz_file = (pos.reshape(-1, 3).astype(np.float64) - old[:3, 3]) @ np.linalg.inv(old[:3, :3]).T
    D, F, lo, hi = asset_frame.data_frame(xyz_file, axes)
    xyz_data = (xyz_file @ D[:3, :3].T + D[:3, 3]).astype(np.float32)
    me.attributes["position"].data.foreach_set("vector", xyz_data.ravel())
    rot = np.empty(n * 4, np.float32)
    me.attributes["rot"].data.foreach_get("value", rot)
    me.attributes["gs_rotation"].data.foreach_set("value", _display_rotations(rot.reshape(-1, 4), F)
                                                  .astype(np.float32).ravel())
    me.update()
    old_size = np.array(obj[keys.SIZE], np.float64)
    old_len, new_len = max(old_size[:2]), max(hi[0] - lo[0], hi[1] - lo[1])
    if new_len > 0 and old_len > 0:
        obj.scale = np.array(obj.scale) * (old_len / new_len)
    obj[keys.FILE_TO_DATA] = D.ravel().tolist()
    obj[keys.SIZE] = (hi - lo).tolist()
    obj[keys.AXES] = axes
    obj[keys.AXES_REASON] = "set by hand"
    asset_box.estimate(obj, xyz_data)  # the old box stood in the old data frame: estimated again
    for key in (keys.STAGE1, keys.STAGE1_DEVIATION):  # measured on the old axes: check again
        if key in obj:
            del obj[key]


def preview_input(obj, name):
    """(the preview modifier of asset ``obj``, the property key of its input ``name``)."""
    mod = node_groups.find_modifier(obj, NODE_GROUP)
    if mod is None:
        raise KeyError(f"{obj.name!r} has no {NODE_GROUP!r} modifier")
    return mod, node_groups.socket_identifier(mod.node_group, name)
