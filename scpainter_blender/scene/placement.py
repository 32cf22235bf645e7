"""Placing Gaussian car assets: fit to a car size, snap to the ground (keyed on an animated car), replace a
recorded car, review.

Asset convention (scene/gaussians.py): data frame Z up, origin at the bottom centre; the *length* is the longer of
the two horizontal extents. Removal boxes are cube empties (display size 1, so the box spans ±scale along each
local axis, length along local Y); their points are removed from the reconstruction by a Geometry Nodes modifier
on the points object, placed before the points preview, and exported to the job (``scene.removal_boxes``: the
boxes the exported points object's modifiers apply, ``applied_removal_boxes``).
Every cube empty (removal boxes, asset boxes of scene/asset_box.py) becomes a box through ``cube_matrix``.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix, Quaternion, Vector

from ..core.geometry import boxes, fits as geometry
from . import compat, keys, kinds, node_groups
from . import points as points_mod
from .props import SceneError

REMOVAL_GROUP = "SCPainter Removal Box"
REMOVAL_GROUP_VERSION = 1
DEFAULT_CAR = (4.5, 1.9, 1.6)  # length, width, height in metres: a mid-size car
STAGE1_TOLERANCE = 0.2


def asset_size(obj) -> np.ndarray:
    """(length, width, height) of an asset in its data frame (before the object's scale)."""
    sx, sy, sz = obj[keys.SIZE]
    return np.array([max(sx, sy), min(sx, sy), sz])


def proportions(obj) -> np.ndarray:
    """(length, width, height) for the stage-1 check: trimesh's upright oriented box where the import measured it
    (mesh assets: right for cars not aligned with an axis), else the data-frame bounds (asset_size)."""
    if keys.OBB_SIZE in obj:
        return np.array(obj[keys.OBB_SIZE], np.float64)
    return asset_size(obj)


def _length_axis(obj) -> int:
    sx, sy, _ = obj[keys.SIZE]
    return 1 if sy >= sx else 0


def fit_size(obj, length: float, width: float | None = None, height: float | None = None, uniform: bool = True):
    """Scale an asset to a car size: uniformly to ``length``, or per axis to (length, width, height). SceneError
    for a size that is not positive or an asset without extent along an axis to scale."""
    L, Wd, H = asset_size(obj)
    if not length > 0:
        raise SceneError("length", f"the length to fit must be positive, got {length}")
    if not L > 0:
        raise SceneError(f"objects[{obj.name!r}]", "the asset has no length to scale",
                         hint="import the file again")
    if uniform or width is None or height is None:
        obj.scale = (length / L,) * 3
        return
    if not (width > 0 and height > 0):
        raise SceneError("width" if not width > 0 else "height", "the width and height to fit must be positive")
    if not (Wd > 0 and H > 0):
        raise SceneError(f"objects[{obj.name!r}]", "the asset is flat (no width or height): scale it uniformly",
                         hint="turn on Keep Proportions")
    scale = [0.0, 0.0, height / H]
    axis = _length_axis(obj)
    scale[axis], scale[1 - axis] = length / L, width / Wd
    obj.scale = scale


def scene_points_world(points_obj) -> np.ndarray:
    """World positions (N, 3) float64 of a points object's vertices (before its removal modifiers)."""
    n = len(points_obj.data.vertices)
    co = np.empty(n * 3, np.float32)
    if n:
        points_obj.data.attributes["position"].data.foreach_get("vector", co)
    M = np.array(points_obj.matrix_world, dtype=np.float64)
    return co.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3]


def cube_matrix(empty, matrix=None) -> np.ndarray:
    """The affine (4, 4) that maps the unit cube [−0.5, 0.5]³ onto the box a cube empty draws: ``matrix`` (default
    its ``matrix_world``) times 2 · ``empty_display_size`` (a cube empty draws [−size, size]³ in its own axes).
    The one place a cube empty becomes a box: removal boxes (display size 1) and asset boxes (0.5,
    scene/asset_box.py) both go through it."""
    M = np.array(empty.matrix_world if matrix is None else matrix, dtype=np.float64)
    M[:3, :3] *= 2.0 * empty.empty_display_size
    return M


def box_matrix(box) -> tuple:
    """(rigid box_to_world 4x4, full size (3,) metres) of a cube empty (a removal box, an asset box): the nearest
    rigid box (``boxes.rigid_box``) of its ``cube_matrix``."""
    return boxes.rigid_box(cube_matrix(box))


