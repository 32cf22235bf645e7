"""scene/kinds.py: the one place the kinds of scene object are named, and its finders."""

import ast
import os

import pytest

from scpainter_blender.scene import kinds

HOME = os.path.join("scpainter_blender", "scene", "kinds.py")
#: Everything but the tests: the extension, the backend and the tools and benchmarks that drive the add-on
#: (what ``tests_support.tracked_sources`` lists).
SHIPPED = ("__init__.py", "operators", "panels", "scpainter_blender", "backend", "tools", "bench")
#: Where the objects are (the Blender layer): there a kind's value is never compared with or assigned. Elsewhere
#: "points" is an ordinary word (a dict key, a task name); reading a kind there needs the property name, checked
#: in all of SHIPPED.
BLENDER_SIDE = ("__init__.py", "operators", "panels", os.path.join("scpainter_blender", "scene"))


def test_stored_values_never_change():
    """Saved .blend files hold these strings: renaming one loses every object of that kind."""
    assert kinds.PROPERTY == "scpainter_kind"
    assert kinds.ALL == ("points", "recorded_camera", "camera_path", "gaussian_asset", "removal_box", "asset_box",
                         "asset_front", "recorded_object", "proposal", "rig", "rig_camera", "rig_lidar")


class _Obj(dict):
    """What the finders use of a Blender object: ``get``, item assignment, ``parent`` and ``children``."""

    def __init__(self, parent=None, **kw):
        super().__init__(**kw)
        self.parent, self.children = parent, []
        if parent is not None:
            parent.children.append(self)


class _Scene:
    def __init__(self, *objects):
        self.objects = list(objects)


def test_mark_and_find():
    pts, cam, path, box, other = _Obj(), _Obj(), _Obj(), _Obj(), _Obj(name="mine")
    a1, a2 = _Obj(), _Obj()
    for obj, kind in ((pts, kinds.POINTS), (cam, kinds.RECORDED_CAMERA), (path, kinds.CAMERA_PATH),
                      (box, kinds.REMOVAL_BOX), (a1, kinds.GAUSSIAN_ASSET), (a2, kinds.GAUSSIAN_ASSET)):
        kinds.mark(obj, kind)
    assert cam == {"scpainter_kind": "recorded_camera"}
    scene = _Scene(other, a1, path, cam, pts, box, a2)
    assert kinds.point_cloud(scene) is pts and kinds.recorded_camera(scene) is cam
    assert kinds.gaussian_assets(scene) == [a1, a2] and kinds.removal_boxes(scene) == [box]
    assert kinds.objects_of_kind(scene, kinds.CAMERA_PATH) == [path]
    assert kinds.kind_of(other) is None and kinds.kind_of(None) is None
    assert not kinds.is_kind(None, kinds.POINTS) and kinds.is_kind(cam, kinds.POINTS, kinds.RECORDED_CAMERA)
    # the active object or scene camera first when it is a recorded camera, else the first in the scene
    cam2 = _Obj()
    kinds.mark(cam2, kinds.RECORDED_CAMERA)
    assert kinds.recorded_camera(scene, prefer=(None, path, cam2)) is cam2
    assert kinds.recorded_camera(scene, prefer=(None, path)) is cam
    assert kinds.point_cloud(_Scene(other)) is None and kinds.recorded_camera(_Scene(), prefer=(None,)) is None
    with pytest.raises(ValueError, match="unknown scene object kind 'point'"):
        kinds.mark(_Obj(), "point")


def test_asset_box_finders():
    asset, lone = _Obj(), _Obj()
    kinds.mark(asset, kinds.GAUSSIAN_ASSET)
    other_child = _Obj(asset)
    box = _Obj(asset)
    front = _Obj(box)
    kinds.mark(box, kinds.ASSET_BOX)
    kinds.mark(front, kinds.ASSET_FRONT)
    assert kinds.asset_box(asset) is box and kinds.asset_front(box) is front
    assert kinds.asset_box(lone) is None and kinds.asset_box(None) is None and kinds.asset_front(other_child) is None
    assert kinds.owning_asset(asset) is asset and kinds.owning_asset(box) is asset
    assert kinds.owning_asset(front) is asset
    assert kinds.owning_asset(other_child) is None and kinds.owning_asset(None) is None
    kinds.mark(lone, kinds.ASSET_BOX)  # a box whose asset is gone (unparented)
    assert kinds.owning_asset(lone) is None


