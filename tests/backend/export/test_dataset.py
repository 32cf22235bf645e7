"""One dataset from a whole run (backend/export/dataset.py): three variants of two base drives, rendered once by
the command itself (a 2-frame, 96 x 64 job with one procedural car each), exported as COCO, KITTI and OpenLABEL with a
split by drive; the split's rules on their own; what the destination may hold; nothing left by a failed export."""

import json
import os

import numpy as np
import pytest

from tests.backend.export import export_fixtures as F
from backend.export import dataset
from scpainter_blender.core import categories, errors, outputs
from scpainter_blender.core import job as J
from scpainter_blender.core.batch_items import DATA_ROOT_DIRECTIVE
from scpainter_blender.core.output_layout import OutputLayout, VariationLayout
from tests_support import run_backend_here

FORMATS = "coco,kitti,openlabel,kitti-tracking"


def _run(root, variants: list) -> str:
    """A vary run's folder as ``vary`` leaves it, for jobs without a scene: ``base/job.json``, ``vNNNN/job.json``
    (the car at ``variants[i]``'s x), ``variation.json`` (the fields the dataset reads), ``variants.txt``.
    Returns the list's path."""
    from scpainter_blender.core import shapes

    layout = VariationLayout(str(root))
    os.makedirs(layout.library)
    ply = os.path.join(layout.library, "car.ply")
    to_file = shapes.save_as_amodal3r(ply, shapes.procedural_car_gaussians(count=2000, seed=1))

    def job(x):
        o2w = F.placed(x, 9.0, 20.0) @ np.linalg.inv(to_file)
        frames = [J.Frame(f, F.K.copy(), F.world_to_camera(0.1 * i)) for i, f in enumerate(F.FRAMES)]
        return J.Job((F.W, F.H), frames, ".", None,
                     [J.Asset("car_01", "../library/car.ply", {f: o2w for f in F.FRAMES})], fps=10.0)

    J.save(layout.base_job, job(0.0))
    entries = []
    for i, x in enumerate(variants):
        name = VariationLayout.variant_name(i)
        J.save(os.path.join(layout.root, name, "job.json"), job(x))
        entries.append({"id": name, "seed": [3, i], "outcome": "placed", "job": f"{name}/job.json",
                        "camera": {"shift_m": float(i), "lane_change": None}, "cars": [{"name": "car_01"}]})
    outputs.write_json(layout.manifest, {"schema": "scpainter.variation-manifest/1", "base": layout.base_job,
                                         "variants": entries})
    with open(layout.list, "w") as f:
        f.write(f"{DATA_ROOT_DIRECTIVE} .\n" + "".join(e["job"] + "\n" for e in entries))
    return layout.list


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    lists = [_run(root / "a", [-1.0, 1.0]), _run(root / "b", [0.5])]
    out = root / "dataset"
    code, ev, err = run_backend_here("export", "--list", lists[0], "--list", lists[1], "--format", FORMATS,
                                "--out", out, "--split", "val=0.5", "--device", "cpu")
    assert code == 0, err[-3000:]
    return root, lists, out, ev


