"""Backend results back in Blender: condition previews and generated frames as image sequences, the video as a
movie clip, shown behind the scene camera, frame-synchronised with the timeline.

Files are numbered by scene frame (``preview_000012.png`` is frame 12), so an image sequence with frame_start = 1
and no offset shows file N at frame N. Loading reuses datablocks of the same path (running twice does not pile
up images). Nothing here runs unless a backend run finished.
"""

from __future__ import annotations

import os

import bpy

CONDITIONS = "SCPainter Conditions"
GENERATED = "SCPainter Generated"
VIDEO = "SCPainter Video"


def _sequence(name: str, folder: str, prefix: str) -> bpy.types.Image | None:
    files = sorted(f for f in os.listdir(folder) if f.startswith(prefix) and f.endswith(".png")) \
        if os.path.isdir(folder) else []
    if not files:
        return None
    first = os.path.join(folder, files[0])
    img = bpy.data.images.get(name)
    if img is None or bpy.path.abspath(img.filepath) != first:
        if img is not None:
            bpy.data.images.remove(img)
        img = bpy.data.images.load(first, check_existing=False)
        img.name = name
    img.source = "SEQUENCE"
    img.reload()
    img["scpainter_frames"] = len(files)
    return img


def load_conditions(output_dir: str) -> bpy.types.Image | None:
    return _sequence(CONDITIONS, os.path.join(output_dir, "conditions"), "preview_")


def load_generated(output_dir: str) -> tuple[bpy.types.Image | None, bpy.types.MovieClip | None]:
    img = _sequence(GENERATED, os.path.join(output_dir, "generated"), "frame_")
    clip = None
    mp4 = os.path.join(output_dir, "generated.mp4")
    if os.path.isfile(mp4):
        clip = bpy.data.movieclips.get(VIDEO)
        if clip is not None:
            bpy.data.movieclips.remove(clip)
        clip = bpy.data.movieclips.load(mp4)
        clip.name = VIDEO
    return img, clip


def show_behind_camera(scene, image: bpy.types.Image, alpha: float = 1.0) -> None:
    """Show an image sequence as the scene camera's background, one file per scene frame."""
    cam = scene.camera
    if cam is None or image is None:
        return
    data = cam.data
    bg = next((b for b in data.background_images if b.image is not None and b.image.name in
               (CONDITIONS, GENERATED)), None) or data.background_images.new()
    bg.source = "IMAGE"
    bg.image = image
    bg.alpha = alpha
    bg.display_depth = "FRONT"
    user = bg.image_user
    user.frame_start = 1
    user.frame_offset = 0
    user.frame_duration = max(scene.frame_end, int(image.get("scpainter_frames", 1)))
    user.use_auto_refresh = True
    data.show_background_images = True