def snap_to_ground(context, obj, points_obj, margin: float = 1.0, align: bool = True, threshold: float = 0.05):
    """Put the asset's bottom centre on the ground plane fitted to the scene points around its footprint.

    Points inside removal boxes (the car being replaced) are left out. ``align`` tilts the asset's up axis to
    the plane normal, keeping its heading. Returns the plane and the number of points it was fitted to.
    SceneError naming the asset when there are too few points around it or they hold no level plane.
    """
    context.view_layer.update()
    P = scene_points_world(points_obj)
    M = np.array(obj.matrix_world, dtype=np.float64)
    size = np.array(obj[keys.SIZE], np.float64)
    corners = np.array([[sx, sy, 0.0] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5)]) * size
    foot = corners @ M[:3, :3].T + M[:3, 3]
    lo, hi = foot[:, :2].min(0) - margin, foot[:, :2].max(0) + margin
    sel = np.all((P[:, :2] >= lo) & (P[:, :2] <= hi), axis=1)
    for box in kinds.removal_boxes(context.scene):
        if sel.any():
            T, s = box_matrix(box)
            sel[sel] &= ~geometry.points_in_box(P[sel], T, s)
    near = P[sel]
    if len(near) < 20:
        raise SceneError(f"objects[{obj.name!r}]", f"only {len(near)} scene points under the asset",
                         hint="move it over the reconstructed road, or widen the margin")
    try:
        plane, inliers, _ = geometry.fit_plane_ransac(near, threshold=threshold)
    except geometry.PlaneFitError as e:  # the points around it hold no plane (a wall, a line of points)
        raise SceneError(f"objects[{obj.name!r}]", f"no ground plane among the {len(near)} scene points under "
                                                   f"the asset: {e}", hint="move it over the reconstructed road")
    x, y = obj.matrix_world.translation.x, obj.matrix_world.translation.y
    z = geometry.plane_height(plane, x, y)
    if align:
        yaw = obj.matrix_world.to_quaternion()
        heading = yaw @ Vector((0.0, 1.0, 0.0))
        flat = Quaternion((0.0, 0.0, 1.0), np.arctan2(-heading.x, heading.y))
        tilt = Vector((0.0, 0.0, 1.0)).rotation_difference(Vector(plane[:3].tolist()))
        _set_rotation(obj, tilt @ flat)
    obj.location = (x, y, z)
    return plane, int(inliers.sum())


#: An object's rotation property in each ``rotation_mode`` (any other mode is an Euler order).
_ROTATION_PATHS = {"QUATERNION": "rotation_quaternion", "AXIS_ANGLE": "rotation_axis_angle"}
#: The transform channels a snap changes: the asset's animation of any of them is what ``snap_keyed`` keys.
SNAP_PATHS = ("location", "rotation_euler", *_ROTATION_PATHS.values())


def rotation_path(obj) -> str:
    """The property holding ``obj``'s rotation in its rotation mode (the one to key)."""
    return _ROTATION_PATHS.get(obj.rotation_mode, "rotation_euler")


def _set_rotation(obj, q: Quaternion) -> None:
    """Set ``obj``'s rotation to ``q`` in its own rotation mode: its rotation keys (Euler ones included) stay the
    ones Blender plays, and an Euler is chosen next to the current one (no 360° flip between keys)."""
    if obj.rotation_mode == "QUATERNION":
        obj.rotation_quaternion = q
    elif obj.rotation_mode == "AXIS_ANGLE":
        axis, angle = q.to_axis_angle()
        obj.rotation_axis_angle = (angle, *axis)
    else:
        obj.rotation_euler = q.to_euler(obj.rotation_mode, obj.rotation_euler)


def snap_key_frames(obj) -> list:
    """The frames of ``obj``'s keys on the channels a snap changes (``SNAP_PATHS``), sorted; [] when none is
    animated."""
    return sorted({k.co.x for fc in compat.fcurves(obj) if fc.data_path in SNAP_PATHS for k in fc.keyframe_points})


