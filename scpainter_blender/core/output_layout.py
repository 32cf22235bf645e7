"""A job's output folder, named once: every file and folder the backend writes there and Blender reads (issue 26).

::

    <output_dir>/
        job.json                        the job Blender exports (``runs.export``) and the backend reads
        .scpainter.lock                 one run at a time (``core.locking``; train's folder has one too)
        backend.log                     the commands' human log; a bug's traceback (the error event's ``log``)
        conditions/frame_NNNNNN.exr     condition layers of output frame NNNNNN (``backend/render/channels.py``)
        conditions/preview_NNNNNN.png   the same image for people (what Blender shows behind the camera)
        conditions/labels_NNNNNN.json   the frame's labels (``core/labels.py``, its ``SCHEMA``)
        conditions/labelled_NNNNNN.png  the preview with the labels drawn (boxes, ids, visible fractions)
        conditions/record.json          the render's job key, the files it wrote, their precision
        generated/frame_NNNNNN.png      the video's frames
        generated/manifest.json         written last: the generation finished (key, model, description, frames)
        generated.mp4                   the video
        generate_state.safetensors      the sampler's latents after each step (resume); removed when finished
        baseline.mp4, contact_sheet.png only in ``evaluate``'s task folders: the baseline's video, the task's pictures
        export/<format>/                ``export``'s default destination (``backend_protocol.EXPORT_FORMATS``)
        export/<format>/export.json     in every export (any ``--out``): what made it; an existing folder is
                                        replaced by a new export only when it has one (or is empty)

A rig job's output folder (docs/design.md §17) holds one such output folder per camera (``OutputLayout.camera``),
named by the camera's sensor name, and the LiDAR's sweeps in a folder named by the LiDAR (``OutputLayout.lidar``)::

    <output_dir>/
        job.json                        the rig job
        CAM_FRONT/ ... CAM_BACK/        each camera's output folder (the layout above: conditions/, generated/, ...)
        LIDAR_TOP/sweep_NNNNNN.pcd.bin  the sweep of scene frame NNNNNN (nuScenes' layout: x, y, z, intensity, ring)
        LIDAR_TOP/sweep_NNNNNN.json     its objects' ``num_lidar_pts`` by track id and the sweep's ``lidar_to_world``

In Blender a scene's output folder (``Scene.scpainter_output_dir``, default ``//scpainter/<scene name>/``) holds one
such output folder per camera and the converted mesh assets its cameras share (``SceneFolder``)::

    <scene output folder>/
        <camera>/                       a camera's output folder (the layout above), named by its cleaned name
        assets/                         mesh cars converted to Gaussians (``scene/gaussians.py``), for every camera

Frames are numbered by scene frame (``frame_000012.exr`` is frame 12) in ``FRAME_DIGITS`` digits (``FrameFiles``:
the one place that formats a frame's file name). Paths come from ``OutputLayout(output_dir)``; bare names (what
``outputs.remove_listed`` / ``remove_temporaries`` take) from the class constants and ``FrameFiles.name``.
Where a backend event carries a path (``done``'s ``video``, ``frames_dir``, ``output_dir``; ``artifact``'s
``path``; ``error``'s ``log``) the reader takes the event's. stdlib only (no bpy): the add-on and the backend share
it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterable

#: Digits of the frame number in a per-frame file name (``frame_000012.png``).
FRAME_DIGITS = 6


@dataclass(frozen=True)
class FrameFiles:
    """One kind of per-frame file: ``<prefix><frame, FRAME_DIGITS digits><ext>``."""

    prefix: str
    ext: str

    def name(self, frame: int) -> str:
        """The bare file name of scene frame ``frame`` (an int >= 0)."""
        return f"{self.prefix}{int(frame):0{FRAME_DIGITS}d}{self.ext}"

    def in_folder(self, folder: str | os.PathLike) -> list[str]:
        """The paths of the files of this kind in ``folder``, sorted by name (= by frame); [] when the folder is
        missing."""
        if not os.path.isdir(folder):
            return []
        return [os.path.join(folder, f) for f in sorted(os.listdir(folder))
                if f.startswith(self.prefix) and f.endswith(self.ext)]


CONDITION_EXR = FrameFiles("frame_", ".exr")       # in conditions/
CONDITION_PREVIEW = FrameFiles("preview_", ".png")  # in conditions/
FRAME_LABELS = FrameFiles("labels_", ".json")       # in conditions/
LABELLED_PREVIEW = FrameFiles("labelled_", ".png")  # in conditions/
GENERATED_FRAME = FrameFiles("frame_", ".png")      # in generated/
LIDAR_SWEEP = FrameFiles("sweep_", ".pcd.bin")      # in a rig job's <LIDAR>/
LIDAR_SWEEP_INFO = FrameFiles("sweep_", ".json")    # in a rig job's <LIDAR>/
SURROUND = FrameFiles("surround_", ".png")          # in a rig job's output folder: its cameras and sweep at a frame


class OutputLayout:
    """The paths of one output folder (``root``, as given: nothing is resolved, created or checked here)."""

    JOB = "job.json"
    LOCK = ".scpainter.lock"
    LOG = "backend.log"
    CONDITIONS = "conditions"
    GENERATED = "generated"
    #: The folders a run creates inside the output folder (``outputs.check_output`` refuses one leading elsewhere).
    FOLDERS = (CONDITIONS, GENERATED)
    RECORD = "record.json"            # in conditions/
    FORMER_RECORD = "job_key.txt"     # in conditions/: the record's former name (one line: the key), removed
    MANIFEST = "manifest.json"        # in generated/
    VIDEO = "generated.mp4"
    STATE = "generate_state.safetensors"
    EVAL_BASELINE = "baseline.mp4"        # evaluate's task folders only
    EVAL_SHEET = "contact_sheet.png"      # evaluate's task folders only
    EXPORT = "export"                     # export/<format>/: the exporters' default destination
    EXPORT_RECORD = "export.json"         # in an export's folder: marks it as one (replaced whole by the next)
    LIDAR = "LIDAR_TOP"                   # a rig job's LiDAR folder when none is named (nuScenes' channel)

    def __init__(self, output_dir: str | os.PathLike) -> None:
        self.root = os.fspath(output_dir)

    def __repr__(self) -> str:
        return f"OutputLayout({self.root!r})"

    def _at(self, *parts: str) -> str:
        return os.path.join(self.root, *parts)

    # the output folder's own files
    @property
    def job(self) -> str:
        return self._at(self.JOB)

    @property
    def lock(self) -> str:
        return self._at(self.LOCK)

    @property
    def log(self) -> str:
        return self._at(self.LOG)

    @property
    def video(self) -> str:
        return self._at(self.VIDEO)

    @property
    def state(self) -> str:
        return self._at(self.STATE)

    @property
    def eval_baseline(self) -> str:
        return self._at(self.EVAL_BASELINE)

    @property
    def eval_sheet(self) -> str:
        return self._at(self.EVAL_SHEET)

    # conditions/
    @property
    def conditions(self) -> str:
        return self._at(self.CONDITIONS)

    @property
    def record(self) -> str:
        return self._at(self.CONDITIONS, self.RECORD)

    @property
    def former_record(self) -> str:
        return self._at(self.CONDITIONS, self.FORMER_RECORD)

    def condition_exr(self, frame: int) -> str:
        return self._at(self.CONDITIONS, CONDITION_EXR.name(frame))

    def condition_preview(self, frame: int) -> str:
        return self._at(self.CONDITIONS, CONDITION_PREVIEW.name(frame))

    def frame_labels(self, frame: int) -> str:
        return self._at(self.CONDITIONS, FRAME_LABELS.name(frame))

    def labelled_preview(self, frame: int) -> str:
        return self._at(self.CONDITIONS, LABELLED_PREVIEW.name(frame))

    @staticmethod
    def condition_names(frames: Iterable[int]) -> list[str]:
        """The bare names a render writes in ``conditions/`` for ``frames`` (ints): EXR, preview, labels, labelled
        preview, per frame."""
        return [n for f in frames for kind in (CONDITION_EXR, CONDITION_PREVIEW, FRAME_LABELS, LABELLED_PREVIEW)
                for n in [kind.name(f)]]

    def export(self, fmt: str) -> str:
        """``export/<fmt>``: where ``export --format fmt`` writes unless told ``--out``."""
        return self._at(self.EXPORT, fmt)

    # a rig job's sensors
    def camera(self, name: str) -> "OutputLayout":
        """The output folder of a rig job's camera ``name`` (a sensor name, ``core.rig.NAME_PATTERN``): an ordinary
        output folder, ``<root>/<name>`` (``Job.camera_jobs`` gives its job this ``output_dir``)."""
        return OutputLayout(self._at(name))

    def lidar(self, name: str = LIDAR) -> str:
        """The folder of a rig job's LiDAR ``name`` (its sweeps)."""
        return self._at(name)

    def lidar_sweep(self, frame: int, name: str = LIDAR) -> str:
        """``<LIDAR>/sweep_NNNNNN.pcd.bin``: the sweep of scene frame ``frame`` (``FRAME_DIGITS`` digits)."""
        return self._at(name, LIDAR_SWEEP.name(frame))

    def lidar_sweep_info(self, frame: int, name: str = LIDAR) -> str:
        """``<LIDAR>/sweep_NNNNNN.json``: the sweep's key, pose and returns (``backend.render.lidar_sweeps``)."""
        return self._at(name, LIDAR_SWEEP_INFO.name(frame))

    def surround(self, frame: int) -> str:
        """``surround_NNNNNN.png`` in a rig job's folder: its cameras tiled beside the sweep from above
        (``backend.render.surround_pictures``)."""
        return self._at(SURROUND.name(frame))

    # generated/
    @property
    def generated(self) -> str:
        return self._at(self.GENERATED)

    @property
    def manifest(self) -> str:
        return self._at(self.GENERATED, self.MANIFEST)

    def generated_frame(self, frame: int) -> str:
        return self._at(self.GENERATED, GENERATED_FRAME.name(frame))


