"""Placing car assets: fit, snap to the ground, removal boxes, replace a recorded car, the two review stages; box
proposals and their review (scene/proposals.py)."""

from __future__ import annotations

import bpy
import numpy as np

from ..scpainter_blender.core import categories
from ..scpainter_blender.scene import keys, kinds, placement, proposals, recorded_objects, visibility
from . import reports, selection


def _asset(context):
    obj = context.active_object
    return obj if kinds.is_kind(obj, kinds.GAUSSIAN_ASSET) else None


def _points(context):
    """Any reconstruction (for ``poll``: cheap, never raises)."""
    return kinds.point_cloud(context.scene)


def _rendered_points(context):
    """The reconstruction the job renders (SceneError when two render), else the scene's first."""
    return visibility.points_object(context.scene, context.view_layer) or _points(context)


class _AssetOperator:
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if _asset(context) is None:
            cls.poll_message_set("Select a Gaussian car asset (File > Import > SCPainter Gaussian Asset)")
            return False
        return True


class SCPAINTER_OT_fit_asset(_AssetOperator, bpy.types.Operator):
    """Scale the active asset to a car size: uniformly to its length, or to length, width and height"""

    bl_idname = "scpainter.fit_asset"
    bl_label = "Fit to Car Size"
    bl_options = {"REGISTER", "UNDO"}

    length: bpy.props.FloatProperty(name="Length", default=placement.DEFAULT_CAR[0], min=0.1, unit="LENGTH")
    width: bpy.props.FloatProperty(name="Width", default=placement.DEFAULT_CAR[1], min=0.1, unit="LENGTH")
    height: bpy.props.FloatProperty(name="Height", default=placement.DEFAULT_CAR[2], min=0.1, unit="LENGTH")
    uniform: bpy.props.BoolProperty(name="Keep Proportions", default=True,
                                    description="Scale uniformly to the length (off: per axis to all three)")

    @reports.reported
    def execute(self, context):
        placement.fit_size(_asset(context), self.length, self.width, self.height, self.uniform)
        return {"FINISHED"}


class SCPAINTER_OT_snap_to_ground(_AssetOperator, bpy.types.Operator):
    """Stand the active asset on the road: a plane fitted to the scene points around its footprint"""

    bl_idname = "scpainter.snap_to_ground"
    bl_label = "Snap to Ground"
    bl_options = {"REGISTER", "UNDO"}

    align: bpy.props.BoolProperty(name="Align to Slope", default=True)
    margin: bpy.props.FloatProperty(name="Margin", default=1.0, min=0.0, unit="LENGTH",
                                    description="How far around the footprint to look for road points")
    all_keys: bpy.props.BoolProperty(name="All Keyframes", default=False,
                                     description="On a car with location or rotation keys: snap it at every one of "
                                                 "those keyframes (each where its animation puts it) and key the "
                                                 "result; off: only the current frame, keyed so it lasts")

    @reports.reported
    def execute(self, context):
        pts = _rendered_points(context)
        if pts is None:
            self.report({"ERROR"}, "no reconstruction in the scene: import a VGGT reconstruction first")
            return {"CANCELLED"}
        asset = _asset(context)
        snapped = placement.snap_keyed(context, asset, pts, self.margin, self.align, self.all_keys)
        _, plane, n = snapped[-1]
        keyed = placement.snap_key_frames(asset)
        if not keyed:
            where = "not animated: nothing keyed"
        elif self.all_keys:
            where = f"keyed at its {len(snapped)} keyframes ({', '.join(f'{f:g}' for f, _, _ in snapped)})"
        else:
            where = f"keyed at frame {snapped[0][0]:g} (All Keyframes snaps every key)"
        self.report({"INFO"}, f"Ground fitted to {n:,} points (normal {np.round(plane[:3], 3).tolist()}); {where}")
        return {"FINISHED"}