def snap_keyed(context, obj, points_obj, margin: float = 1.0, align: bool = True, all_keys: bool = False,
               threshold: float = 0.05) -> list:
    """``snap_to_ground`` that lasts on an animated asset: [(frame, plane, points fitted)] per frame snapped.

    Not animated (no key on ``SNAP_PATHS``): snapped as it stands, nothing keyed (the values stay). Animated: the
    next frame change would put back the keyed values, so the snapped ones are keyed at the current frame
    (location, and the rotation when ``align``); with ``all_keys`` every frame with a key on those channels is
    evaluated in turn (scene.frame_set: the asset where its animation puts it), snapped there and keyed, and the
    scene goes back to its frame — the current frame first, as it stands, when it is a key frame or the asset was
    moved there without a key (that edit is kept, keyed). SceneError (``snap_to_ground``'s) at any frame stops with the frames before it
    keyed: the operator's undo step takes them back."""
    scene = context.scene
    frames = snap_key_frames(obj)
    if not frames:
        return [(scene.frame_current, *snap_to_ground(context, obj, points_obj, margin, align, threshold))]

    def snap_and_key(frame):
        plane, n = snap_to_ground(context, obj, points_obj, margin, align, threshold)
        obj.keyframe_insert("location", frame=frame)
        if align:
            obj.keyframe_insert(rotation_path(obj), frame=frame)
        return frame, plane, n

    here = scene.frame_current + scene.frame_subframe
    if not all_keys:  # as it stands now (an edit not keyed yet included)
        return [snap_and_key(here)]
    # the current frame first when it is a key frame or the asset was moved there without a key: snapped as it
    # stands and keyed, so the frame changes below do not throw that edit away
    out = [snap_and_key(here)] if here in frames or _unkeyed_edit(obj, here) else []
    current = (scene.frame_current, scene.frame_subframe)
    try:
        for f in frames:
            if f != here:
                scene.frame_set(int(np.floor(f)), subframe=float(f - np.floor(f)))
                out.append(snap_and_key(f))
        return sorted(out, key=lambda r: r[0])
    finally:
        scene.frame_set(current[0], subframe=current[1])


def _unkeyed_edit(obj, frame: float) -> bool:
    """Whether ``obj``'s location or rotation differs from what its animation gives at ``frame`` (moved by hand
    and not keyed yet)."""
    for fc in compat.fcurves(obj):
        if fc.data_path in SNAP_PATHS:
            value = getattr(obj, fc.data_path)[fc.array_index]
            if abs(fc.evaluate(frame) - value) > 1e-6 * max(1.0, abs(value)):
                return True
    return False


def _removal_group() -> bpy.types.NodeTree:
    """Geometry Nodes: delete the points inside the Box object (a cube empty spanning ±1 in its own scaled axes);
    no box (deleted) removes nothing."""
    return node_groups.ensure_group(REMOVAL_GROUP, REMOVAL_GROUP_VERSION,
                                    (node_groups.Socket("Box", "NodeSocketObject"),), _build_removal_group)


def _build_removal_group(b: node_groups.Builder) -> None:
    gi = b.group_input
    # the box in the points object's own space
    info = b.node("GeometryNodeObjectInfo", {"Object": gi.outputs["Box"]}, transform_space="RELATIVE")
    inv = b.node("FunctionNodeInvertMatrix", {"Matrix": info.outputs["Transform"]})
    local = b.node("FunctionNodeTransformPoint", {"Vector": b.node("GeometryNodeInputPosition").outputs["Position"],
                                                  "Transform": inv.outputs["Matrix"]})
    absv = b.node("ShaderNodeVectorMath", {0: local.outputs["Vector"]}, operation="ABSOLUTE")
    sep = b.node("ShaderNodeSeparateXYZ", {"Vector": absv.outputs["Vector"]})
    inside = None
    for axis in ("X", "Y", "Z"):  # the cube empty spans ±1 in its own (scaled) axes
        within = b.node("FunctionNodeCompare", {"A": sep.outputs[axis], "B": 1.0}, data_type="FLOAT",
                        operation="LESS_EQUAL").outputs["Result"]
        inside = within if inside is None else b.boolean("AND", inside, within)
    valid = b.boolean("AND", inside, inv.outputs["Invertible"])  # no box (deleted): nothing is removed
    delete = b.node("GeometryNodeDeleteGeometry", {"Geometry": gi.outputs["Geometry"], "Selection": valid},
                    domain="POINT")
    b.output(delete.outputs["Geometry"])


