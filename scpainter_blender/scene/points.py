"""Coloured point clouds as Blender objects: one mesh of vertices drawn as points by Geometry Nodes.

A mesh filled with ``foreach_set`` and turned into points by "Mesh to Points" renders natively in Cycles and
EEVEE and scales to millions of points (instancing does not). Vertex positions are stored relative to the
object's origin, placed near the points, so float32 vertices keep millimetres 1e5 m from the world origin.
Attributes: ``point_color`` (FLOAT_COLOR, linear; the source images' sRGB values decoded), ``vggt_frame`` (INT,
source frame), and for a multi-camera recording ``scene_frame`` (INT, the scene frame offset of the point's source
frame: ``core.vggt.sensors.Sensors.scene_frames``; without it source frame i is scene frame offset i). *Current Frame
Only* keeps the points whose scene frame offset lies within the window of the current one, so a multi-camera
recording shows every sensor's frame grouped at the current scene frame.
"""

from __future__ import annotations

import bpy
import numpy as np

from ..core import colors
from ..core.vggt import sensors as sensors_mod
from . import keys, materials, node_groups

NODE_GROUP = "SCPainter Points"
MATERIAL = "SCPainter Points"
NODE_GROUP_VERSION = 2  # 2: Current Frame Only by ``scene_frame`` where the points have it
COLOR_ATTRIBUTE = "point_color"  # not "color": Cycles does not find a point-cloud attribute of that name
FRAME_ATTRIBUTE = "vggt_frame"
SCENE_FRAME_ATTRIBUTE = "scene_frame"

INPUTS = (
    node_groups.Socket("Point Radius", "NodeSocketFloat", 0.03, 0.0),
    node_groups.Socket("Current Frame Only", "NodeSocketBool", False),
    node_groups.Socket("Frame Window", "NodeSocketInt", 0, 0),
    node_groups.Socket("Frame Offset", "NodeSocketInt", 1),
    node_groups.Socket("Material", "NodeSocketMaterial"),
)


def ensure_material() -> bpy.types.Material:
    """An emission material showing the point colour as it is (display colour = source image colour)."""
    return materials.emission_material(MATERIAL, COLOR_ATTRIBUTE)


def ensure_node_group() -> bpy.types.NodeTree:
    """Geometry Nodes: optionally keep only the points of the current frame (± window), then Mesh to Points."""
    return node_groups.ensure_group(NODE_GROUP, NODE_GROUP_VERSION, INPUTS, _build_node_group)


def _build_node_group(b: node_groups.Builder) -> None:
    gi = b.group_input
    vggt_frame = b.node("GeometryNodeInputNamedAttribute", {"Name": FRAME_ATTRIBUTE}, data_type="INT")
    scene_frame = b.node("GeometryNodeInputNamedAttribute", {"Name": SCENE_FRAME_ATTRIBUTE}, data_type="INT")
    # a point's scene frame offset: its own where the recording has several cameras, else its source frame's
    frame = b.node("GeometryNodeSwitch", {"Switch": scene_frame.outputs["Exists"],
                                          "False": vggt_frame.outputs["Attribute"],
                                          "True": scene_frame.outputs["Attribute"]}, input_type="INT")
    time = b.node("GeometryNodeInputSceneTime")
    # scene frame offset shown now = scene frame - offset; drop points further than the window from it
    current = b.math("SUBTRACT", time.outputs["Frame"], gi.outputs["Frame Offset"])
    dist = b.math("ABSOLUTE", b.math("SUBTRACT", frame.outputs["Output"], current))
    outside = b.math("GREATER_THAN", dist, b.math("ADD", gi.outputs["Frame Window"], 0.5))
    delete = b.node("GeometryNodeDeleteGeometry", {"Geometry": gi.outputs["Geometry"],
                                                   "Selection": b.boolean("AND", gi.outputs["Current Frame Only"],
                                                                          outside)}, domain="POINT")
    to_points = b.node("GeometryNodeMeshToPoints", {"Mesh": delete.outputs["Geometry"],
                                                    "Radius": gi.outputs["Point Radius"]})
    b.output(b.node("GeometryNodeSetMaterial", {"Geometry": to_points.outputs["Points"],
                                                "Material": gi.outputs["Material"]}).outputs["Geometry"])