class SceneFolder:
    """The paths of a Blender scene's output folder (``root``, absolute; nothing is created or checked here): one
    job output folder per camera (``camera``), and ``assets``."""

    ASSETS = "assets"
    VARIATIONS = "variations"      # Make Variations' default folder (``VariationLayout``)
    #: Names a camera's folder may not take: the scene folder's own, and the folders of an output folder, which a
    #: .blend rendered before the per-camera folders holds directly in its scene folder (its results stay there).
    RESERVED = (ASSETS, VARIATIONS, OutputLayout.CONDITIONS, OutputLayout.GENERATED, OutputLayout.EXPORT)

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = os.fspath(root)

    def __repr__(self) -> str:
        return f"SceneFolder({self.root!r})"

    def camera(self, folder_name: str) -> str:
        """The output folder of the camera whose folder name (a file-system-safe name) is ``folder_name``."""
        return os.path.join(self.root, folder_name)

    @property
    def assets(self) -> str:
        return os.path.join(self.root, self.ASSETS)

    @property
    def variations(self) -> str:
        return os.path.join(self.root, self.VARIATIONS)


class VariationLayout:
    """The folder a variation run writes (``vary``, docs/design.md §16)::

        <root>/
            variation.json      the manifest: the settings, the base, every variant (what it holds and why,
                                or why it could not be placed), the summary's counts
            variants.txt        the ``batch`` list: ``data-root:`` lines, then one job per placed variant
            library/            mesh cars converted once, recoloured copies (shared by every variant)
            base/job.json       the job the variants start from (when the run exported it from a scene)
            v0000/job.json      a variant's job; the folder is its output folder (``OutputLayout``)
            contact_sheet.png   the first frame of every variant (``contact-sheet``)
    """

    MANIFEST = "variation.json"
    LIST = "variants.txt"
    LIBRARY = "library"
    BASE = "base"
    SHEET = "contact_sheet.png"
    VARIANT_DIGITS = 4

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = os.fspath(root)

    def _at(self, *parts: str) -> str:
        return os.path.join(self.root, *parts)

    @property
    def manifest(self) -> str:
        return self._at(self.MANIFEST)

    @property
    def list(self) -> str:
        return self._at(self.LIST)

    @property
    def library(self) -> str:
        return self._at(self.LIBRARY)

    @property
    def base_job(self) -> str:
        return self._at(self.BASE, OutputLayout.JOB)

    @property
    def sheet(self) -> str:
        return self._at(self.SHEET)

    @classmethod
    def variant_name(cls, index: int) -> str:
        return f"v{int(index):0{cls.VARIANT_DIGITS}d}"

    def variant(self, index: int) -> OutputLayout:
        """Variant ``index``'s output folder."""
        return OutputLayout(self._at(self.variant_name(index)))


class DatasetLayout:
    """The top of a dataset exported from many jobs (``export --list``, docs/design.md §15; each format's folder is
    its writer's, and ``backend/export/dataset.py``'s docstring has the whole tree)::

        <root>/
            export.json         the record (``OutputLayout.EXPORT_RECORD``): formats, split, counts
            manifest.json       one row per image: its job, variant, drive, split, quality
            <format>/           one folder per format
    """

    RECORD = OutputLayout.EXPORT_RECORD
    MANIFEST = "manifest.json"