def add_removal_box(context, points_obj, box_to_world=None, size=DEFAULT_CAR, name="Removal box"):
    """A cube empty whose inside points are removed from ``points_obj`` (a modifier before the points preview).

    ``size`` is (length, width, height) in metres: length along the box's local Y. ``box_to_world`` (rigid 4x4,
    box centre) defaults to the 3D cursor with the box standing on it.
    """
    L, Wd, H = size
    box = bpy.data.objects.new(name, None)
    box.empty_display_type = "CUBE"
    box.empty_display_size = 1.0
    if box_to_world is None:
        box_to_world = np.eye(4)
        box_to_world[:3, 3] = np.array(context.scene.cursor.location) + [0.0, 0.0, H / 2]
    box.matrix_world = Matrix(np.asarray(box_to_world, np.float64).tolist())
    box.scale = (Wd / 2, L / 2, H / 2)
    kinds.mark(box, kinds.REMOVAL_BOX)
    for coll in points_obj.users_collection:
        coll.objects.link(box)
    attach_removal_box(points_obj, box)
    return box


def attach_removal_box(points_obj, box):
    """Make ``box`` remove its inside points from ``points_obj``: a "SCPainter Removal Box" modifier placed before
    the points preview (remove first, then draw what is left). Returns the modifier."""
    mod = node_groups.add_modifier(points_obj, f"SCPainter Remove {box.name}", _removal_group(), {"Box": box})
    preview = points_mod.points_modifier(points_obj)
    if preview is not None:
        points_obj.modifiers.move(len(points_obj.modifiers) - 1, list(points_obj.modifiers).index(preview))
    box[keys.POINTS_OBJECT] = points_obj.name
    return mod


def removal_modifiers(points_obj) -> list:
    """``points_obj``'s removal-box modifiers, in stack order (enabled or not)."""
    return node_groups.find_modifiers(points_obj, REMOVAL_GROUP)


def applied_removal_boxes(points_obj) -> list:
    """The removal boxes whose points Blender's render removes from ``points_obj``: those its removal modifiers
    enabled in renders (``show_render``) name, in stack order. The box's own visibility does not matter: Blender
    applies the modifier even when the box is hidden or its collection excluded (scene/visibility.py); a box
    whose modifier was deleted or disabled removes nothing, and neither does a deleted box."""
    out = []
    for mod in removal_modifiers(points_obj):
        box = node_groups.get_input(mod, "Box") if mod.show_render else None
        if kinds.is_kind(box, kinds.REMOVAL_BOX) and box not in out:
            out.append(box)
    return out


def align_to_box(obj, box, uniform: bool = False):
    """Stand the asset in the box: bottom centre on the box's floor, heading along its length (local Y), sized
    to it (per axis, or uniformly to its length)."""
    T, size = box_matrix(box)
    L, Wd, H = size[1], size[0], size[2]
    fit_size(obj, L, Wd, H, uniform=uniform)
    R = T[:3, :3].copy()
    if _length_axis(obj) == 0:  # the asset's length runs along its X: turn it a quarter to the box's Y
        R = R @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    obj.rotation_mode = "QUATERNION"
    obj.rotation_quaternion = Matrix(R.tolist()).to_quaternion()
    obj.location = (T[:3, 3] - T[:3, 2] * H / 2).tolist()
    obj[keys.TARGET_BOX] = box.name


def stage1_check(obj, target=None, tolerance: float = STAGE1_TOLERANCE) -> dict:
    """The paper's stage-1 filter: the asset's proportions against its target box (or a default car).

    Writes ``scpainter_stage1`` ("ok" or "flagged") and ``scpainter_stage1_deviation`` (width, height) on the
    asset; returns both with the target used.
    """
    if target is None:
        box = bpy.data.objects.get(obj.get(keys.TARGET_BOX, ""))
        if box is not None:
            _, s = box_matrix(box)
            target = (s[1], s[0], s[2])
        else:
            target = DEFAULT_CAR
    dev = geometry.proportion_deviation(proportions(obj), target)
    status = "flagged" if np.any(np.abs(dev) > tolerance) else "ok"
    obj[keys.STAGE1] = status
    obj[keys.STAGE1_DEVIATION] = [float(dev[1]), float(dev[2])]
    return {"status": status, "width": float(dev[1]), "height": float(dev[2]), "target": list(map(float, target))}
