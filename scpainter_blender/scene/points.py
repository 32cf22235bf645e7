"""Coloured point clouds as Blender objects: one mesh of vertices drawn as points by Geometry Nodes.

A mesh filled with ``foreach_set`` and turned into points by "Mesh to Points" renders natively in Cycles and
EEVEE and scales to millions of points (instancing does not). Vertex positions are stored relative to the
object's origin, placed near the points, so float32 vertices keep millimetres 1e5 m from the world origin.
Attributes: ``point_color`` (FLOAT_COLOR, linear; the source images' sRGB values decoded), ``vggt_frame`` (INT,
source frame).
"""

from __future__ import annotations

import bpy
import numpy as np

from ..core import colors
from . import materials

NODE_GROUP = "SCPainter Points"
MATERIAL = "SCPainter Points"
NODE_GROUP_VERSION = 1
COLOR_ATTRIBUTE = "point_color"  # not "color": Cycles does not find a point-cloud attribute of that name
FRAME_ATTRIBUTE = "vggt_frame"

# name -> (socket type, default, min)
INPUTS = {
    "Point Radius": ("NodeSocketFloat", 0.03, 0.0),
    "Current Frame Only": ("NodeSocketBool", False, None),
    "Frame Window": ("NodeSocketInt", 0, 0),
    "Frame Offset": ("NodeSocketInt", 1, None),
    "Material": ("NodeSocketMaterial", None, None),
}


def ensure_material() -> bpy.types.Material:
    """An emission material showing the point colour as it is (display colour = source image colour)."""
    return materials.emission_material(MATERIAL, COLOR_ATTRIBUTE)


def ensure_node_group() -> bpy.types.NodeTree:
    """Geometry Nodes: optionally keep only the points of the current frame (± window), then Mesh to Points."""
    ng = bpy.data.node_groups.get(NODE_GROUP)
    if ng is not None and ng.get("scpainter_version") == NODE_GROUP_VERSION:
        return ng
    ng = bpy.data.node_groups.new(NODE_GROUP, "GeometryNodeTree")
    ng["scpainter_version"] = NODE_GROUP_VERSION
    iface = ng.interface
    iface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    for name, (stype, default, vmin) in INPUTS.items():
        s = iface.new_socket(name, in_out="INPUT", socket_type=stype)
        if default is not None:
            s.default_value = default
        if vmin is not None:
            s.min_value = vmin
    iface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")

    n, link = ng.nodes, ng.links.new
    gi, go = n.new("NodeGroupInput"), n.new("NodeGroupOutput")
    frame_attr = n.new("GeometryNodeInputNamedAttribute")
    frame_attr.data_type = "INT"
    frame_attr.inputs["Name"].default_value = FRAME_ATTRIBUTE
    time = n.new("GeometryNodeInputSceneTime")

    def math(op, a, b=None):
        m = n.new("ShaderNodeMath")
        m.operation = op
        for i, v in enumerate((a, b)):
            if v is None:
                continue
            if isinstance(v, (int, float)):
                m.inputs[i].default_value = v
            else:
                link(v, m.inputs[i])
        return m.outputs[0]

    # source frame shown now = scene frame - offset; drop points further than the window from it
    current = math("SUBTRACT", time.outputs["Frame"], gi.outputs["Frame Offset"])
    dist = math("ABSOLUTE", math("SUBTRACT", frame_attr.outputs["Attribute"], current))
    outside = math("GREATER_THAN", dist, math("ADD", gi.outputs["Frame Window"], 0.5))
    both = n.new("FunctionNodeBooleanMath")
    both.operation = "AND"
    link(gi.outputs["Current Frame Only"], both.inputs[0])
    link(outside, both.inputs[1])
    delete = n.new("GeometryNodeDeleteGeometry")
    delete.domain = "POINT"
    link(gi.outputs["Geometry"], delete.inputs["Geometry"])
    link(both.outputs[0], delete.inputs["Selection"])
    to_points = n.new("GeometryNodeMeshToPoints")
    link(delete.outputs["Geometry"], to_points.inputs["Mesh"])
    link(gi.outputs["Point Radius"], to_points.inputs["Radius"])
    set_mat = n.new("GeometryNodeSetMaterial")
    link(to_points.outputs["Points"], set_mat.inputs["Geometry"])
    link(gi.outputs["Material"], set_mat.inputs["Material"])
    link(set_mat.outputs["Geometry"], go.inputs[0])
    for i, node in enumerate((gi, frame_attr, time, delete, to_points, set_mat, go)):
        node.location = (i * 220 - 700, 0)
    return ng


