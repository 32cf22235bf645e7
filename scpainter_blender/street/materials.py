"""Materials and worlds of the procedural street (bpy): plain and textured surfaces, the sky, and the emission
override that the depth pass renders with.

Textures are procedural (noise, brick) and seeded, so the street renders the same on every machine; the depth
override emits (camera z in metres, object pass index, 1) for a one-sample pass read back from a float EXR.
"""

from __future__ import annotations

import bpy

from ..scene.compat import node_tree


def _material(name):
    mat = bpy.data.materials.new(name)
    nt = node_tree(mat)
    bsdf = next(n for n in nt.nodes if n.type == "BSDF_PRINCIPLED")
    return mat, nt, bsdf


def plain(name, color, roughness=0.6, metallic=0.0):
    mat, _, bsdf = _material(name)
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    mat.diffuse_color = (*color, 1.0)
    return mat


def asphalt(name, seed):
    """Dark grey with fine noise and larger stains, so the road has texture to see alignment against."""
    mat, nt, bsdf = _material(name)
    tc = nt.nodes.new("ShaderNodeTexCoord")
    fine = nt.nodes.new("ShaderNodeTexNoise")
    fine.inputs["Scale"].default_value = 3.0
    fine.inputs["Detail"].default_value = 3.0  # each octave costs: 3 keep a CPU render of the drive cheap
    mapping = nt.nodes.new("ShaderNodeMapping")  # the seed moves the noise field
    mapping.inputs["Location"].default_value = (17.0 * seed, 0.0, 0.0)
    nt.links.new(tc.outputs["Object"], mapping.inputs["Vector"])
    nt.links.new(mapping.outputs["Vector"], fine.inputs["Vector"])
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.035, 0.035, 0.038, 1)
    ramp.color_ramp.elements[1].color = (0.16, 0.16, 0.165, 1)
    nt.links.new(fine.outputs["Fac"], ramp.inputs["Fac"])
    nt.links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.9
    return mat


def facade(name, wall, glass=(0.04, 0.06, 0.09), window=(1.6, 1.4)):
    """A wall with a grid of dark windows: a brick texture whose bricks are the windows, mortar the wall."""
    mat, nt, bsdf = _material(name)
    tc = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    comb = nt.nodes.new("ShaderNodeCombineXYZ")
    nt.links.new(tc.outputs["Object"], sep.inputs["Vector"])
    nt.links.new(sep.outputs["Y"], comb.inputs["X"])  # facades face ±X: windows tile the (y, z) plane
    nt.links.new(sep.outputs["Z"], comb.inputs["Y"])
    brick = nt.nodes.new("ShaderNodeTexBrick")
    brick.offset = 0.0
    brick.inputs["Scale"].default_value = 1.0
    brick.inputs["Brick Width"].default_value = window[0]
    brick.inputs["Row Height"].default_value = window[1]
    brick.inputs["Mortar Size"].default_value = 0.45
    brick.inputs["Color1"].default_value = (*glass, 1)
    brick.inputs["Color2"].default_value = tuple(c * 1.4 for c in glass) + (1,)
    brick.inputs["Mortar"].default_value = (*wall, 1)
    nt.links.new(comb.outputs["Vector"], brick.inputs["Vector"])
    nt.links.new(brick.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.7
    mat.diffuse_color = (*wall, 1.0)
    return mat


def sky_world(name="SCPainter street sky"):
    world = bpy.data.worlds.new(name)
    nt = node_tree(world, clear=True)
    tc = nt.nodes.new("ShaderNodeTexCoord")
    sep = nt.nodes.new("ShaderNodeSeparateXYZ")
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].position = 0.0
    ramp.color_ramp.elements[0].color = (0.75, 0.82, 0.92, 1)
    ramp.color_ramp.elements[1].position = 0.5
    ramp.color_ramp.elements[1].color = (0.22, 0.42, 0.85, 1)
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = 1.0
    out = nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(tc.outputs["Generated"], sep.inputs["Vector"])  # world "Generated" = view direction
    nt.links.new(sep.outputs["Z"], ramp.inputs["Fac"])
    nt.links.new(ramp.outputs["Color"], bg.inputs["Color"])
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    world.cycles.sampling_method = "NONE"
    return world


def black_world():
    world = bpy.data.worlds.new("SCPainter black")
    bg = next(n for n in node_tree(world).nodes if n.type == "BACKGROUND")
    bg.inputs["Color"].default_value = (0, 0, 0, 1)
    bg.inputs["Strength"].default_value = 0.0
    return world


def depth_override():
    """Emission of (camera z in metres, object pass index, 1): read back from a float EXR."""
    mat = bpy.data.materials.new("SCPainter depth override")
    nt = node_tree(mat, clear=True)
    camdata = nt.nodes.new("ShaderNodeCameraData")
    info = nt.nodes.new("ShaderNodeObjectInfo")
    comb = nt.nodes.new("ShaderNodeCombineColor")
    emit = nt.nodes.new("ShaderNodeEmission")
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(camdata.outputs["View Z Depth"], comb.inputs[0])
    nt.links.new(info.outputs["Object Index"], comb.inputs[1])
    comb.inputs[2].default_value = 1.0
    nt.links.new(comb.outputs[0], emit.inputs["Color"])
    emit.inputs["Strength"].default_value = 1.0
    nt.links.new(emit.outputs[0], out.inputs["Surface"])
    return mat