def _spelled_kinds(source, name, values=True):
    """Sorted (line, what) for each place ``source`` spells the vocabulary itself: the property name anywhere, or
    (``values``) a kind's value compared with (``== "points"``, ``in ("points", ...)``) or assigned as an item
    (``obj[...] = "points"``)."""
    found = []

    def kind_constants(node):
        elts = node.elts if isinstance(node, (ast.Tuple, ast.List, ast.Set)) else [node]
        return [e for e in elts if isinstance(e, ast.Constant) and e.value in kinds.ALL]

    for node in ast.walk(ast.parse(source, name)):
        if isinstance(node, ast.Constant) and node.value == kinds.PROPERTY:
            found.append((node.lineno, kinds.PROPERTY))
        elif values and isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            found += [(c.lineno, c.value) for operand in operands for c in kind_constants(operand)]
        elif values and isinstance(node, ast.Assign) and any(isinstance(t, ast.Subscript) for t in node.targets):
            found += [(c.lineno, c.value) for c in kind_constants(node.value)]
    return sorted(found)


def test_the_check_sees_each_spelling():
    src = ('a = o.get("scpainter_kind")\nb = o.get(k) == "points"\nc = k in ("x", "removal_box")\n'
           'o["k"] = "gaussian_asset"\nd = {"points": 1, "camera_path": 2}\n')
    assert _spelled_kinds(src, "x.py") == [(1, "scpainter_kind"), (2, "points"), (3, "removal_box"),
                                           (4, "gaussian_asset")]
    assert _spelled_kinds(src, "x.py", values=False) == [(1, "scpainter_kind")]


def test_kinds_are_spelled_only_in_their_module():
    """Code names kinds through scene/kinds.py (its constants and finders), never by their strings."""
    from tests_support import tracked_sources

    sources = tracked_sources()  # every tracked .py outside tests/ (SHIPPED)
    assert HOME.replace(os.sep, "/") in sources and "operators/placement.py" in sources
    assert {rel.split("/")[0] for rel in sources} <= set(SHIPPED)
    spelled = {}
    for rel, text in sources.items():
        if rel != HOME.replace(os.sep, "/"):
            found = _spelled_kinds(text, rel, values=rel.startswith(BLENDER_SIDE))
            if found:
                spelled[rel] = found
    assert spelled == {}


def test_rig_finders():
    """A camera path's rig is its child of kind ``rig``; the rig's cameras and LiDAR come in their stored order
    (``scpainter_sensor_index``), whatever order Blender lists the children in, unnumbered ones last by name."""
    path, lone = _Obj(), _Obj()
    rig = _Obj(path)
    _Obj(path)  # another child of the path
    made = {}
    for name, index, kind in (("CAM_BACK", 3, kinds.RIG_CAMERA), ("LIDAR_TOP", 6, kinds.RIG_LIDAR),
                              ("CAM_FRONT", 0, kinds.RIG_CAMERA), ("EXTRA", None, kinds.RIG_CAMERA),
                              ("CAM_FRONT_LEFT", 2, kinds.RIG_CAMERA)):
        o = made[name] = _Obj(rig)
        o.name = name
        kinds.mark(o, kind)
        if index is not None:
            o["scpainter_sensor_index"] = index
    kinds.mark(rig, kinds.RIG)
    assert kinds.rig_of(path) is rig and kinds.rig_of(lone) is None and kinds.rig_of(None) is None
    assert [o.name for o in kinds.rig_sensors(rig, kinds.RIG_CAMERA)] == ["CAM_FRONT", "CAM_FRONT_LEFT", "CAM_BACK",
                                                                          "EXTRA"]
    assert kinds.rig_sensors(rig, kinds.RIG_LIDAR) == [made["LIDAR_TOP"]] and kinds.rig_sensors(None, kinds.RIG) == []
