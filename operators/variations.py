"""*Make Variations*: the scene as the base of many variants (docs/design.md §16), written for ``batch``."""

from __future__ import annotations

import os

import bpy

from ..scpainter_blender.core.output_layout import SceneFolder, VariationLayout
from ..scpainter_blender.core.variation import spec as spec_mod, variants
from ..scpainter_blender.runs import preferences
from ..scpainter_blender.scene import props, variations
from . import reports


class SCPAINTER_OT_make_variations(bpy.types.Operator):
    """Write variants of this scene (camera shifts, lane changes, cars from a library placed on the road) as job
    folders, with a batch list, a manifest and a summary"""

    bl_idname = "scpainter.make_variations"
    bl_label = "Make Variations"
    bl_options = {"REGISTER"}

    spec: bpy.props.StringProperty(name="Spec", subtype="FILE_PATH",
                                   description="A variation spec (scpainter.variation/1 JSON); empty: the defaults")
    library: bpy.props.StringProperty(name="Car Library", subtype="DIR_PATH",
                                      description="Folder of car files to draw from (empty: the spec's)")
    folder: bpy.props.StringProperty(name="Folder", subtype="DIR_PATH",
                                     description="Where to write the variants (empty: <output folder>/variations)")
    variants: bpy.props.IntProperty(name="Variants", default=spec_mod.VariationSpec.variants, min=1,
                                    max=spec_mod.MAX_VARIANTS,
                                    description="How many variants (with a spec: the spec's unless changed here)")
    seed: bpy.props.IntProperty(name="Seed", default=spec_mod.VariationSpec.seed, min=0,
                                description="The random seed (with a spec: the spec's unless changed here)")

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def draw(self, context):
        layout = self.layout
        for name in ("spec", "library", "folder", "variants", "seed"):
            layout.prop(self, name)
        if self.spec and not any(self.chosen(n) for n in ("variants", "seed")):
            layout.label(text="Variants and Seed: the spec's unless changed here", icon="INFO")

    def chosen(self, name: str) -> bool:
        """Whether ``name`` was given in this call or changed in the dialog (a value remembered from an earlier run,
        a "ghost", is not a choice)."""
        return self.properties.is_property_set(name, ghost=False)

    @reports.reported
    def execute(self, context):
        spec = spec_mod.load(bpy.path.abspath(self.spec)) if self.spec else spec_mod.VariationSpec()
        library = os.path.abspath(bpy.path.abspath(self.library)) if self.library else None
        # a spec's variants and seed stand unless the artist chose others here (the dialog always shows a value)
        chosen = {n: getattr(self, n) for n in ("variants", "seed") if self.chosen(n) or not self.spec}
        spec = spec.with_overrides(**chosen, library=library)
        out = bpy.path.abspath(self.folder) if self.folder else SceneFolder(props.output_dir(context.scene)).variations
        wm = context.window_manager
        wm.progress_begin(0, spec.variants)
        try:
            manifest = variations.make_variations(context, spec, out, python=preferences.python(preferences.get(context)),
                                                  progress=lambda done, total: wm.progress_update(done))
        finally:
            wm.progress_end()
        s = manifest["summary"]
        for w in variants.warnings(manifest):  # what the CLIs send as warning events: unplaced variants, the run's
            self.report({"WARNING"}, w["message"])
        self.report({"INFO"}, f"{s['placed']} of {s['variants']} variants placed ({s['cars']} cars) in {out}; "
                              f"render them with: python -m backend batch --list "
                              f"{VariationLayout(out).list}")
        return {"FINISHED"}


classes = (SCPAINTER_OT_make_variations,)
