"""Materials that show a colour attribute as it is (emission), optionally blended by its alpha."""

from __future__ import annotations

import bpy

from . import compat


def emission_material(name: str, attribute: str, attribute_type: str = "GEOMETRY",
                      alpha: bool = False) -> bpy.types.Material:
    """Emission of ``attribute`` (a colour attribute) so renders show the stored colour unlit; with ``alpha``, mixed
    with transparency by the attribute's alpha. ``attribute_type`` "INSTANCER" reads it from an instance's point.
    Created once per name."""
    mat = bpy.data.materials.get(name)
    if mat is not None:
        return mat
    mat = bpy.data.materials.new(name)
    nt = compat.node_tree(mat, clear=True)
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_type = attribute_type
    attr.attribute_name = attribute
    emit = nt.nodes.new("ShaderNodeEmission")
    emit.inputs["Strength"].default_value = 1.0
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(attr.outputs["Color"], emit.inputs["Color"])
    shader = emit.outputs[0]
    if alpha:
        clear = nt.nodes.new("ShaderNodeBsdfTransparent")
        mix = nt.nodes.new("ShaderNodeMixShader")
        nt.links.new(attr.outputs["Alpha"], mix.inputs["Fac"])
        nt.links.new(clear.outputs[0], mix.inputs[1])
        nt.links.new(emit.outputs[0], mix.inputs[2])
        shader = mix.outputs[0]
        if hasattr(mat, "surface_render_method"):  # EEVEE Next (4.2+): sort and blend, don't dither
            mat.surface_render_method = "BLENDED"
    nt.links.new(shader, out.inputs["Surface"])
    for i, node in enumerate(nt.nodes):
        node.location = (i * 200 - 400, 0)
    return mat
