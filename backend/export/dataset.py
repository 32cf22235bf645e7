"""One dataset from many jobs (a variation run, a batch list): ``python -m backend export --list variants.txt
--format coco,kitti,openlabel --out DATASET [--split val=0.1]`` and ``batch --command export`` (docs/design.md §15).

One process for every job and format: the jobs are loaded and their drives found first (so the split is known
before anything is written); then job after job, its output folder locked, what is missing rendered
(``command.rendered_job``, as a single export does), each frame read once (``command.read_frame``: labels, image,
the instance layer when a format needs it) and written in every format. The destination is written whole
(``outputs.atomic_folder``): a killed or failed export leaves no half dataset, and a previous dataset there (its
``OutputLayout.EXPORT_RECORD`` of format ``FORMAT``) is replaced only when the new one is complete; any other
content, a single-job export included, is refused (``command.check_destination``). Bad input in any job (its file,
its inputs) stops the whole export: a dataset silently missing jobs would be worse than none. ::

    DATASET/
        export.json                         the record: formats, split, counts (``FORMAT``: "dataset")
        manifest.json                       one row per image (``MANIFEST_SCHEMA``)
        coco/images/NNNNNN.png              COCO: one images folder,
        coco/annotations/instances_<split>.json   one annotations file per split (COCO's own naming)
        kitti/training/{image_2,label_2,calib}/NNNNNN.*   KITTI object: every image under training/ (the layout
        kitti/ImageSets/<split>.txt                      OpenPCDet and mmdetection3d read), one index list a split
        kitti/frames.json                   the KITTI writer's frame index, merged (index -> job, frame)
        openlabel/images/NNNNNN.png, openlabel/SSSS.json   OpenLABEL: one document per job (sequence SSSS)
        openlabel/<split>.txt               the documents of each split
        kitti-tracking/training/{image_02/SSSS/NNNNNN.png, label_02/SSSS.txt, calib/SSSS.txt, pose/SSSS.txt}
                                            KITTI tracking: one sequence SSSS per job, its frames numbered from 0
        kitti-tracking/<split>.txt          the sequences of each split; kitti-tracking/frames.json: their frames
        nuscenes/<version>/*.json, samples/, sweeps/, maps/   nuScenes: one dataroot, one scene per job
                                            (``scpainter-SSSS``); its ``<version>/splits.json`` lists each split's
                                            scenes. A rig job (several cameras, a LiDAR) exports as nuScenes only.

Names: image NNNNNN is the same frame in every format (sequential over the jobs in listed order, each job's frames in
its order: unique file names and ids); COCO image id = NNNNNN + 1, annotation ids unique over the dataset, one
category table for every split (``core.categories.CATEGORIES``, each annotation's class mapped by name).

Drives and splits: a job's drive is the recording it was made from (its ``scene.predictions`` file, links
followed); a job without one belongs to its variation's base job (``vary``'s ``variation.json`` beside its folder),
else to itself. ``--split val=0.1`` gives val a tenth of the drives (rounded, at least one when there are two or
more, always leaving one for train), drawn by the SHA-256 of the drive's path, so the split does not depend on the
list's order and no drive is in two splits; every job of a drive goes to its split.

One module over 400 lines: the jobs and their drives, the split, and the writer that places each format's files
under the dataset's names are one pass over the jobs sharing the numbering (``_Writer``); apart, each would need
the others' state passed around.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
from collections.abc import Sequence
from dataclasses import dataclass

from scpainter_blender.core import categories, errors, files, job_inputs, outputs
from scpainter_blender.core import job as job_mod
from scpainter_blender.core.batch_items import first_items, shared_output_items
from scpainter_blender.core.output_layout import DatasetLayout, OutputLayout, VariationLayout
from scpainter_blender.core.variation import proposals as proposals_core

from .. import events
from ..batch import command as batch
from ..render import proposals as render_proposals
from . import coco, command, common, kitti, kitti_tracking, nuscenes, openlabel

#: The record's ``format`` of a merged dataset (``command.check_destination`` replaces only its own kind).
FORMAT = "dataset"
MANIFEST = DatasetLayout.MANIFEST
MANIFEST_SCHEMA = "scpainter.dataset-manifest/1"
TRAIN = "train"
#: The warning event's ``code`` of a split that got no drive (fewer drives than splits).
EMPTY_SPLIT = "empty_split"
#: The sub-folders of the formats.
COCO_IMAGES, COCO_ANNOTATIONS = "images", "annotations"
KITTI_TRAINING, KITTI_SETS = "training", "ImageSets"
OPENLABEL_IMAGES = "images"
SPLIT_NAME = re.compile(r"[a-z][a-z0-9_]*")


class _Stopped(Exception):
    """SIGTERM while a job rendered: the temporary dataset is dropped."""


def parse_formats(text: str) -> list:
    """``--format coco,kitti`` -> ["coco", "kitti"] (each once, in the given order); ArgumentError naming
    ``--format`` for an unknown or empty one."""
    names = [t.strip() for t in str(text).split(",")]
    if not all(names):
        raise errors.ArgumentError("--format", f"{text!r}: expected formats separated by commas, e.g. coco,kitti")
    return list(dict.fromkeys(command.check_format(n) for n in names))


def parse_split(text: str | None) -> dict:
    """``--split val=0.1[,test=0.1]`` -> {"val": 0.1, ...}: the share of the drives each split gets, the rest
    train's; {} for None. ArgumentError naming ``--split`` unless each is NAME=FRACTION with a lower-case name other
    than train, 0 < FRACTION < 1, their sum below 1."""
    if text is None:
        return {}
    out = {}
    for part in str(text).split(","):
        name, eq, value = part.strip().partition("=")
        try:
            frac = float(value)
        except ValueError:
            frac = None
        if not eq or not SPLIT_NAME.fullmatch(name) or name == TRAIN or name in out or frac is None \
                or not 0.0 < frac < 1.0:
            raise errors.ArgumentError("--split", f"{part.strip()!r}: expected NAME=FRACTION with a lower-case name "
                                                  f"other than {TRAIN}, given once, and 0 < FRACTION < 1",
                                       hint="e.g. --split val=0.1 (a tenth of the drives for val, the rest train)")
        out[name] = frac
    if sum(out.values()) >= 1.0:
        raise errors.ArgumentError("--split", f"{text!r}: the fractions add up to {sum(out.values()):g}; train "
                                              "needs the rest (below 1 in all)")
    return out


def assign_splits(drives: Sequence[str], fractions: dict) -> dict:
    """{drive: split} for the drives (each once): ``fractions`` (``parse_split``) in order take
    round(fraction x drives) of them (at least one each when there are two drives or more; never the last one:
    train keeps at least one), drawn in the order of the SHA-256 of the drive's name; the others are train's."""
    unique = sorted(set(drives), key=lambda d: hashlib.sha256(d.encode("utf-8")).hexdigest())
    n, start, out = len(unique), 0, {}
    for name, frac in fractions.items():
        k = round(frac * n)
        if n >= 2:
            k = max(k, 1)
        k = max(0, min(k, n - 1 - start))
        out.update(dict.fromkeys(unique[start:start + k], name))
        start += k
    out.update(dict.fromkeys(unique[start:], TRAIN))
    return out


@dataclass
class Member:
    """A job of the dataset: ``path`` (absolute), the loaded ``job``, its confinement (``allow_outside``,
    ``data_roots``), what its variation manifest says of it (``variant``: the manifest's entry, None for a job
    that is no variant; ``base``: the base job, else None), ``drive``, ``identity`` (``nuscenes.job_identity``)
    and, once assigned, ``split``."""
    path: str
    job: job_mod.Job
    allow_outside: bool = False
    data_roots: tuple = ()
    variant: dict | None = None
    base: str | None = None
    drive: str = ""
    split: str = TRAIN
    sequence: int = 0
    images: str = ""
    identity: str = ""


def variation_entry(job_path: str, manifests: dict) -> tuple:
    """(base job path, manifest entry) of a variant job (``vary``'s layout: ``<run>/vNNNN/job.json`` beside
    ``<run>/variation.json``, whose ``variants[i].job`` names it), else (None, None). ``manifests`` caches the
    manifests read (path -> dict or None). InputError naming the manifest when it cannot be read."""
    run = os.path.dirname(os.path.dirname(job_path))
    path = os.path.join(run, VariationLayout.MANIFEST)
    if path not in manifests:
        manifests[path] = files.read_json(path) if os.path.isfile(path) else None
    manifest = manifests[path]
    if manifest is None:
        return None, None
    if not isinstance(manifest, dict) or not isinstance(manifest.get("variants"), list):
        raise errors.InputError(path, "variants", "expected the list of a vary run's variants",
                                hint="run vary again, or list jobs that are not in a vary run's folder")
    for e in manifest["variants"]:
        if isinstance(e, dict) and isinstance(e.get("job"), str) and \
                os.path.normpath(os.path.join(run, e["job"])) == os.path.normpath(job_path):
            base = manifest.get("base")
            return (os.path.abspath(base) if isinstance(base, str) else None), e
    return None, None


def drive_of(member: Member) -> str:
    """The drive a job shows: its recording (``scene.predictions``, links followed), else its variation's base job,
    else the job itself."""
    sc = member.job.scene
    if sc is not None and sc.predictions:
        return os.path.realpath(job_mod.resolve(member.path, sc.predictions))
    return member.base or member.path


def members(items: Sequence[str], allow_outside=False, data_roots: dict | None = None,
            formats: Sequence[str] | None = None) -> list:
    """The dataset's jobs: each item (a job path; ``allow_outside`` True, False or the collection of the items that
    may lead outside, ``data_roots`` {item: folders}, as ``batch`` takes them) loaded once (a job listed again is
    skipped), with its variation and drive. InputError: a job that cannot be read, two jobs sharing an output
    folder (``batch_items.shared_output_items``); a rig job when ``formats`` (the dataset's) is not nuScenes alone
    (JobError on ``rig``, its hint ``--format nuscenes``)."""
    items = list(items)
    first = first_items(items)
    for fields in shared_output_items(items, first).values():   # its error's text: "<file>: <field>: <message>"
        raise errors.InputError(fields["file"], fields["field"], fields["error"].split(": ", 2)[-1],
                                hint=fields["hint"])
    manifests: dict = {}
    out = []
    for k, item in enumerate(items):
        if first[k] != k:
            continue
        path = os.path.abspath(item)
        job = job_mod.load(path)
        if formats is not None and list(formats) != [nuscenes.FORMAT]:   # nuScenes alone takes several cameras
            job.require_single_camera(
                path, f"a dataset export as {','.join(formats)}",
                hint=f"--format {nuscenes.FORMAT} takes rig jobs (one scene per job); for another format export "
                     "the rig job on its own, one format at a time: one export per camera in <out>/<camera>/")
        m = Member(path, job, batch.allows_outside(allow_outside, item),
                   tuple((data_roots or {}).get(item, ())))
        m.base, m.variant = variation_entry(path, manifests)
        m.drive = drive_of(m)
        m.identity = nuscenes.job_identity(path)   # its nuScenes tokens' seed
        m.sequence = len(out)
        out.append(m)
    return out


def _variant_fields(m: Member) -> dict:
    """A manifest row's fields of the job: the job, its variant (id, seed, camera shift, lane change, cars), its
    base job, drive and split."""
    v = m.variant or {}
    cam = v.get("camera") or {}
    return {"sequence": m.sequence, "job": m.path, "variant": v.get("id"), "base": m.base, "drive": m.drive,
            "split": m.split, "seed": v.get("seed"), "camera_shift_m": cam.get("shift_m"),
            "lane_change": cam.get("lane_change"), "cars": [c.get("name") for c in v.get("cars", [])]}


class _Writer:
    """The dataset being written into ``root`` (the temporary folder): each job's frames added in every format."""

    def __init__(self, root: str, formats: list, splits: list, options: dict | None = None) -> None:
        self.root, self.formats, self.splits = root, formats, splits
        self.next_index = 0
        self.rows: list = []
        self.counts = {f: {s: {"frames": 0, "objects": 0, "ignore_regions": 0} for s in splits} for f in formats}
        self.coco = {s: {"images": [], "annotations": []} for s in splits}
        self.coco_info = None
        self.annotations = 0   # COCO annotation ids so far: unique over the dataset, from 1
        self.kitti_frames: list = []
        self.kitti_sets: dict = {s: [] for s in splits}
        self.openlabel_sets: dict = {s: [] for s in splits}
        self.tracking_sets: dict = {s: [] for s in splits}
        self.tracking_frames: list = []
        for f in formats:
            outputs.make_folder(os.path.join(root, f))
        self.nuscenes = nuscenes.Writer(os.path.join(root, nuscenes.FORMAT), **(options or {})) \
            if nuscenes.FORMAT in formats else None

    def add(self, m: Member, frames: list) -> None:
        """Job ``m``'s frames (``common.ExportFrame``, in its order) in every format; their manifest rows."""
        first = self.next_index
        names = [common.index_name(first + i, "") for i in range(len(frames))]
        for fmt in self.formats:
            written = getattr(self, "_" + fmt.replace("-", "_"))(m, frames, names)
            counts = self.counts[fmt][m.split]
            counts["frames"] += len(frames)
            counts["objects"] += written["objects"]   # as each format's own export counts them
            counts["ignore_regions"] += written["ignore_regions"]
        job_fields = _variant_fields(m)
        for name, fr in zip(names, frames):
            lab = fr.labels
            self.rows.append({"index": name, "image": name + ".png", **job_fields, "frame": lab["frame"],
                              "timestamp_s": lab["timestamp_s"], "images": m.images, **common.frame_quality(lab)})
        self.next_index += len(frames)

    def _coco(self, m: Member, frames: list, names: list) -> int:
        folder = os.path.join(self.root, "coco", COCO_IMAGES)
        outputs.make_folder(folder)
        files_ = [n + ".png" for n in names]
        for fr, name in zip(frames, files_):
            common.copy_image(fr.image, os.path.join(folder, name))
        data = coco.dataset(frames, files_)
        self.coco_info = self.coco_info or data.get("info")
        names_of = {c["id"]: c["name"] for c in data["categories"]}
        place = {name: self.next_index + i + 1 for i, name in enumerate(files_)}   # COCO ids from 1
        image_id = {img["id"]: place[img["file_name"]] for img in data["images"]}
        split = self.coco[m.split]
        for img in data["images"]:
            split["images"].append({**img, "id": image_id[img["id"]]})
        for ann in data["annotations"]:
            name = names_of[ann["category_id"]]
            if name not in categories.BY_NAME:
                raise errors.InputError(m.path, "class", f"the class {name!r} is not in the category table "
                                                         f"({', '.join(categories.NAMES)})",
                                        hint="give the object one of the table's classes (core/categories.py)")
            self.annotations += 1
            split["annotations"].append({**ann, "id": self.annotations, "image_id": image_id[ann["image_id"]],
                                         "category_id": categories.category_id(name)})
        crowd = sum(ann["iscrowd"] for ann in data["annotations"])
        return {"objects": len(data["annotations"]) - crowd, "ignore_regions": crowd}

    def _kitti(self, m: Member, frames: list, names: list) -> int:
        """The KITTI writer's files of this job (written into a scratch folder) moved under ``training/`` with
        the dataset's names; its frames index merged."""
        scratch = os.path.join(self.root, ".kitti_job")
        outputs.make_folder(scratch)
        counts = kitti.write(scratch, frames)
        training = os.path.join(self.root, "kitti", KITTI_TRAINING)
        local = {common.index_name(i, ""): name for i, name in enumerate(names)}
        for entry in sorted(os.listdir(scratch)):
            src = os.path.join(scratch, entry)
            if entry == kitti.FRAMES:
                with open(src, encoding="utf-8") as f:
                    for row in json.load(f)["frames"]:
                        self.kitti_frames.append({**row, "index": local[row["index"]], "sequence": m.sequence})
                continue
            if not os.path.isdir(src):
                raise RuntimeError(f"the KITTI writer wrote {entry}, which a merged dataset does not place")
            dest = os.path.join(training, entry)
            outputs.make_folder(dest)
            for name in os.listdir(src):
                stem, ext = os.path.splitext(name)
                if stem not in local:
                    raise RuntimeError(f"the KITTI writer wrote {entry}/{name}, not a frame's NNNNNN file")
                os.rename(os.path.join(src, name), os.path.join(dest, local[stem] + ext))
        shutil.rmtree(scratch)
        self.kitti_sets[m.split] += names
        return counts

    def _openlabel(self, m: Member, frames: list, names: list) -> int:
        folder = os.path.join(self.root, "openlabel")
        outputs.make_folder(os.path.join(folder, OPENLABEL_IMAGES))
        rel = [f"{OPENLABEL_IMAGES}/{n}.png" for n in names]
        for fr, r in zip(frames, rel):
            common.copy_image(fr.image, os.path.join(folder, r))
        name = (m.variant or {}).get("id") or os.path.basename(os.path.dirname(m.path)) or "job"
        doc = openlabel.document(frames, rel, name=f"{m.sequence:04d} {name}")
        doc_name = f"{m.sequence:04d}.json"
        with outputs.atomic_write(os.path.join(folder, doc_name), "w") as f:
            json.dump(doc, f, allow_nan=False)
        self.openlabel_sets[m.split].append(doc_name)
        return openlabel.counts(doc)

    def _kitti_tracking(self, m: Member, frames: list, names: list) -> int:
        """The job as one KITTI tracking sequence (``m.sequence``, four digits): the tracking writer's sequence
        ``0000`` (written into a scratch folder) moved under ``training/`` with its number; its frames index
        merged."""
        scratch = os.path.join(self.root, ".kitti_tracking_job")
        outputs.make_folder(scratch)
        counts = kitti_tracking.write(scratch, frames)
        seq, own = f"{m.sequence:04d}", kitti_tracking.SEQUENCE
        training = os.path.join(self.root, "kitti-tracking", KITTI_TRAINING)
        for sub in (kitti_tracking.LABELS, kitti_tracking.CALIB, kitti_tracking.POSES):
            outputs.make_folder(os.path.join(training, sub))
            os.rename(os.path.join(scratch, sub, own + ".txt"), os.path.join(training, sub, seq + ".txt"))
        outputs.make_folder(os.path.join(training, kitti_tracking.IMAGES))
        os.rename(os.path.join(scratch, kitti_tracking.IMAGES, own), os.path.join(training, kitti_tracking.IMAGES, seq))
        with open(os.path.join(scratch, kitti.FRAMES), encoding="utf-8") as f:
            for row, name in zip(json.load(f)["frames"], names):
                self.tracking_frames.append({**row, "sequence": seq, "image": name + ".png"})
        shutil.rmtree(scratch)
        self.tracking_sets[m.split].append(seq)
        return counts

    def _nuscenes(self, m: Member, frames: list, names: list) -> dict:
        """The job as one scene of the nuScenes dataroot (``frames``: a single-camera job's; a rig job's clip is
        read from its output folder by ``add_rig``)."""
        return self.nuscenes.add(nuscenes.clip_of_frames(frames, nuscenes.scene_name(m.sequence),
                                                         nuscenes.job_description(m.path), m.identity), m.split)

    def add_rig(self, m: Member, root: str) -> None:
        """A rig job (its output folder ``root``) into the nuScenes dataroot (the only format a rig job has here);
        one manifest row per frame (its image: CAM_FRONT's, else the first camera's)."""
        clip, m.images, _ = nuscenes.job_clip(m.job, root, nuscenes.scene_name(m.sequence),
                                              nuscenes.job_description(m.path), m.identity)
        written = self.nuscenes.add(clip, m.split)
        counts = self.counts[nuscenes.FORMAT][m.split]
        for k in ("frames", "objects", "ignore_regions"):
            counts[k] += written[k]
        cam = next((c for c in clip.cameras if c.name == "CAM_FRONT"), clip.cameras[0])
        job_fields = _variant_fields(m)
        for i, lab in enumerate(cam.labels):
            name = common.index_name(self.next_index + i, "")
            self.rows.append({"index": name, "image": None, "camera": cam.name, **job_fields, "frame": lab["frame"],
                              "timestamp_s": lab["timestamp_s"], "images": m.images, **common.frame_quality(lab)})
        self.next_index += len(cam.labels)

    def finish(self) -> None:
        """What is written once every job is in: COCO's annotation files, KITTI's index lists and frames index,
        OpenLABEL's split lists, nuScenes' tables."""
        if self.nuscenes is not None:
            self.nuscenes.finish()
        if "coco" in self.formats:
            folder = os.path.join(self.root, "coco", COCO_ANNOTATIONS)
            outputs.make_folder(folder)
            table = [{"id": c.id, "name": c.name, "supercategory": c.supercategory} for c in categories.CATEGORIES]
            for split, data in self.coco.items():
                with outputs.atomic_write(os.path.join(folder, f"instances_{split}.json"), "w") as f:
                    json.dump({"info": self.coco_info or {}, **data, "categories": table}, f, allow_nan=False)
        if "kitti" in self.formats:
            sets = os.path.join(self.root, "kitti", KITTI_SETS)
            outputs.make_folder(sets)
            for split, names in self.kitti_sets.items():
                _write_lines(os.path.join(sets, f"{split}.txt"), names)
            with outputs.atomic_write(os.path.join(self.root, "kitti", kitti.FRAMES), "w") as f:
                json.dump({"frames": self.kitti_frames}, f, indent=1)
        if "openlabel" in self.formats:
            for split, docs in self.openlabel_sets.items():
                _write_lines(os.path.join(self.root, "openlabel", f"{split}.txt"), docs)
        if "kitti-tracking" in self.formats:
            for split, seqs in self.tracking_sets.items():
                _write_lines(os.path.join(self.root, "kitti-tracking", f"{split}.txt"), seqs)
            with outputs.atomic_write(os.path.join(self.root, "kitti-tracking", kitti.FRAMES), "w") as f:
                json.dump({"frames": self.tracking_frames}, f, indent=1)


def _write_lines(path: str, lines: list) -> None:
    with outputs.atomic_write(path, "w") as f:
        f.writelines(f"{line}\n" for line in lines)


def check_out(out: str, jobs: list, formats: list) -> None:
    """``--out`` may be new, empty or a previous dataset of this command in the same ``formats``; never other
    content (a single-job export included), a dataset of other formats (replacing it would silently delete those)
    or a folder holding a job's output folder (``command.check_destination``, for every job)."""
    for m in jobs:
        command.check_destination(out, job_mod.resolve(m.path, m.job.output_dir), given=True, fmt=FORMAT)
    record = os.path.join(out, OutputLayout.EXPORT_RECORD)
    if os.path.isfile(record):
        try:
            previous = files.read_json(record).get("formats")
        except (errors.InputError, AttributeError):
            previous = None
        if not isinstance(previous, list) or sorted(map(str, previous)) != sorted(formats):
            was = ",".join(map(str, previous)) if isinstance(previous, list) else "unknown formats"
            raise errors.ArgumentError(
                "--out", f"{out} holds a dataset of {was}, not {','.join(formats)}: replacing it would delete the "
                "formats this export does not write", hint=f"give a new folder, or --format {was}")


def export_dataset(items: Sequence[str], formats: Sequence[str], out: str, split: dict | None = None,
                   device: str = "cpu", allow_outside=False, stop=(), data_roots: dict | None = None,
                   proposals: str | None = None, options: dict | None = None) -> dict:
    """Export the jobs ``items`` as one dataset per format (``formats``, ``command.FORMATS``' names) under
    ``out``, split by drive (``split``: ``parse_split``'s), rendering what each job is missing. ``allow_outside``,
    ``data_roots``: as ``members``; ``proposals``: each job's box proposals (``backend/render/proposals.py``; None:
    its default mode); ``options``: the nuScenes format's (``nuscenes.check_options``). Emits a progress event per
    frame and warning events. Returns the done
    event's fields (``out``, ``formats``, ``jobs``, ``frames``, ``rendered``, ``counts`` {format: {split:
    {"frames", "objects"}}}, ``splits`` {split: {"drives", "jobs", "frames"}}, ``images``, ``manifest``) and
    ``stopped`` (SIGTERM while rendering: nothing written)."""
    formats = [command.check_format(f) for f in formats]
    split = dict(split or {})
    out = os.path.abspath(out)
    jobs = members(items, allow_outside, data_roots, formats)
    if not jobs:
        raise errors.ArgumentError("jobs", "no jobs given", hint="give job.json paths, or --list FILE")
    for m in jobs:  # what nothing labels, as a single export adds it (label-only: the layers are kept)
        m.job, _ = render_proposals.apply(m.path, m.job, proposals or proposals_core.DEFAULT_MODE, m.allow_outside,
                                          m.data_roots)
    check_out(out, jobs, formats)
    options = nuscenes.check_options(**(options or {})) if nuscenes.FORMAT in formats else None
    drives = assign_splits([m.drive for m in jobs], split)
    for m in jobs:
        m.split = drives[m.drive]
    splits = [TRAIN, *split]
    for name in split:
        if name not in drives.values():
            events.warning(f"the split {name} has no drive: {len(set(drives))} drive(s) in all, and train keeps one "
                           "(a split by drive needs several drives)", EMPTY_SPLIT, split=name)
    instance = any(command.FORMATS[f].NEEDS_INSTANCE for f in formats)
    total = sum(len(m.job.frames) for m in jobs)
    done, rendered = 0, 0
    outputs.make_folder(os.path.dirname(out), "--out")
    try:
        with outputs.atomic_folder(out, replace=True, usual_mode=True, record=OutputLayout.EXPORT_RECORD) as tmp:
            writer = _Writer(tmp, formats, splits, options)
            for m in jobs:
                if stop:
                    raise _Stopped
                paths = command.checked_paths(m.path, m.job, m.allow_outside, m.data_roots)
                layout = OutputLayout(paths["output_dir"])
                with job_inputs.reading(m.path, m.allow_outside, m.data_roots), \
                        command.rendered_job(m.path, m.job, device, paths, m.allow_outside, stop) as (render, log):
                    rendered += render["rendered"]
                    if render["stopped"]:
                        raise _Stopped
                    if getattr(m.job, "rig", None) is not None:
                        writer.add_rig(m, layout.root)
                        done += len(m.job.frames)
                        events.progress("export", done, total, job=m.path)
                        continue
                    m.images, _ = command.image_source(layout, m.job)
                    frames = []
                    for e in m.job.frames:
                        frames.append(command.read_frame(layout, e.frame, m.images, instance))
                        done += 1
                        events.progress("export", done, total, frame=e.frame, job=m.path)
                    writer.add(m, frames)
                    log(f"export: {len(frames)} frames into the dataset {out} (sequence {m.sequence}, {m.split})")
            writer.finish()
            result = _summary(out, formats, split, jobs, writer, rendered)
            outputs.write_json(os.path.join(tmp, MANIFEST), {"schema": MANIFEST_SCHEMA, "images": writer.rows})
            outputs.write_json(os.path.join(tmp, OutputLayout.EXPORT_RECORD), {
                "schema": command.EXPORT_SCHEMA, "format": FORMAT, "formats": formats, "split": split,
                **{k: result[k] for k in ("jobs", "frames", "counts", "splits", "images")},
                "members": [_variant_fields(m) for m in jobs]})
    except _Stopped:
        return {"out": out, "formats": formats, "rendered": rendered, "stopped": True}
    conditions = [m.path for m in jobs if m.images == "conditions"]
    if conditions:
        events.warning(f"{len(conditions)} of {len(jobs)} jobs export the condition previews as images (no finished "
                       "generation of their frames): run generate first for the generated video's frames",
                       command.NO_GENERATED, jobs=conditions)
    return {**result, "stopped": False}


def _summary(out: str, formats: list, split: dict, jobs: list, writer: _Writer, rendered: int) -> dict:
    splits = {}
    for name in [TRAIN, *split]:
        mine = [m for m in jobs if m.split == name]
        splits[name] = {"drives": len({m.drive for m in mine}), "jobs": len(mine),
                        "frames": sum(len(m.job.frames) for m in mine)}
    images = {"generated": sum(m.images == "generated" for m in jobs),
              "conditions": sum(m.images == "conditions" for m in jobs)}
    return {"out": out, "formats": formats, "split": split, "jobs": len(jobs), "frames": writer.next_index,
            "rendered": rendered, "counts": writer.counts, "splits": splits, "images": images,
            "manifest": os.path.join(out, MANIFEST)}