def test_one_dataset_of_every_format_split_by_drive(exported):
    root, lists, out, ev = exported
    done = ev[-1]
    assert done["event"] == "done" and done["command"] == "export" and done["jobs"] == 3 and done["frames"] == 6
    assert done["rendered"] == 6 and set(done["counts"]) == {"coco", "kitti", "openlabel", "kitti-tracking"}
    assert [e["done"] for e in ev if e["event"] == "progress" and e["stage"] == "export"] == [1, 2, 3, 4, 5, 6]
    splits = done["splits"]
    assert splits["train"]["drives"] == splits["val"]["drives"] == 1
    assert splits["train"]["frames"] + splits["val"]["frames"] == 6

    manifest = json.loads((out / dataset.MANIFEST).read_text())["images"]
    assert [r["index"] for r in manifest] == [f"{i:06d}" for i in range(6)]         # every image, once
    drives = {s: {r["drive"] for r in manifest if r["split"] == s} for s in ("train", "val")}
    assert drives["train"] and drives["val"] and not drives["train"] & drives["val"]  # no drive in both
    assert {r["drive"] for r in manifest} == {str(root / "a" / "base" / "job.json"),
                                             str(root / "b" / "base" / "job.json")}
    row = next(r for r in manifest if r["variant"] == "v0001")
    assert row["seed"] == [3, 1] and row["camera_shift_m"] == 1.0 and row["cars"] == ["car_01"]
    assert {"coverage", "flags", "frame", "timestamp_s", "job"} <= set(row)

    from pycocotools.coco import COCO

    image_ids, ann_ids = [], []
    for split in ("train", "val"):
        api = COCO(str(out / "coco" / "annotations" / f"instances_{split}.json"))
        imgs = api.loadImgs(api.getImgIds())
        assert sorted(i["file_name"] for i in imgs) == sorted(r["image"] for r in manifest if r["split"] == split)
        assert all((out / "coco" / "images" / i["file_name"]).is_file() for i in imgs)
        assert [c["id"] for c in api.loadCats(api.getCatIds())] == [c.id for c in categories.CATEGORIES]
        for ann in api.loadAnns(api.getAnnIds()):
            assert api.annToMask(ann).sum() > 0 and ann["category_id"] == categories.category_id("car")
        crowd = len(api.getAnnIds(iscrowd=True))
        assert done["counts"]["coco"][split] == {"frames": len(imgs), "objects": len(api.getAnnIds()) - crowd,
                                                 "ignore_regions": crowd}
        image_ids += api.getImgIds()
        ann_ids += api.getAnnIds()
    assert sorted(image_ids) == list(range(1, 7)) and len(set(ann_ids)) == len(ann_ids)

    kitti = out / "kitti"
    sets = {s: (kitti / "ImageSets" / f"{s}.txt").read_text().split() for s in ("train", "val")}
    assert sorted(sets["train"] + sets["val"]) == [r["index"] for r in manifest]
    assert sets["val"] == [r["index"] for r in manifest if r["split"] == "val"]
    for sub, ext in (("image_2", ".png"), ("label_2", ".txt"), ("calib", ".txt")):
        assert sorted(os.listdir(kitti / "training" / sub)) == [r["index"] + ext for r in manifest]
    index = json.loads((kitti / "frames.json").read_text())["frames"]
    assert [(r["index"], r["frame"]) for r in index] == [(r["index"], r["frame"]) for r in manifest]

    for split in ("train", "val"):
        docs = (out / "openlabel" / f"{split}.txt").read_text().split()
        assert len(docs) == splits[split]["jobs"]
        for name in docs:
            doc = json.loads((out / "openlabel" / name).read_text())["openlabel"]
            uris = [f["frame_properties"]["streams"]["camera"]["uri"] for f in doc["frames"].values()]
            assert all((out / "openlabel" / u).is_file() for u in uris)
    tracking = out / "kitti-tracking"
    seqs = {s: (tracking / f"{s}.txt").read_text().split() for s in ("train", "val")}
    assert sorted(seqs["train"] + seqs["val"]) == ["0000", "0001", "0002"]     # one sequence per job
    assert len(seqs["val"]) == splits["val"]["jobs"]
    for sub in ("label_02", "calib", "pose"):
        assert sorted(os.listdir(tracking / "training" / sub)) == ["0000.txt", "0001.txt", "0002.txt"]
    for seq in seqs["train"] + seqs["val"]:
        assert sorted(os.listdir(tracking / "training" / "image_02" / seq)) == ["000000.png", "000001.png"]
        lines = (tracking / "training" / "label_02" / f"{seq}.txt").read_text().splitlines()
        assert {int(line.split()[0]) for line in lines} <= {0, 1} and all(line.split()[2] == "Car" for line in lines)
    rows = json.loads((tracking / "frames.json").read_text())["frames"]
    assert [r["image"] for r in rows] == [r["image"] for r in manifest]        # the manifest's image, per frame
    assert done["counts"]["kitti-tracking"]["train"]["frames"] == splits["train"]["frames"]
    record = json.loads((out / OutputLayout.EXPORT_RECORD).read_text())
    assert record["format"] == dataset.FORMAT and record["split"] == {"val": 0.5}


def test_the_same_frame_has_the_same_image_in_every_format(exported):
    _, _, out, _ = exported
    for name in ("000000.png", "000005.png"):
        a = (out / "coco" / "images" / name).read_bytes()
        assert a == (out / "kitti" / "training" / "image_2" / name).read_bytes()
        assert a == (out / "openlabel" / "images" / name).read_bytes()


