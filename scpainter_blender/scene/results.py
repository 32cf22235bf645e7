"""Backend results back in Blender: condition previews and generated frames as image sequences, the video as a
movie clip, shown behind the scene camera, frame-synchronised with the timeline.

A render's condition previews are loaded as "SCPainter Conditions", its labelled previews (when it wrote them) as
"SCPainter Labels". Files are numbered by scene frame (``preview_000012.png`` is frame 12), so an image sequence
with frame_start = 1 and no offset shows file N at frame N. Loading reuses datablocks of the same path (running
twice does not pile up images). Nothing here runs unless a backend run finished. Every result carries a fake
user, so saving the .blend keeps it even when nothing shows it (a movie clip no editor has opened, the conditions
once the video is behind the camera).

The files are named by ``core.output_layout``; their folders and the video come from the backend's ``done`` event
(``runs.finish``). The model's video and the baseline's (OpenCV inpainting, no model) are written to the same files
(``generated/``, ``generated.mp4``), so they are loaded under names that say which one is there (``NAMES``): loading
one kind renames the other kind's image sequence (the camera background keeps it) and replaces its movie clip, so
the scene never shows one generator's frames under the other's name. Each datablock also carries
``scpainter_model`` and ``scpainter_description`` (the backend's one line about what made it).
"""

from __future__ import annotations

import os

import bpy

from ..core.output_layout import CONDITION_PREVIEW, GENERATED_FRAME, LABELLED_PREVIEW

CONDITIONS = "SCPainter Conditions"
LABELS = "SCPainter Labels"   # the condition previews with the labels drawn (boxes, ids), beside CONDITIONS
GENERATED = "SCPainter Generated"
VIDEO = "SCPainter Video"
BASELINE = "SCPainter Baseline"
BASELINE_VIDEO = "SCPainter Video (Baseline)"
#: (image sequence, movie clip) of each generator (the ``done`` event's ``model``).
NAMES = {"scpainter": (GENERATED, VIDEO), "baseline": (BASELINE, BASELINE_VIDEO)}


def _sequence(name: str, files: list, replaces=()) -> bpy.types.Image | None:
    """The PNG sequence ``files`` (paths sorted by frame, ``FrameFiles.in_folder``) as image ``name``, reloaded. The
    datablock of that name is reused (else the first of ``replaces`` there is, renamed; the others' users are moved
    to it), so the camera background and image editors that show it keep showing it."""
    if not files:
        return None
    first = files[0]
    img = bpy.data.images.get(name)
    for other in replaces:  # one datablock per set of files: the other generator's becomes this one
        old = bpy.data.images.get(other)
        if old is not None and img is None:
            old.name, img = name, old
        elif old is not None:
            old.user_remap(img)
            bpy.data.images.remove(old)
    if img is None:
        img = bpy.data.images.load(first, check_existing=False)
        img.name = name
    elif bpy.path.abspath(img.filepath) != first:  # another output folder: the same datablock, pointed there
        img.filepath = first
    img.source = "SEQUENCE"
    img.use_fake_user = True  # kept in the saved .blend when the camera background shows another result
    img.reload()
    img["scpainter_frames"] = len(files)
    return img


def load_conditions(folder: str) -> bpy.types.Image | None:
    """The condition previews in ``folder`` (``<output_dir>/conditions``)."""
    return _sequence(CONDITIONS, CONDITION_PREVIEW.in_folder(folder))


def load_labels(folder: str) -> bpy.types.Image | None:
    """The labelled previews in ``folder`` (``<output_dir>/conditions``) as image sequence ``LABELS``; None when
    the render wrote none (a backend from before labels)."""
    return _sequence(LABELS, LABELLED_PREVIEW.in_folder(folder))


def load_generated(frames_dir: str, mp4: str, model: str = "scpainter", description: str = "") \
        -> tuple[bpy.types.Image | None, bpy.types.MovieClip | None]:
    """The frames in ``frames_dir`` and the video ``mp4`` (the ``done`` event's ``frames_dir`` and ``video``) under
    the names of ``model`` ("scpainter" or "baseline", ``NAMES``), the other generator's datablocks renamed or
    removed (they show the same files)."""
    name, video = NAMES[model]
    others = [n for m, n in NAMES.items() if m != model]
    img = _sequence(name, GENERATED_FRAME.in_folder(frames_dir), replaces=[n for n, _ in others])
    # a clip is loaded afresh (it does not reload its file); the old ones' users (clip editors, strips) move to it
    clip = bpy.data.movieclips.load(mp4, check_existing=False) if os.path.isfile(mp4) else None
    for stale in [video, *(v for _, v in others)]:
        if (old := bpy.data.movieclips.get(stale)) is not None and old != clip:
            if clip is not None:
                old.user_remap(clip)
            bpy.data.movieclips.remove(old)
    if clip is not None:
        clip.name = video
        clip.use_fake_user = True  # nothing uses a fresh clip yet: without this, saving the .blend would drop it
    for block in (img, clip):
        if block is not None:
            block["scpainter_model"], block["scpainter_description"] = model, description
    return img, clip


def show_behind_camera(scene, image: bpy.types.Image, alpha: float = 1.0) -> None:
    """Show an image sequence as the scene camera's background, one file per scene frame."""
    cam = scene.camera
    if cam is None or image is None:
        return
    data = cam.data
    bg = next((b for b in data.background_images if b.image is not None and b.image.name in
               (CONDITIONS, LABELS, GENERATED, BASELINE)), None) or data.background_images.new()
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
