"""Backend results back in Blender: condition previews and generated frames as image sequences, the video as a
movie clip, shown behind the camera that saw them, frame-synchronised with the timeline.

Every result belongs to a camera (each camera has its own output folder, ``props.camera_output_dir``) and is named
after it: ``"<kind> · <camera>"`` (``result_name``; e.g. "SCPainter Conditions · Camera path 2 m left"). A render's
condition previews are loaded as kind "SCPainter Conditions", its labelled previews (when it wrote them) as
"SCPainter Labels". Files are numbered by scene frame (``preview_000012.png`` is frame 12), so an image sequence
with frame_start = 1 and no offset shows file N at frame N. Loading reuses the camera's datablock of the same kind
(running twice does not pile up images); another camera's are never touched. A datablock is found by what it
holds, ``scpainter_result`` (its kind) and ``scpainter_camera`` (the camera's name), not by its name, which Blender
may have shortened (63 bytes before Blender 5) and the user may have changed. Nothing here runs unless a backend run
finished. Every result carries a fake user, so saving the .blend keeps it even when nothing shows it (a movie clip
no editor has opened, the conditions once the video is behind the camera).

The files are named by ``core.output_layout``; their folders and the video come from the backend's ``done`` event
(``runs.finish``). The model's video and the baseline's (OpenCV inpainting, no model) are written to the same files
of a camera's folder (``generated/``, ``generated.mp4``), so they are loaded under kinds that say which one is
there (``NAMES``): loading one kind renames that camera's datablock of the other kind (the camera background keeps
it) and replaces its movie clip, so the scene never shows one generator's frames under the other's name. Each
datablock also carries ``scpainter_model`` and ``scpainter_description`` (the backend's one line about what made
it). Results loaded before results were per camera keep their plain names ("SCPainter Conditions") and are left
alone, except that the camera background slot showing one is reused. A rig job's results (docs/design.md §17) are
each camera's, from its own folder ``<output folder>/<CAMERA>/``, loaded under the name of the rig camera that is
that sensor and shown behind it (``rig_cameras``); the camera path shows the sensor it is (CAM_FRONT for a preset); the rig's surround pictures (its cameras tiled beside
the LiDAR sweep) load as the camera path's kind "SCPainter Surround", for an image editor.
"""

from __future__ import annotations

import os

import bpy

from ..core.output_layout import CONDITION_PREVIEW, GENERATED_FRAME, LABELLED_PREVIEW
from ..core.output_layout import SURROUND as SURROUND_FILES
from . import keys, kinds, paths

CONDITIONS = "SCPainter Conditions"
LABELS = "SCPainter Labels"   # the condition previews with the labels drawn (boxes, ids), beside CONDITIONS
SURROUND = "SCPainter Surround"  # a rig render's frames as one picture: its cameras tiled beside the LiDAR sweep
GENERATED = "SCPainter Generated"
VIDEO = "SCPainter Video"
BASELINE = "SCPainter Baseline"
BASELINE_VIDEO = "SCPainter Video (Baseline)"
#: (image sequence, movie clip) kinds of each generator (the ``done`` event's ``model``).
NAMES = {"scpainter": (GENERATED, VIDEO), "baseline": (BASELINE, BASELINE_VIDEO)}
#: The image sequences a camera background may show (a slot showing one of them is reused, not added to).
SEQUENCES = (CONDITIONS, LABELS, GENERATED, BASELINE)
#: Between a result's kind and its camera's name in the datablock's name.
SEPARATOR = " · "
#: The custom properties that say what a datablock holds: its kind and its camera's name ("" for none).
RESULT, CAMERA = keys.RESULT, keys.CAMERA


def result_name(kind: str, camera: str | None) -> str:
    """The datablock name of result ``kind`` of the camera named ``camera``: "<kind> · <camera>"; the bare kind
    without a camera."""
    return f"{kind}{SEPARATOR}{camera}" if camera else kind


def find(collection, kind: str, camera: str | None):
    """The datablock of ``collection`` (``bpy.data.images`` / ``movieclips``) holding result ``kind`` of
    ``camera``, else None. Without a camera, also one of that bare name (loaded before results were per camera)."""
    for block in collection:
        if block.get(RESULT) == kind and block.get(CAMERA) == (camera or ""):
            return block
    old = collection.get(kind) if not camera else None
    return old if old is not None and old.get(RESULT) is None else None


def _tag(block, kind: str, camera: str | None) -> None:
    block[RESULT], block[CAMERA] = kind, camera or ""