def test_batch_export_writes_the_same_dataset_and_replaces_its_own(exported, capsys):
    from backend.__main__ import main

    root, lists, out, _ = exported
    again = root / "again"
    assert main(["batch", "--list", str(lists[0]), "--list", str(lists[1]), "--command", "export", "--format",
                 FORMATS, "--out", str(again), "--split", "val=0.5", "--device", "cpu"]) == 0
    done = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert done["command"] == "batch" and done["rendered"] == 0 and done["frames"] == 6
    for rel in ("manifest.json", "coco/annotations/instances_val.json", "kitti/ImageSets/val.txt"):
        assert (again / rel).read_bytes() == (out / rel).read_bytes()
    # a previous dataset of the same formats is replaced (here by one run's jobs, one split)
    assert main(["export", "--list", str(lists[0]), "--format", FORMATS, "--out", str(again)]) == 0
    assert json.loads((again / "export.json").read_text())["jobs"] == 2
    assert sorted(os.listdir(again)) == sorted(["export.json", "manifest.json", *FORMATS.split(",")])


def test_batch_export_as_nuscenes_one_scene_per_job_with_its_split(exported, capsys):
    pytest.importorskip("nuscenes")
    from nuscenes.nuscenes import NuScenes

    from backend.__main__ import main

    root, lists, _, _ = exported
    nus = root / "nus"
    assert main(["batch", "--list", str(lists[0]), "--list", str(lists[1]), "--command", "export", "--format",
                 "nuscenes", "--out", str(nus), "--split", "val=0.5", "--version", "v1.0-trainval",
                 "--keyframe-hz", "10", "--device", "cpu"]) == 0
    done = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert done["rendered"] == 0 and done["frames"] == 6
    nusc = NuScenes("v1.0-trainval", str(nus / "nuscenes"), verbose=False)
    assert [s["name"] for s in nusc.scene] == ["scpainter-0000", "scpainter-0001", "scpainter-0002"]
    assert len(nusc.sample) == 6 and len(nusc.sample_annotation) == done["counts"]["nuscenes"]["train"]["objects"] \
        + done["counts"]["nuscenes"]["val"]["objects"] > 0
    splits = json.loads((nus / "nuscenes" / "v1.0-trainval" / "splits.json").read_text())
    assert sorted(len(v) for v in splits.values()) == [1, 2]         # by drive: run a's two variants together
    assert main(["batch", "--list", str(lists[0]), "--version", "v1.0-mini"]) == 2   # an export option elsewhere


def test_a_folder_with_other_content_or_another_export_is_refused(exported, tmp_path):
    root, lists, _, _ = exported
    jobs = [str(root / "a" / "v0000" / "job.json")]
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("keep me")
    single = tmp_path / "single"
    single.mkdir()
    (single / OutputLayout.EXPORT_RECORD).write_text('{"format": "coco"}')
    for folder, says in ((mine, "other content"), (single, "holds a coco export"), (root / "a", "output folder")):
        with pytest.raises(errors.ArgumentError, match=says) as e:
            dataset.export_dataset(jobs, ["kitti"], str(folder), data_roots={jobs[0]: (str(root / "a"),)})
        assert e.value.field == "--out"
    assert (mine / "thesis.tex").read_text() == "keep me" and os.listdir(single) == [OutputLayout.EXPORT_RECORD]
    # a dataset of other formats is not replaced by one of fewer: that would delete the formats left out
    _, _, out, _ = exported
    made = sorted(os.listdir(out))
    with pytest.raises(errors.ArgumentError, match="holds a dataset of coco,kitti,openlabel,kitti-tracking") as e:
        dataset.export_dataset(jobs, ["coco"], str(out), data_roots={jobs[0]: (str(root / "a"),)})
    assert e.value.field == "--out" and sorted(os.listdir(out)) == made


def test_a_failed_export_leaves_nothing_and_keeps_the_previous_dataset(exported, tmp_path, monkeypatch):
    root, _, _, _ = exported
    jobs = [str(root / "a" / "v0000" / "job.json"), str(root / "b" / "v0000" / "job.json")]
    roots = {jobs[0]: (str(root / "a"),), jobs[1]: (str(root / "b"),)}
    out = tmp_path / "d"
    dataset.export_dataset(jobs, ["kitti", "openlabel"], str(out), data_roots=roots)
    before = sorted(os.listdir(out / "kitti" / "training" / "label_2"))
    calls = []

    def killed(frames, names, name="x"):   # the second job: killed half-way through the dataset
        calls.append(name)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(frames, names, name)

    real = dataset.openlabel.document
    monkeypatch.setattr(dataset.openlabel, "document", killed)
    with pytest.raises(KeyboardInterrupt):
        dataset.export_dataset(jobs, ["kitti", "openlabel"], str(out), data_roots=roots)
    assert sorted(os.listdir(tmp_path)) == ["d"]                                     # no temporary left
    assert sorted(os.listdir(out / "kitti" / "training" / "label_2")) == before      # the previous one, whole
    calls.clear()
    with pytest.raises(KeyboardInterrupt):
        dataset.export_dataset(jobs, ["openlabel"], str(tmp_path / "new"), data_roots=roots)
    assert sorted(os.listdir(tmp_path)) == ["d"]                                     # a new one: nothing at all


