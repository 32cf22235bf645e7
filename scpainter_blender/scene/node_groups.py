"""Geometry Nodes groups of the add-on, built one way, and their modifiers' inputs read and set by name.

Each group (points preview, Gaussian preview, removal box) is versioned: ``ensure_group`` returns the group of
that name carrying ``scpainter_version`` = its version, or builds it. An older version (a .blend saved by an older
add-on) is left as it is for the modifiers that still use it; the new one takes Blender's next free name
(``"SCPainter Points.001"``), so modifiers are found by the group's name prefix (``find_modifier``).

The interface calls used here (``NodeTree.interface.new_socket``, ``items_tree``, socket ``default_value`` /
``min_value``) and every node type the groups use are the same from Blender 4.2 to 5.0: nothing here needs
``compat``.
"""

from __future__ import annotations

from dataclasses import dataclass

import bpy

from . import keys

VERSION_KEY = keys.VERSION


@dataclass(frozen=True)
class Socket:
    """One interface socket: its name, Blender socket type (``"NodeSocketFloat"``, ...), optional default and
    minimum (None: Blender's)."""

    name: str
    type: str
    default: object = None
    min: float | None = None


GEOMETRY = Socket("Geometry", "NodeSocketGeometry")


class Builder:
    """Adds nodes to a group and links them; ``group_input`` / ``group_output`` are its Group Input and Output.

    Nodes are laid out left to right in the order they are made (cosmetic: the node editor shows them so)."""

    def __init__(self, tree):
        self.tree = tree
        self.group_input = self.node("NodeGroupInput")
        self.group_output = self.node("NodeGroupOutput")

    def node(self, type_name: str, inputs: dict | None = None, **properties):
        """A new node of ``type_name``: ``properties`` set in the order given (a node's sockets can depend on
        them, e.g. ``data_type``), then ``inputs`` fed: socket name or index -> an output socket (linked) or a
        value (the socket's default)."""
        n = self.tree.nodes.new(type_name)
        n.location = (220.0 * (len(self.tree.nodes) - 1), 0.0)
        for key, value in properties.items():
            setattr(n, key, value)
        for key, value in (inputs or {}).items():
            self.feed(n.inputs[key], value)
        return n

    def feed(self, socket, value) -> None:
        """Link ``value`` into ``socket`` when it is an output socket, else set the socket's default to it."""
        if isinstance(value, bpy.types.NodeSocket):
            self.tree.links.new(value, socket)
        else:
            socket.default_value = value

    def math(self, operation: str, a, b=None):
        """A float Math node's result: ``a`` (and ``b``) sockets or numbers."""
        return self.node("ShaderNodeMath", {i: v for i, v in enumerate((a, b)) if v is not None},
                         operation=operation).outputs[0]

    def boolean(self, operation: str, a, b):
        """A Boolean Math node's result of sockets (or values) ``a`` and ``b``."""
        return self.node("FunctionNodeBooleanMath", {0: a, 1: b}, operation=operation).outputs[0]

    def output(self, socket) -> None:
        """Link ``socket`` to the group's (first) output."""
        self.feed(self.group_output.inputs[0], socket)


def find_group(name: str, version: int):
    """The node group called ``name`` (or a Blender copy, ``name.001`` ...) built at ``version``, or None."""
    exact = bpy.data.node_groups.get(name)
    if exact is not None and exact.get(VERSION_KEY) == version:
        return exact
    for ng in bpy.data.node_groups:
        if _is_copy(ng.name, name) and ng.get(VERSION_KEY) == version:
            return ng
    return None


def ensure_group(name: str, version: int, inputs, build, outputs=(GEOMETRY,)):
    """The Geometry Nodes group ``name`` at ``version``: found (``find_group``) or made now.

    A new group's interface is Geometry + ``inputs`` (Sockets) in and ``outputs`` out; ``build(builder)`` adds
    its nodes (a ``Builder``, whose ``group_input`` has an output per interface input).
    """
    ng = find_group(name, version)
    if ng is not None:
        return ng
    ng = bpy.data.node_groups.new(name, "GeometryNodeTree")
    ng[VERSION_KEY] = version
    for socket in (GEOMETRY, *inputs):
        _new_socket(ng, socket, "INPUT")
    for socket in outputs:
        _new_socket(ng, socket, "OUTPUT")
    build(Builder(ng))
    return ng


def _new_socket(ng, socket: Socket, in_out: str):
    s = ng.interface.new_socket(socket.name, in_out=in_out, socket_type=socket.type)
    if socket.default is not None:
        s.default_value = socket.default
    if socket.min is not None:
        s.min_value = socket.min
    return s


def _is_copy(candidate: str, name: str) -> bool:
    suffix = candidate[len(name):]
    return candidate.startswith(name) and len(suffix) == 4 and suffix[0] == "." and suffix[1:].isdigit()


# -- modifiers ---------------------------------------------------------------------------------------------------

def add_modifier(obj, name: str, group, inputs: dict | None = None):
    """A Geometry Nodes modifier ``name`` (last in the stack) on ``obj`` running ``group``, with ``inputs``
    (interface name -> value) set."""
    mod = obj.modifiers.new(name, "NODES")
    mod.node_group = group
    for key, value in (inputs or {}).items():
        set_input(mod, key, value)
    return mod


def find_modifiers(obj, group_name: str) -> list:
    """The Geometry Nodes modifiers of ``obj`` running the group ``group_name`` (or a copy of it), in stack order."""
    return [m for m in obj.modifiers
            if m.type == "NODES" and m.node_group is not None and m.node_group.name.startswith(group_name)]


def find_modifier(obj, group_name: str):
    """The first Geometry Nodes modifier of ``obj`` running the group ``group_name`` (or a copy of it), or None."""
    found = find_modifiers(obj, group_name)
    return found[0] if found else None


def socket_identifier(group, name: str) -> str:
    """The identifier of ``group``'s interface input ``name`` (the key of a modifier's input property)."""
    for item in group.interface.items_tree:
        if getattr(item, "in_out", None) == "INPUT" and item.name == name:
            return item.identifier
    raise KeyError(f"node group {group.name!r} has no input {name!r}")


def set_input(modifier, name: str, value) -> None:
    """Set a Geometry Nodes modifier input by its interface name."""
    modifier[socket_identifier(modifier.node_group, name)] = value


def get_input(modifier, name: str):
    """A Geometry Nodes modifier input's value, by its interface name."""
    return modifier[socket_identifier(modifier.node_group, name)]