class SCPAINTER_OT_add_removal_box(bpy.types.Operator):
    """Add a box whose points are removed from the reconstruction (around the active asset, else at the cursor)"""

    bl_idname = "scpainter.add_removal_box"
    bl_label = "Add Removal Box"
    bl_options = {"REGISTER", "UNDO"}

    length: bpy.props.FloatProperty(name="Length", default=placement.DEFAULT_CAR[0], min=0.1, unit="LENGTH")
    width: bpy.props.FloatProperty(name="Width", default=placement.DEFAULT_CAR[1], min=0.1, unit="LENGTH")
    height: bpy.props.FloatProperty(name="Height", default=placement.DEFAULT_CAR[2], min=0.1, unit="LENGTH")

    @classmethod
    def poll(cls, context):
        if _points(context) is None:
            cls.poll_message_set("Import a VGGT reconstruction first")
            return False
        return True

    @reports.reported
    def execute(self, context):
        box = placement.add_removal_box(context, _rendered_points(context),
                                        size=(self.length, self.width, self.height))
        selection.select_only(context, box)
        return {"FINISHED"}


class SCPAINTER_OT_replace_car(_AssetOperator, bpy.types.Operator):
    """Align the active asset to the selected removal box (the recorded car it replaces), or to a removal box made
    from the selected recorded object, and check its size"""

    bl_idname = "scpainter.replace_car"
    bl_label = "Replace Car"
    bl_options = {"REGISTER", "UNDO"}

    uniform: bpy.props.BoolProperty(name="Keep Proportions", default=False,
                                    description="Scale uniformly to the box length instead of filling the box")

    @reports.reported
    def execute(self, context):
        boxes = [o for o in context.selected_objects if kinds.is_kind(o, kinds.REMOVAL_BOX)]
        recorded = recorded_objects.of_selection(context)
        if not boxes and len(recorded) == 1:  # the recorded car's box becomes the removal box it is replaced in
            boxes = [recorded_objects.removal_box(context, recorded[0], _rendered_points(context))]
        if len(boxes) != 1:
            self.report({"ERROR"}, "select exactly one removal box (or one recorded object) together with the asset")
            return {"CANCELLED"}
        asset = _asset(context)
        placement.align_to_box(asset, boxes[0], self.uniform)
        r = placement.stage1_check(asset)
        level = {"WARNING"} if r["status"] == "flagged" else {"INFO"}
        self.report(level, f"{asset.name}: stage 1 {r['status']} (width {r['width']:+.0%}, "
                           f"height {r['height']:+.0%} against the box)")
        return {"FINISHED"}


class SCPAINTER_OT_check_assets(bpy.types.Operator):
    """Stage 1: flag assets whose proportions deviate from their target box (or a mid-size car) by too much"""

    bl_idname = "scpainter.check_assets"
    bl_label = "Check Asset Sizes"
    bl_options = {"REGISTER", "UNDO"}

    tolerance: bpy.props.FloatProperty(name="Tolerance", default=placement.STAGE1_TOLERANCE, min=0.0, max=1.0,
                                       subtype="FACTOR")

    @reports.reported
    def execute(self, context):
        assets = kinds.gaussian_assets(context.scene)
        flagged = []
        for o in assets:
            r = placement.stage1_check(o, tolerance=self.tolerance)
            if r["status"] != "ok":
                flagged.append(f"{o.name} (width {r['width']:+.0%}, height {r['height']:+.0%} at the length of "
                               f"{r['target'][0]:.3g} m)")
        self.report({"WARNING"} if flagged else {"INFO"}, f"{len(assets)} assets checked against "
                    f"±{self.tolerance:.0%}, flagged: {'; '.join(flagged) or 'none'}")
        return {"FINISHED"}