def test_a_run_of_twenty_variants_of_four_drives_is_one_dataset_split_by_drive(tmp_path):
    """Issue 41's done-when: 20 variants (four base drives, five variants each) rendered and exported in one call
    as one COCO + KITTI dataset with ``--split val=0.25``: one drive's five variants in val, the others' in train,
    every image once with its own id, each split loaded by pycocotools."""
    from pycocotools.coco import COCO

    lists = [_run(tmp_path / f"drive_{d}", [0.3 * k - 0.6 for k in range(5)]) for d in range(4)]
    jobs = [os.path.join(os.path.dirname(lst), line.strip()) for lst in lists
            for line in open(lst) if line.strip() and not line.startswith(DATA_ROOT_DIRECTIVE)]
    roots = {j: (os.path.dirname(os.path.dirname(j)),) for j in jobs}
    out = tmp_path / "dataset"
    done = dataset.export_dataset(jobs, ["coco", "kitti"], str(out), {"val": 0.25}, data_roots=roots)
    assert done["jobs"] == 20 and done["frames"] == 40 and done["rendered"] == 40
    assert done["splits"]["val"] == {"drives": 1, "jobs": 5, "frames": 10}
    assert done["splits"]["train"] == {"drives": 3, "jobs": 15, "frames": 30}
    manifest = json.loads((out / dataset.MANIFEST).read_text())["images"]
    by_split = {s: {r["drive"] for r in manifest if r["split"] == s} for s in ("train", "val")}
    assert len(by_split["val"]) == 1 and len(by_split["train"]) == 3 and not by_split["val"] & by_split["train"]
    ids = []
    for split in ("train", "val"):
        api = COCO(str(out / "coco" / "annotations" / f"instances_{split}.json"))
        ids += api.getImgIds()
        assert all(api.annToMask(a).sum() > 0 for a in api.loadAnns(api.getAnnIds()))
    assert sorted(ids) == list(range(1, 41))


def test_splits_are_by_drive_deterministic_and_leave_train_a_drive():
    drives = [f"/data/drive_{i}" for i in range(20)]
    a = dataset.assign_splits(drives, {"val": 0.1})
    assert a == dataset.assign_splits(list(reversed(drives)) * 2, {"val": 0.1})       # not the list's order
    assert sorted(a.values()).count("val") == 2
    b = dataset.assign_splits(drives, {"val": 0.2, "test": 0.1})
    assert [sorted(b.values()).count(s) for s in ("test", "train", "val")] == [2, 14, 4]
    assert dataset.assign_splits(drives[:2], {"val": 0.9}) != dict.fromkeys(drives[:2], "val")  # train keeps one
    assert set(dataset.assign_splits(drives[:2], {"val": 0.01}).values()) == {"train", "val"}   # at least one
    assert dataset.assign_splits(drives[:1], {"val": 0.5}) == {drives[0]: "train"}


@pytest.mark.parametrize("text", ["val", "val=0", "val=1", "train=0.1", "Val=0.1", "val=0.6,test=0.5",
                                  "val=0.1,val=0.2", "val=x"])
def test_bad_splits_name_the_option(text):
    with pytest.raises(errors.ArgumentError) as e:
        dataset.parse_split(text)
    assert e.value.field == "--split"


def test_formats_are_checked_and_kept_once():
    assert dataset.parse_formats("coco, kitti,coco") == ["coco", "kitti"]
    for bad in ("yolo", "coco,,kitti", ""):
        with pytest.raises(errors.ArgumentError) as e:
            dataset.parse_formats(bad)
        assert e.value.field == "--format"


def test_command_line_errors_exit_2(tmp_path):
    job = str(tmp_path / "job.json")
    code, ev, _ = run_backend_here("export", job, job, "--format", "coco")
    assert code == 2 and ev[-1]["field"] == "--out"
    code, ev, _ = run_backend_here("export", job, "--format", "coco", "--split", "val=2")
    assert code == 2 and ev[-1]["field"] == "--split"
    code, ev, _ = run_backend_here("batch", job, "--command", "export", "--out", str(tmp_path / "d"))
    assert code == 2 and ev[-1]["field"] == "--format"
    code, ev, _ = run_backend_here("batch", job, "--command", "render", "--format", "coco")
    assert code == 2 and ev[-1]["field"] == "--format"