def scene_frame_offsets(obj) -> np.ndarray:
    """(S,) int64 per VGGT frame of the points object ``obj`` its scene frame offset from the import's first frame:
    a multi-camera recording's ``keys.SCENE_FRAMES`` (several sensors' frames share one), else 0 ... S − 1 (S its
    ``keys.NUM_FRAMES``; 0 when unknown)."""
    if keys.SCENE_FRAMES in obj:
        return np.array([int(v) for v in obj[keys.SCENE_FRAMES]], np.int64)
    return np.arange(int(obj.get(keys.NUM_FRAMES, 0)), dtype=np.int64)


def num_scene_frames(obj) -> int:
    """The scene frames the recording of points object ``obj`` spans (the frame range the import set): the last
    scene frame offset + 1 (``scene_frame_offsets``); a single-camera recording's VGGT frame count."""
    offsets = scene_frame_offsets(obj)
    return int(offsets.max()) + 1 if len(offsets) else 0


def camera_frames(obj) -> dict:
    """{sensor: (n,) its VGGT frame indices} of the points object ``obj``, one entry per recorded camera the import
    made, the reference sensor's first: a multi-camera recording's ``keys.FRAME_SENSORS`` through
    ``core.vggt.sensors.camera_frames`` (the import's own grouping), else {"": 0 ... S − 1} (its one camera). None
    for a multi-camera recording imported before the sensors were stored (import it again)."""
    if keys.FRAME_SENSORS in obj:
        return sensors_mod.camera_frames([str(v) for v in obj[keys.FRAME_SENSORS]])
    if keys.SCENE_FRAMES in obj:
        return None
    return {"": np.arange(int(obj.get(keys.NUM_FRAMES, 0)), dtype=np.int64)}


def points_modifier(obj):
    """The SCPainter points modifier of ``obj``, or None."""
    return node_groups.find_modifier(obj, NODE_GROUP)


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


def linear_rgba(colors):
    """Linear RGBA float32 (alpha 1) of sRGB-encoded colours in [0, 1], through the 8-bit table."""
    out = np.empty((len(colors), 4), np.float32)
    out[:, 3] = 1.0
    top = np.float32(len(_LUT) - 1)
    for a in range(0, len(colors), _CHUNK):
        q = np.clip(colors[a:a + _CHUNK], 0.0, 1.0) * top + np.float32(0.5)
        out[a:a + _CHUNK, :3] = _LUT[q.astype(np.uint8)]
    return out


def create_point_cloud(name: str, positions, colors, frame, collection, radius: float = 0.03,
                       frame_offset: int = 1, scene_frame=None) -> bpy.types.Object:
    """A point-cloud object from world positions (N, 3) float64, sRGB colours (N, 3) in [0, 1], frames (N,) and,
    for a multi-camera recording, scene frame offsets (N,) (``SCENE_FRAME_ATTRIBUTE``; None: none written).

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
        col.data.foreach_set("color", linear_rgba(np.asarray(colors, np.float32)).ravel())
    fa = mesh.attributes.new(FRAME_ATTRIBUTE, "INT", "POINT")
    if N:
        fa.data.foreach_set("value", np.asarray(frame, dtype=np.int32))
    if scene_frame is not None:
        sa = mesh.attributes.new(SCENE_FRAME_ATTRIBUTE, "INT", "POINT")
        if N:
            sa.data.foreach_set("value", np.asarray(scene_frame, dtype=np.int32))
    col = mesh.color_attributes[COLOR_ATTRIBUTE]
    mesh.color_attributes.active_color = col
    mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index
    mesh.update()

    obj = bpy.data.objects.new(name, mesh)
    obj.location = origin.tolist()
    collection.objects.link(obj)
    mat = ensure_material()
    node_groups.add_modifier(obj, "SCPainter Points", ensure_node_group(),
                             {"Point Radius": float(radius), "Frame Offset": int(frame_offset), "Material": mat})
    mesh.materials.append(mat)
    return obj