class SCPAINTER_OT_review_asset(bpy.types.Operator):
    """Stage 2: mark an asset accepted or rejected after looking at it (rejected assets are not rendered)"""

    bl_idname = "scpainter.review_asset"
    bl_label = "Review Asset"
    bl_options = {"REGISTER", "UNDO"}

    name: bpy.props.StringProperty(name="Asset")
    status: bpy.props.EnumProperty(name="Status", items=[("accepted", "Accept", ""), ("rejected", "Reject", ""),
                                                          ("unchecked", "Unchecked", "")])

    @reports.reported
    def execute(self, context):
        obj = bpy.data.objects.get(self.name) or _asset(context)
        if not kinds.is_kind(obj, kinds.GAUSSIAN_ASSET):
            self.report({"ERROR"}, f"no Gaussian asset named {self.name!r}")
            return {"CANCELLED"}
        obj[keys.REVIEW] = self.status
        return {"FINISHED"}


class SCPAINTER_OT_propose_boxes(bpy.types.Operator):
    """Propose a box for each object above the road that nothing labels (a parked car): for review"""

    bl_idname = "scpainter.propose_boxes"
    bl_label = "Propose Boxes"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if _points(context) is None or kinds.recorded_camera(context.scene) is None:
            cls.poll_message_set("Import a VGGT reconstruction first (File > Import > SCPainter VGGT Reconstruction)")
            return False
        return True

    @reports.reported
    def execute(self, context):
        made = proposals.propose(context)
        self.report({"INFO"}, f"{len(made)} box proposals" + (f": {', '.join(o.name for o in made)}" if made else
                                                             ": every object above the road is labelled"))
        return {"FINISHED"}


def _named_proposal(op, context):
    """The proposal the operator names (its ``name``, else the active object); None, reported as an error, when
    that is no box proposal."""
    obj = bpy.data.objects.get(op.name) if op.name else context.active_object
    if kinds.is_kind(obj, kinds.PROPOSAL):
        return obj
    op.report({"ERROR"}, f"no box proposal named {op.name or '(the active object)'!r}")
    return None


class SCPAINTER_OT_review_proposal(bpy.types.Operator):
    """Accept a box proposal (a recorded object, labelled), ignore it (a recorded object that every export makes an
    ignore region) or reject it (deleted)"""

    bl_idname = "scpainter.review_proposal"
    bl_label = "Review Proposal"
    bl_options = {"REGISTER", "UNDO"}

    name: bpy.props.StringProperty(name="Proposal", description="The proposal's object (default: the active one)")
    action: bpy.props.EnumProperty(name="Action", items=[
        ("accept", "Accept", "A recorded object of its class, labelled in every frame"),
        ("ignore", "Ignore", "A recorded object that is not labelled: an ignore region in every export"),
        ("reject", "Reject", "Not an object: delete the proposal")])

    @reports.reported
    def execute(self, context):
        obj = _named_proposal(self, context)
        if obj is None:
            return {"CANCELLED"}
        if self.action == "reject":
            proposals.reject(obj)
        else:
            proposals.accept(context, obj, ignore=self.action == "ignore")
        return {"FINISHED"}


class SCPAINTER_OT_relabel_proposal(bpy.types.Operator):
    """Set the class of a box proposal"""

    bl_idname = "scpainter.relabel_proposal"
    bl_label = "Relabel Proposal"
    bl_options = {"REGISTER", "UNDO"}

    name: bpy.props.StringProperty(name="Proposal", description="The proposal's object (default: the active one)")
    category: bpy.props.EnumProperty(name="Class", items=[(n, n, "") for n in categories.NAMES])

    @reports.reported
    def execute(self, context):
        obj = _named_proposal(self, context)
        if obj is None:
            return {"CANCELLED"}
        proposals.relabel(obj, self.category)
        return {"FINISHED"}


classes = (SCPAINTER_OT_fit_asset, SCPAINTER_OT_snap_to_ground, SCPAINTER_OT_add_removal_box,
           SCPAINTER_OT_replace_car, SCPAINTER_OT_check_assets, SCPAINTER_OT_review_asset, SCPAINTER_OT_propose_boxes,
           SCPAINTER_OT_review_proposal, SCPAINTER_OT_relabel_proposal)
