"""Gaussian-splat assets as Blender objects: every file value kept, plus a viewport preview for placing cars.

Object data: a mesh with one vertex per (valid) Gaussian, in the asset's *data frame*: Z up, origin at the bottom
centre of the Gaussians' bounds. ``scpainter_data_from_file`` (4x4, on the object) maps the PLY's own coordinates
to it (TRELLIS/Amodal3R files: their axis change undone), so object_to_world of the file = matrix_world @ it.

Point attributes:
* raw, exactly as in the file: ``sh_0`` .. ``sh_{K-1}`` (FLOAT_VECTOR, RGB of SH coefficient k; ``sh_0`` is f_dc),
  ``opacity`` (logit), ``scale`` (log, local axes), ``rot`` (QUATERNION, file frame, as stored), ``ply_<name>``
  for any other property;
* for display, derived: ``gs_rotation`` (unit QUATERNION, data frame), ``gs_scale`` (standard deviations),
  ``gs_color`` (linear RGBA: the DC colour and the opacity).

The Geometry Nodes preview draws either sprites (points of radius size·mean σ) or oriented ellipsoids (an
icosphere instanced per Gaussian, scaled to size·σ along its axes), both coloured and opacity-blended.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..core import cameras, splats
from . import materials
from .points import _linear_rgba, _socket_identifier, set_input

NODE_GROUP = "SCPainter Gaussians"
NODE_GROUP_VERSION = 1
MATERIALS = {"GEOMETRY": "SCPainter Gaussian sprites", "INSTANCER": "SCPainter Gaussian ellipsoids"}
TRELLIS_DEFAULT_LENGTH = 4.5  # metres: a unit-cube asset is scaled to a mid-size car until the artist fits it


def _material(attribute_type: str) -> bpy.types.Material:
    # points carry gs_color themselves; instances read it from the point they stand on
    return materials.emission_material(MATERIALS[attribute_type], "gs_color", attribute_type, alpha=True)


def ensure_node_group() -> bpy.types.NodeTree:
    ng = bpy.data.node_groups.get(NODE_GROUP)
    if ng is not None and ng.get("scpainter_version") == NODE_GROUP_VERSION:
        return ng
    ng = bpy.data.node_groups.new(NODE_GROUP, "GeometryNodeTree")
    ng["scpainter_version"] = NODE_GROUP_VERSION
    iface = ng.interface
    iface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    e = iface.new_socket("Ellipsoids", in_out="INPUT", socket_type="NodeSocketBool")
    e.default_value = False
    size = iface.new_socket("Size", in_out="INPUT", socket_type="NodeSocketFloat")
    size.default_value, size.min_value = 2.0, 0.0
    iface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    n, link = ng.nodes, ng.links.new
    gi, go = n.new("NodeGroupInput"), n.new("NodeGroupOutput")

    scale = n.new("GeometryNodeInputNamedAttribute")
    scale.data_type = "FLOAT_VECTOR"
    scale.inputs["Name"].default_value = "gs_scale"
    rot = n.new("GeometryNodeInputNamedAttribute")
    rot.data_type = "QUATERNION"
    rot.inputs["Name"].default_value = "gs_rotation"

    # sprites: radius = size · mean σ
    mean_sigma = n.new("ShaderNodeVectorMath")
    mean_sigma.operation = "DOT_PRODUCT"
    link(scale.outputs["Attribute"], mean_sigma.inputs[0])
    mean_sigma.inputs[1].default_value = (1 / 3, 1 / 3, 1 / 3)
    radius = n.new("ShaderNodeMath")
    radius.operation = "MULTIPLY"
    link(mean_sigma.outputs["Value"], radius.inputs[0])
    link(gi.outputs["Size"], radius.inputs[1])
    sprites = n.new("GeometryNodeMeshToPoints")
    link(gi.outputs["Geometry"], sprites.inputs["Mesh"])
    link(radius.outputs[0], sprites.inputs["Radius"])
    sprite_mat = n.new("GeometryNodeSetMaterial")
    sprite_mat.inputs["Material"].default_value = _material("GEOMETRY")
    link(sprites.outputs["Points"], sprite_mat.inputs["Geometry"])

    # ellipsoids: an icosphere per Gaussian, rotated and scaled to size · σ
    ico = n.new("GeometryNodeMeshIcoSphere")
    ico.inputs["Radius"].default_value = 1.0
    ico.inputs["Subdivisions"].default_value = 1
    ico_mat = n.new("GeometryNodeSetMaterial")
    ico_mat.inputs["Material"].default_value = _material("INSTANCER")
    link(ico.outputs["Mesh"], ico_mat.inputs["Geometry"])
    axes = n.new("ShaderNodeVectorMath")
    axes.operation = "SCALE"
    link(scale.outputs["Attribute"], axes.inputs[0])
    link(gi.outputs["Size"], axes.inputs["Scale"])
    as_points = n.new("GeometryNodeMeshToPoints")
    link(gi.outputs["Geometry"], as_points.inputs["Mesh"])
    inst = n.new("GeometryNodeInstanceOnPoints")
    link(as_points.outputs["Points"], inst.inputs["Points"])
    link(ico_mat.outputs["Geometry"], inst.inputs["Instance"])
    link(rot.outputs["Attribute"], inst.inputs["Rotation"])
    link(axes.outputs["Vector"], inst.inputs["Scale"])

    switch = n.new("GeometryNodeSwitch")
    switch.input_type = "GEOMETRY"
    link(gi.outputs["Ellipsoids"], switch.inputs["Switch"])
    link(sprite_mat.outputs["Geometry"], switch.inputs["False"])
    link(inst.outputs["Instances"], switch.inputs["True"])
    link(switch.outputs[0], go.inputs[0])
    return ng


@dataclass
class GaussianImport:
    object: bpy.types.Object
    count: int
    dropped: dict
    axes: str
    timings: dict = field(default_factory=dict)


def detect_axes(ply: splats.GaussianPly, keep) -> str:
    """"TRELLIS" for files shaped like TRELLIS/Amodal3R output (SH 0, normals, inside the unit cube), else "NONE"."""
    if ply.sh_degree != 0 or not {"nx", "ny", "nz"} <= set(ply.extra) or not keep.any():
        return "NONE"
    return "TRELLIS" if np.abs(ply.xyz[keep]).max() <= 0.5 + 1e-4 else "NONE"


def import_gaussians(context, filepath: str, axes: str = "AUTO", target_length: float | None = None,
                     ellipsoids: bool = False, name: str | None = None) -> GaussianImport:
    """Import a Gaussian PLY as an asset object at the 3D cursor; ``target_length`` metres along its longest
    horizontal axis (None: 4.5 m for a TRELLIS unit-cube asset, file units otherwise)."""
    t0 = time.perf_counter()
    filepath = os.path.abspath(bpy.path.abspath(filepath))
    ply = splats.read_ply(filepath)
    keep, dropped = splats.valid_rows(ply)
    if not keep.any():
        raise splats.SplatsError(filepath, f"no valid Gaussians ({len(ply)} rows, dropped {dropped})")
    if axes == "AUTO":
        axes = detect_axes(ply, keep)
    F = splats.TRELLIS_FILE_FROM_ZUP.T if axes == "TRELLIS" else np.eye(3)
    xyz = ply.xyz[keep].astype(np.float64) @ F.T
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    bottom = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    data_from_file = np.eye(4)
    data_from_file[:3, :3] = F
    data_from_file[:3, 3] = -bottom
    pos = (xyz - bottom).astype(np.float32)
    rot_raw = ply.rot[keep]
    q_unit = rot_raw.astype(np.float64) / np.linalg.norm(rot_raw.astype(np.float64), axis=1, keepdims=True)
    q_data = cameras.rotation_to_quaternion(F @ cameras.quaternion_to_rotation(q_unit))
    sigma = np.exp(ply.scale[keep].astype(np.float64))
    opacity = 1.0 / (1.0 + np.exp(-ply.opacity[keep].astype(np.float64)))
    rgba = _linear_rgba(np.clip(splats.SH_C0 * ply.f_dc[keep] + 0.5, 0.0, 1.0).astype(np.float32))
    rgba[:, 3] = opacity
    t_read = time.perf_counter()

    N = len(pos)
    stem = name or os.path.splitext(os.path.basename(filepath))[0]
    mesh = bpy.data.meshes.new(stem)
    mesh.vertices.add(N)
    mesh.attributes["position"].data.foreach_set("vector", pos.ravel())

    def put(attr_name, kind, values, prop):
        a = mesh.attributes.new(attr_name, kind, "POINT")  # written at once: a new attribute may move the others
        a.data.foreach_set(prop, np.ascontiguousarray(values, dtype=np.float32 if kind != "INT" else np.int32).ravel())

    sh = np.concatenate([ply.f_dc[keep][:, None, :], np.swapaxes(ply.f_rest[keep], 1, 2)], axis=1)
    for k in range(sh.shape[1]):
        put(f"sh_{k}", "FLOAT_VECTOR", sh[:, k], "vector")
    put("opacity", "FLOAT", ply.opacity[keep], "value")
    put("scale", "FLOAT_VECTOR", ply.scale[keep], "vector")
    put("rot", "QUATERNION", rot_raw, "value")
    for extra, values in ply.extra.items():
        is_int = np.issubdtype(values.dtype, np.integer)
        put(f"ply_{extra}", "INT" if is_int else "FLOAT", values[keep], "value")
    put("gs_rotation", "QUATERNION", q_data, "value")
    put("gs_scale", "FLOAT_VECTOR", sigma, "vector")
    col = mesh.color_attributes.new("gs_color", "FLOAT_COLOR", "POINT")
    col.data.foreach_set("color", rgba.ravel())
    mesh.update()

    obj = bpy.data.objects.new(stem, mesh)
    context.scene.collection.objects.link(obj)
    obj.location = context.scene.cursor.location
    extent = max(hi[0] - lo[0], hi[1] - lo[1])
    if target_length is None:
        target_length = TRELLIS_DEFAULT_LENGTH if axes == "TRELLIS" else extent
    if extent > 0:
        obj.scale = (target_length / extent,) * 3
    mod = obj.modifiers.new("SCPainter Gaussians", "NODES")
    mod.node_group = ensure_node_group()
    set_input(mod, "Ellipsoids", bool(ellipsoids))
    obj["scpainter_kind"] = "gaussian_asset"
    obj["scpainter_source"] = filepath
    obj["scpainter_data_from_file"] = data_from_file.ravel().tolist()
    obj["scpainter_axes"] = axes
    obj["scpainter_sh_degree"] = ply.sh_degree
    obj["scpainter_dropped"] = int(sum(dropped.values()))
    obj["scpainter_size"] = (hi - lo).tolist()  # data-frame extents (before the object's scale)
    obj["scpainter_review"] = "unchecked"
    t_end = time.perf_counter()
    return GaussianImport(obj, N, dropped, axes, {"read_decode": t_read - t0, "object": t_end - t_read,
                                                 "total": t_end - t0})


def preview_input(obj, name):
    mod = next(m for m in obj.modifiers if m.type == "NODES" and m.node_group
               and m.node_group.name.startswith(NODE_GROUP))
    return mod, _socket_identifier(mod.node_group, name)