def _sequence(kind: str, camera: str | None, files: list, replaces=()) -> bpy.types.Image | None:
    """The PNG sequence ``files`` (paths sorted by frame, ``FrameFiles.in_folder``) as ``camera``'s image of
    ``kind``, reloaded. That datablock is reused (else the first of ``camera``'s ``replaces`` kinds there is,
    renamed; the others' users are moved to it), so the camera background and image editors that show it keep
    showing it."""
    if not files:
        return None
    first = files[0]
    img = find(bpy.data.images, kind, camera)
    for other in replaces:  # one datablock per set of files: the other generator's becomes this one
        old = find(bpy.data.images, other, camera)
        if old is not None and img is None:
            old.name, img = result_name(kind, camera), old
        elif old is not None:
            old.user_remap(img)
            bpy.data.images.remove(old)
    if img is None:
        img = bpy.data.images.load(first, check_existing=False)
        img.name = result_name(kind, camera)
    # relative to the saved .blend (``paths.stored``), so a moved project shows its own results; another output
    # folder: the same datablock, pointed there
    if img.filepath != (where := paths.stored(first)):
        img.filepath = where
    _tag(img, kind, camera)
    img.source = "SEQUENCE"
    img.use_fake_user = True  # kept in the saved .blend when the camera background shows another result
    img.reload()
    img[keys.FRAMES] = len(files)
    return img


def load_conditions(folder: str, camera: str | None = None) -> bpy.types.Image | None:
    """The condition previews in ``folder`` (``<output_dir>/conditions``) of the camera named ``camera``."""
    return _sequence(CONDITIONS, camera, CONDITION_PREVIEW.in_folder(folder))


def load_labels(folder: str, camera: str | None = None) -> bpy.types.Image | None:
    """The labelled previews in ``folder`` (``<output_dir>/conditions``) as ``camera``'s image sequence of kind
    ``LABELS``; None when the render wrote none (a backend from before labels)."""
    return _sequence(LABELS, camera, LABELLED_PREVIEW.in_folder(folder))


def load_surround(folder: str, camera: str | None = None) -> bpy.types.Image | None:
    """A rig render's surround pictures (``surround_NNNNNN.png`` in the rig job's ``folder``: its cameras tiled
    beside the sweep from above) as the image sequence of kind ``SURROUND`` of the camera path named ``camera``, for an
    image editor (not a camera background: it is no camera's view); None when the render wrote none."""
    return _sequence(SURROUND, camera, SURROUND_FILES.in_folder(folder))


def load_generated(frames_dir: str, mp4: str, model: str = "scpainter", description: str = "",
                   camera: str | None = None) -> tuple[bpy.types.Image | None, bpy.types.MovieClip | None]:
    """The frames in ``frames_dir`` and the video ``mp4`` (the ``done`` event's ``frames_dir`` and ``video``) as
    ``camera``'s results of ``model`` ("scpainter" or "baseline", ``NAMES``), that camera's datablocks of the other
    generator renamed or removed (they show the same files)."""
    name, video = NAMES[model]
    others = [n for m, n in NAMES.items() if m != model]
    img = _sequence(name, camera, GENERATED_FRAME.in_folder(frames_dir), replaces=[n for n, _ in others])
    # a clip is loaded afresh (it does not reload its file); the old ones' users (clip editors, strips) move to it
    clip = bpy.data.movieclips.load(mp4, check_existing=False) if os.path.isfile(mp4) else None
    for stale in [video, *(v for _, v in others)]:
        if (old := find(bpy.data.movieclips, stale, camera)) is not None and old != clip:
            if clip is not None:
                old.user_remap(clip)
            bpy.data.movieclips.remove(old)
    if clip is not None:
        clip.name = result_name(video, camera)
        clip.filepath = paths.stored(mp4)
        _tag(clip, video, camera)
        clip.use_fake_user = True  # nothing uses a fresh clip yet: without this, saving the .blend would drop it
    for block in (img, clip):
        if block is not None:
            block[keys.MODEL], block[keys.DESCRIPTION] = model, description
    return img, clip


def rig_cameras(scene, camera) -> tuple[dict, str | None]:
    """({sensor name: camera object}, the sensor the camera path is) of the camera rig that follows ``camera`` (a
    camera object, or None): where a rig job's results are shown, each camera's behind its own rig camera
    (scene/rig.py); ({}, None) without a rig."""
    rig = kinds.rig_of(camera)
    if rig is None:
        return {}, None
    return ({str(c.get(keys.SENSOR, c.name)): c for c in kinds.rig_sensors(rig, kinds.RIG_CAMERA)},
            rig.get(keys.RIG_FOLLOW))


def _is_result(image) -> bool:
    """Whether ``image`` is a result sequence (any camera's, or one loaded before results were per camera)."""
    return image.get(RESULT) in SEQUENCES or (image.get(RESULT) is None and image.name in SEQUENCES)


def show_behind_camera(scene, image: bpy.types.Image, alpha: float = 1.0, camera=None) -> None:
    """Show an image sequence as ``camera``'s background (default: the scene camera), one file per scene frame,
    in the slot that shows a result already (else a new one). A camera shows its own results: the caller passes
    the camera that saw them."""
    cam = camera or scene.camera
    if cam is None or image is None or cam.type != "CAMERA":
        return
    data = cam.data
    bg = next((b for b in data.background_images if b.image is not None and _is_result(b.image)), None) \
        or data.background_images.new()
    bg.source = "IMAGE"
    bg.image = image
    bg.alpha = alpha
    bg.display_depth = "FRONT"
    user = bg.image_user
    user.frame_start = 1
    user.frame_offset = 0
    user.frame_duration = max(scene.frame_end, int(image.get(keys.FRAMES, 1)))
    user.use_auto_refresh = True
    data.show_background_images = True
