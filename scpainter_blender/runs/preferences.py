"""Add-on preferences: where the backend runs and what it loads."""

from __future__ import annotations

import bpy

from ..core import backend_protocol
from . import warm_session

#: The extension's package (``bl_ext.<repo>.scpainter`` when installed): two levels above this module.
ADDON_PACKAGE = __package__.rsplit(".", 2)[0]


def _backend_changed(self, context):
    """A setting the warm backend was started with changed: it ends now (the next run starts one that fits)."""
    warm_session.end()


#: The last "Check Backend" report (written by the operator, shown under its button here): ok, text, report.
DOCTOR: dict = {}

#: *Keep Backend*'s default: seconds a warm backend waits for the next run before it ends.
KEEP_BACKEND_DEFAULT = 600


class SCPAINTER_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    backend_python: bpy.props.StringProperty(
        name="Backend Python", subtype="FILE_PATH", update=_backend_changed,
        description="Python interpreter with torch for the backend (empty: the one running Blender, if it has "
                    "torch)")
    keep_backend: bpy.props.IntProperty(
        name="Keep Backend", default=KEEP_BACKEND_DEFAULT, min=0, soft_max=3600, update=_backend_changed,
        description="Seconds the backend process stays loaded after a run (torch, the renderer's kernels, the "
                    "scene's points), so the next Render Conditions or Generate starts at once; 0: a new process "
                    "for every run")
    checkpoint_dir: bpy.props.StringProperty(
        name="Checkpoint Folder", subtype="DIR_PATH",
        description="Local folder of the SCPainter / Stable Video Diffusion weights (nothing is downloaded); "
                    "empty: Generate makes the OpenCV inpainting baseline, not the model")
    device: bpy.props.EnumProperty(  # the backend's --device names, upper-case (Blender's enum style); device()
        name="Device", default=backend_protocol.DEFAULT_DEVICE.upper(), update=_backend_changed,
        items=[(name.upper(), label, text) for name, (label, text) in backend_protocol.DEVICES.items()])

    def draw(self, context):
        col = self.layout.column()
        col.prop(self, "backend_python")
        col.prop(self, "checkpoint_dir")
        if not self.checkpoint_dir:
            col.label(text="No checkpoint: Generate makes the OpenCV inpainting baseline (no model)", icon="INFO")
        col.prop(self, "device")
        col.prop(self, "keep_backend")
        row = self.layout.row()
        row.operator("scpainter.check_backend", icon="CHECKMARK")
        if DOCTOR:
            row.label(text=DOCTOR["text"], icon="CHECKMARK" if DOCTOR.get("ok") else "ERROR")


def device(prefs: SCPAINTER_AP_preferences | None) -> str:
    """The backend's ``--device`` the preferences choose (``core.backend_protocol.DEVICE_NAMES``); its default
    without them."""
    return prefs.device.lower() if prefs else backend_protocol.DEFAULT_DEVICE


def python(prefs: SCPAINTER_AP_preferences | None) -> str:
    """The Backend Python the preferences name, "" without one (``client.backend_python`` then takes the
    running interpreter when it can import torch)."""
    return prefs.backend_python if prefs else ""


def keep_backend(prefs: SCPAINTER_AP_preferences | None) -> int:
    """Seconds a warm backend waits for the next run (0: one process per run); its default without preferences."""
    return prefs.keep_backend if prefs else KEEP_BACKEND_DEFAULT


def get(context=None) -> SCPAINTER_AP_preferences | None:
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_PACKAGE)
    return addon.preferences if addon else None


classes = (SCPAINTER_AP_preferences,)