def _socket_identifier(ng, name):
    for item in ng.interface.items_tree:
        if getattr(item, "in_out", None) == "INPUT" and item.name == name:
            return item.identifier
    raise KeyError(f"node group {ng.name!r} has no input {name!r}")


def set_input(modifier, name, value):
    """Set a Geometry Nodes modifier input by its interface name."""
    modifier[_socket_identifier(modifier.node_group, name)] = value


def get_input(modifier, name):
    return modifier[_socket_identifier(modifier.node_group, name)]


def points_modifier(obj):
    """The SCPainter points modifier of ``obj``, or None."""
    for m in obj.modifiers:
        if m.type == "NODES" and m.node_group is not None and m.node_group.name.startswith(NODE_GROUP):
            return m
    return None


def srgb_to_linear_lut(levels: int = 256) -> np.ndarray:
    """sRGB-encoded level -> linear value, tabulated (IEC 61966-2-1); 256 levels match 8-bit source images."""
    return colors.srgb_to_linear(np.linspace(0.0, 1.0, levels)).astype(np.float32)


_LUT = srgb_to_linear_lut()
_CHUNK = 1 << 20  # points per chunk: temporaries stay small and warm in cache instead of page-faulting GBs


def _local_float32(positions, origin):
    """float32 (positions - origin), subtracted in float64 chunk by chunk (1e5 m coordinates stay exact)."""
    out = np.empty(positions.shape, np.float32)
    for a in range(0, len(positions), _CHUNK):
        out[a:a + _CHUNK] = positions[a:a + _CHUNK] - origin
    return out


def _linear_rgba(colors):
    """Linear RGBA float32 (alpha 1) of sRGB-encoded colours in [0, 1], through the 8-bit table."""
    out = np.empty((len(colors), 4), np.float32)
    out[:, 3] = 1.0
    top = np.float32(len(_LUT) - 1)
    for a in range(0, len(colors), _CHUNK):
        q = np.clip(colors[a:a + _CHUNK], 0.0, 1.0) * top + np.float32(0.5)
        out[a:a + _CHUNK, :3] = _LUT[q.astype(np.uint8)]
    return out


def create_point_cloud(name: str, positions, colors, frame, collection, radius: float = 0.03,
                       frame_offset: int = 1) -> bpy.types.Object:
    """A point-cloud object from world positions (N, 3) float64, sRGB colours (N, 3) in [0, 1], frames (N,).

    Everything is written with ``foreach_set`` in bulk: no per-point Python. Colours go in as linear
    FLOAT_COLOR (a straight copy; Blender's per-element sRGB conversion for BYTE_COLOR is ten times slower).
    """
    positions = np.asarray(positions, dtype=np.float64)
    N = len(positions)
    # near the points, and a whole number of metres so float32 stores it exactly; a subsample is enough
    origin = np.round(positions[:: max(1, N // 4096)].mean(axis=0)) if N else np.zeros(3)
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(N)
    # write each attribute right after creating it: adding another may move the others' storage
    if N:  # an empty mesh has no position attribute at all
        mesh.attributes["position"].data.foreach_set("vector", _local_float32(positions, origin).ravel())
    col = mesh.color_attributes.new(COLOR_ATTRIBUTE, "FLOAT_COLOR", "POINT")
    if N:
        col.data.foreach_set("color", _linear_rgba(np.asarray(colors, np.float32)).ravel())
    fa = mesh.attributes.new(FRAME_ATTRIBUTE, "INT", "POINT")
    if N:
        fa.data.foreach_set("value", np.asarray(frame, dtype=np.int32))
    col = mesh.color_attributes[COLOR_ATTRIBUTE]
    mesh.color_attributes.active_color = col
    mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index
    mesh.update()

    obj = bpy.data.objects.new(name, mesh)
    obj.location = origin.tolist()
    collection.objects.link(obj)
    mod = obj.modifiers.new("SCPainter Points", "NODES")
    mod.node_group = ensure_node_group()
    mat = ensure_material()
    set_input(mod, "Point Radius", float(radius))
    set_input(mod, "Frame Offset", int(frame_offset))
    set_input(mod, "Material", mat)
    mesh.materials.append(mat)
    return obj
