"""scene.node_groups: versioned Geometry Nodes groups built once, older versions left to their modifiers, and
modifier inputs by interface name."""

import bpy
import pytest

from scpainter_blender.scene import node_groups as NG

INPUTS = (NG.Socket("Radius", "NodeSocketFloat", 0.25, 0.0), NG.Socket("Only", "NodeSocketBool", True),
          NG.Socket("Box", "NodeSocketObject"))


def _build(b):
    radius = b.math("MULTIPLY", b.group_input.outputs["Radius"], 2.0)
    to_points = b.node("GeometryNodeMeshToPoints", {"Mesh": b.group_input.outputs["Geometry"], "Radius": radius})
    b.output(to_points.outputs["Points"])


def test_group_built_once_per_version(empty_scene):
    ng = NG.ensure_group("Test Group", 1, INPUTS, _build)
    assert ng.name == "Test Group" and ng[NG.VERSION_KEY] == 1
    assert NG.ensure_group("Test Group", 1, INPUTS, _build) == ng
    items = [(i.in_out, i.name, i.socket_type) for i in ng.interface.items_tree]
    assert [i for i in items if i[0] == "INPUT"] == [
        ("INPUT", "Geometry", "NodeSocketGeometry"), ("INPUT", "Radius", "NodeSocketFloat"),
        ("INPUT", "Only", "NodeSocketBool"), ("INPUT", "Box", "NodeSocketObject")]
    assert [i for i in items if i[0] == "OUTPUT"] == [("OUTPUT", "Geometry", "NodeSocketGeometry")]
    radius = next(i for i in ng.interface.items_tree if i.name == "Radius")
    assert radius.default_value == 0.25 and radius.min_value == 0.0
    math = next(n for n in ng.nodes if n.bl_idname == "ShaderNodeMath")
    assert math.operation == "MULTIPLY" and math.inputs[1].default_value == 2.0 and math.inputs[0].is_linked
    assert ng.nodes["Group Output"].inputs[0].links[0].from_node.bl_idname == "GeometryNodeMeshToPoints"
    # a newer version: the old group stays for the modifiers that use it, the new one takes the next name
    obj = bpy.data.objects.new("holder", bpy.data.meshes.new("holder"))
    empty_scene.collection.objects.link(obj)
    old = NG.add_modifier(obj, "Old", ng, {"Radius": 0.5})
    new_ng = NG.ensure_group("Test Group", 2, INPUTS, _build)
    assert new_ng.name == "Test Group.001" and old.node_group == ng and NG.get_input(old, "Radius") == 0.5
    assert NG.ensure_group("Test Group", 2, INPUTS, _build) == new_ng  # found again, not a third copy
    assert NG.find_modifier(obj, "Test Group") == old and NG.find_modifier(obj, "Other") is None


def test_modifier_inputs_by_name(empty_scene):
    ng = NG.ensure_group("Test Inputs", 1, INPUTS, _build)
    obj = bpy.data.objects.new("holder", bpy.data.meshes.new("holder"))
    box = bpy.data.objects.new("box", None)
    mod = NG.add_modifier(obj, "Preview", ng, {"Only": False, "Box": box})
    assert not NG.get_input(mod, "Only")  # its default is True
    assert NG.get_input(mod, "Box") == box and NG.get_input(mod, "Radius") == 0.25
    NG.set_input(mod, "Radius", 1.5)
    assert mod[NG.socket_identifier(ng, "Radius")] == 1.5
    with pytest.raises(KeyError, match="has no input 'Size'"):
        NG.set_input(mod, "Size", 1.0)
