"""``python -m backend export``: the command's checks, its reading of an output folder, the destination written
whole; and the whole command on a tiny job (once the render writes labels and the instance layer)."""

import json
import os

import numpy as np
import pytest

from tests.backend.export import export_fixtures as F
from backend.export import command
from backend.render import channels
from scpainter_blender.core import backend_protocol, errors, labels, outputs
from scpainter_blender.core.output_layout import OutputLayout
from tests_support import run_backend_here

HAS_INSTANCE = hasattr(channels, "INSTANCE")
NEEDS_INSTANCE = pytest.mark.skipif(not HAS_INSTANCE, reason="needs the render's instance layer (channels.INSTANCE)")


def test_format_names_have_one_home():
    assert tuple(command.FORMATS) == backend_protocol.EXPORT_FORMAT_NAMES
    for name, writer in command.FORMATS.items():             # each writer says what it reads
        assert writer.__name__ == f"backend.export.{name.replace('-', '_')}" and callable(writer.write)
        assert isinstance(writer.NEEDS_INSTANCE, bool)
    with pytest.raises(errors.ArgumentError) as e:
        command.check_format("yolo")
    assert e.value.field == "--format"


def test_destination_never_overwrites_what_is_not_an_export(tmp_path):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    command.check_destination(str(tmp_path / "new"), str(out_dir), given=True)    # missing: fine
    (tmp_path / "empty").mkdir()
    command.check_destination(str(tmp_path / "empty"), str(out_dir), given=True)  # empty: fine
    prev = tmp_path / "prev"
    prev.mkdir()
    (prev / OutputLayout.EXPORT_RECORD).write_text('{"files": ["x.txt"]}')          # the files it wrote
    (prev / "x.txt").write_text("old")
    command.check_destination(str(prev), str(out_dir), given=True)                # a previous export: fine
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "thesis.tex").write_text("keep me")
    planted = tmp_path / "planted"                 # a user's folder with an export.json: its files are not the export's
    planted.mkdir()
    (planted / OutputLayout.EXPORT_RECORD).write_text("{}")
    (planted / "thesis.tex").write_text("keep me")
    (tmp_path / "file").write_text("")
    os.symlink(tmp_path / "empty", tmp_path / "link")
    for bad in ("mine", "planted", "file", "link", ".", "out"):
        with pytest.raises(errors.ArgumentError) as e:
            command.check_destination(str(tmp_path / bad), str(out_dir), given=True)
        assert e.value.field == "--out" and e.value.path == errors.COMMAND_LINE, bad
    with pytest.raises(errors.InputError) as e:                                   # the default: names the folder
        command.check_destination(str(tmp_path / "mine"), str(out_dir), given=False)
    assert e.value.path == str(tmp_path / "mine") and not isinstance(e.value, errors.ArgumentError)


def test_labels_missing_or_of_another_schema_name_the_file(tmp_path):
    path = str(tmp_path / "labels_000004.json")
    with pytest.raises(errors.InputError) as e:
        command.read_labels(path, 4)
    assert e.value.path == path
    outputs.write_json(path, {"schema": "scpainter.labels/0", "frame": 4, "objects": []})
    with pytest.raises(errors.InputError) as e:
        command.read_labels(path, 4)
    assert (e.value.path, e.value.field) == (path, "schema") and "render again" in e.value.hint
    lab, _ = F.frame_labels(F.job(), 0)
    outputs.write_json(path, lab)
    assert command.read_labels(path, 4)["frame"] == 4
    with pytest.raises(errors.InputError) as e:
        command.read_labels(path, 5)
    assert e.value.field == "frame"


def _output_folder(tmp_path, generated: bool) -> tuple:
    """An output folder as render (and generate) leave it for ``export_fixtures.job()``: labels, EXRs with an
    ``instance.Y`` channel (written with OpenEXR directly), previews; generated frames and their manifest."""
    import OpenEXR

    j = F.job()
    layout = OutputLayout(str(tmp_path / "out"))
    os.makedirs(layout.conditions)
    for i, e in enumerate(j.frames):
        lab, inst = F.frame_labels(j, i)
        outputs.write_json(layout.frame_labels(e.frame), lab)
        zeros = np.zeros((F.H, F.W), np.float32)
        px = {n: zeros for n in ("image.R", "image.G", "image.B", "hole.Y", "asset_mask.Y")}
        px.update({"depth.Z": zeros + 10, "instance.Y": inst.astype(np.float32)})
        with open(layout.condition_exr(e.frame), "wb") as f:
            OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, px).write(f)
        F.write_png(layout.condition_preview(e.frame), i)
    if generated:
        os.makedirs(layout.generated)
        for i, e in enumerate(j.frames):
            F.write_png(layout.generated_frame(e.frame), 10 + i)
        outputs.write_json(layout.manifest, {"frames": [e.frame for e in j.frames]})
    return j, layout


@pytest.mark.parametrize("fmt", ["kitti", "openlabel", "kitti-tracking",
                                 pytest.param("coco", marks=NEEDS_INSTANCE)])
def test_write_export_from_an_output_folder(tmp_path, capsys, fmt):
    j, layout = _output_folder(tmp_path, generated=False)
    dest = layout.export(fmt)
    result = command.write_export(str(tmp_path / "job.json"), j, layout, fmt, dest)
    assert result == {"frames": 2, "objects": 6, "ignore_regions": 2, "images": "conditions"}
    evs = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [e["code"] for e in evs if e["event"] == "warning"] == [command.NO_GENERATED]
    assert [(e["done"], e["frame"]) for e in evs if e["event"] == "progress"] == [(1, 4), (2, 5)]
    record = json.load(open(os.path.join(dest, OutputLayout.EXPORT_RECORD)))
    assert (record["format"], record["scene_frames"], record["frames"]) == (fmt, [4, 5], 2)
    assert record["images"] == "conditions"
    assert not [n for n in os.listdir(os.path.dirname(dest)) if n.endswith(".tmp")]
    assert os.stat(dest).st_mode & 0o777 == 0o777 & ~outputs._umask()         # not mkdtemp's 0700


def test_generated_frames_are_the_images_when_finished_and_newer(tmp_path, capsys):
    j, layout = _output_folder(tmp_path, generated=True)
    assert command.image_source(layout, j) == ("generated", "")
    dest = str(tmp_path / "kitti")
    assert command.write_export("job.json", j, layout, "kitti", dest)["images"] == "generated"
    assert open(os.path.join(dest, "image_2", "000001.png"), "rb").read() == \
        open(layout.generated_frame(5), "rb").read()
    assert not [line for line in capsys.readouterr().out.splitlines() if '"warning"' in line]
    future = os.stat(layout.manifest).st_mtime + 10      # conditions rendered again after the generation
    os.utime(layout.condition_exr(5), (future, future))
    assert command.image_source(layout, j)[0] == "conditions"
    os.remove(layout.generated_frame(4))
    assert command.image_source(layout, j) == ("conditions", "generated frames are missing")


def test_a_new_export_replaces_the_previous_one_only_when_complete(tmp_path, monkeypatch):
    j, layout = _output_folder(tmp_path, generated=False)
    dest = layout.export("kitti")
    command.write_export("job.json", j, layout, "kitti", dest)
    before = sorted(os.listdir(os.path.join(dest, "label_2")))

    def broken(folder, frames, progress=None):
        os.makedirs(os.path.join(folder, "label_2"))
        raise RuntimeError("killed half-way")

    monkeypatch.setitem(command.FORMATS, "kitti", type("M", (), {"write": staticmethod(broken)}))
    with pytest.raises(RuntimeError):
        command.write_export("job.json", j, layout, "kitti", dest)
    assert sorted(os.listdir(os.path.join(dest, "label_2"))) == before        # the previous export, whole
    assert sorted(os.listdir(os.path.dirname(dest))) == ["kitti"]              # nothing half-written beside it


def test_command_line_errors_exit_2(tmp_path):
    code, ev, _ = run_backend_here("export", tmp_path / "job.json", "--format", "yolo")
    assert code == 2 and ev[-1]["file"] == errors.COMMAND_LINE and ev[-1]["field"] == "--format"
    code, ev, _ = run_backend_here("export", tmp_path / "job.json", "--format", "coco", "--out", " ")
    assert code == 2 and ev[-1]["field"] == "--out"
    code, ev, _ = run_backend_here("export", tmp_path / "job.json", "--format", "coco")
    assert code == 2 and ev[-1]["file"] == str(tmp_path / "job.json")


def _tiny_job(tmp_path) -> str:
    """A job with no scene and one procedural Gaussian car, two frames at 96 x 64."""
    from scpainter_blender.core import job as J
    from scpainter_blender.core import shapes

    ply = tmp_path / "car.ply"
    to_file = shapes.save_as_amodal3r(str(ply), shapes.procedural_car_gaussians(count=3000, seed=1))
    o2w = F.placed(0.0, 9.0, 20.0) @ np.linalg.inv(to_file)
    job = J.Job((F.W, F.H), [J.Frame(f, F.K.copy(), F.world_to_camera(0.1 * i)) for i, f in enumerate(F.FRAMES)],
                "out", None, [J.Asset("car", "car.ply", {f: o2w for f in F.FRAMES})], fps=10.0)
    J.save(tmp_path / "job.json", job)
    return str(tmp_path / "job.json")


def test_export_command_end_to_end(tmp_path):
    job = _tiny_job(tmp_path)
    code, ev, err = run_backend_here("export", job, "--format", "coco", "--device", "cpu")
    assert code == 0, err
    done = ev[-1]
    out = os.path.join(tmp_path, "out", "export", "coco")
    assert done["event"] == "done" and done["command"] == "export" and done["format"] == "coco"
    assert done["out"] == out and done["frames"] == 2 and done["images"] == "conditions" and done["rendered"] == 2
    assert any(e["event"] == "warning" and e["code"] == command.NO_GENERATED for e in ev)
    from pycocotools.coco import COCO

    api = COCO(os.path.join(out, "annotations.json"))
    assert done["objects"] == len(api.getAnnIds()) >= 1
    inst = channels.read(os.path.join(tmp_path, "out", "conditions", "frame_000004.exr"),
                         required=(channels.INSTANCE,))[channels.INSTANCE]
    ann = api.loadAnns(api.getAnnIds(imgIds=[1]))[0]
    assert np.array_equal(api.annToMask(ann).astype(bool), np.rint(inst) == 1)
    code, ev, _ = run_backend_here("export", job, "--format", "coco", "--device", "cpu")   # again: nothing rendered
    assert code == 0 and ev[-1]["rendered"] == 0 and os.path.isdir(out)


def test_an_export_of_another_format_is_never_written_over(tmp_path):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    prev = tmp_path / "prev"
    prev.mkdir()
    (prev / OutputLayout.EXPORT_RECORD).write_text('{"format": "coco"}')
    command.check_destination(str(prev), str(out_dir), given=True, fmt="coco")
    with pytest.raises(errors.ArgumentError, match="holds a coco export, not kitti"):
        command.check_destination(str(prev), str(out_dir), given=True, fmt="kitti")


def test_every_format_carries_each_frames_coverage_and_flags(tmp_path):
    """A pipeline reading only the export can drop weak frames: KITTI's frames.json, COCO's images and OpenLABEL's
    frame_properties (and KITTI tracking's frames.json) hold the labels' coverage and flags."""
    from backend.export import coco, kitti, kitti_tracking, openlabel

    frames = F.export_frames(tmp_path)
    frames[1].labels["flags"] = [labels.CAMERA_INSIDE_FLAG]
    got = {}
    for name, module in (("kitti", kitti), ("coco", coco), ("openlabel", openlabel), ("tracking", kitti_tracking)):
        out = tmp_path / name
        out.mkdir()
        module.write(str(out), frames)
        got[name] = out
    index = json.loads((got["kitti"] / "frames.json").read_text())["frames"]
    images = json.loads((got["coco"] / "annotations.json").read_text())["images"]
    props = [f["frame_properties"] for f in json.loads((got["openlabel"] / "openlabel.json").read_text())[
        "openlabel"]["frames"].values()]
    tracking = json.loads((got["tracking"] / "frames.json").read_text())["frames"]
    for rows in (index, images, props, tracking):
        assert [r["flags"] for r in rows] == [fr.labels["flags"] for fr in frames]
        assert [r["coverage"] for r in rows] == [fr.labels["coverage"] for fr in frames]


def test_coco_and_openlabel_carry_the_fields_the_labels_table_says(tmp_path):
    """COCO's annotations have the labels' carried identity and measures as keys, OpenLABEL's objects the carried
    measures as per-frame ``num`` (``core.labels.OBJECT_FIELDS``, which both read), in the order they always had."""
    from backend.export import coco, openlabel

    frames = F.export_frames(tmp_path)
    names = [fr.image for fr in frames]
    anns = coco.dataset(frames, names)["annotations"]
    assert anns and all(list(a)[-6:] == ["track_id", "synthetic", "hole_fraction", "occlusion", "truncation",
                                         "visible_fraction"] for a in anns)
    assert set(coco.EXTRA_KEYS) == set(labels.CARRIED_IDENTITY + labels.CARRIED_MEASURES)
    doc = openlabel.document(frames, names)["openlabel"]
    nums = [[n["name"] for n in o["object_data"]["num"]] for f in doc["frames"].values()
            for o in f.get("objects", {}).values()]
    assert ["hole_fraction", "visible_fraction", "occlusion", "truncation"] in nums
    assert {n for ns in nums for n in ns} == set(labels.CARRIED_MEASURES)


def test_the_default_destination_is_never_written_through_a_planted_export_link(tmp_path):
    """export followed a link at out/export (issue 42): the default destination under it is refused by name."""
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    os.symlink(elsewhere, out_dir / OutputLayout.EXPORT)
    dest = OutputLayout(str(out_dir)).export("coco")
    with pytest.raises(errors.InputError) as e:
        command.check_destination(dest, str(out_dir), given=False, fmt="coco")
    assert e.value.path == dest and "symbolic link" in e.value.message
    with pytest.raises(errors.InputError):       # and where the folder is made, never through it
        outputs.own_folder(str(out_dir), OutputLayout.EXPORT)
    assert os.listdir(elsewhere) == []


def test_a_file_put_in_the_destination_while_frames_render_is_never_deleted(tmp_path, monkeypatch):
    """export --out deleted a user's file created in the destination while the missing frames rendered (2 of 2,
    issue 42). The user's write is made at the point between the render and the export's rename (in-process)."""
    from scpainter_blender.core import job as J
    from tests_support import small_job

    job = small_job(tmp_path / "job")
    dest = tmp_path / "dataset"
    chose = command.image_source

    def rendered_then_user_writes(*args):
        dest.mkdir()                                  # the destination did not exist when it was checked
        (dest / "thesis.tex").write_text("keep me")
        return chose(*args)

    monkeypatch.setattr(command, "image_source", rendered_then_user_writes)
    with pytest.raises(errors.InputError) as e:
        command.export_job(job, J.load(job), "kitti", out=str(dest))
    assert e.value.path == str(dest) and "thesis.tex" in e.value.message
    assert os.listdir(dest) == ["thesis.tex"] and (dest / "thesis.tex").read_text() == "keep me"
    assert sorted(os.listdir(tmp_path)) == ["dataset", "job"]      # nothing left beside it


def test_a_destination_path_too_long_is_refused_naming_it_before_anything_is_made(tmp_path):
    """Issue 42 (fuzz names 39): `export --out` with a 4,200-byte path (every name short) failed naming the export's
    temporary folder (`.dddd….tmp`); now the destination itself is refused (field --out) and nothing is made."""
    from scpainter_blender.core import job as J
    from tests_support import small_job

    job = small_job(tmp_path / "job")
    dest = os.path.join(tmp_path, *["d" * 200] * 21)          # 21 names of 200 bytes: beyond PATH_MAX (4,096)
    before = sorted(os.listdir(tmp_path))
    with pytest.raises(errors.InputError) as e:
        command.export_job(job, J.load(job), "kitti", out=dest)
    assert (e.value.path, e.value.field) == (dest, "--out") and "too long for its file system" in e.value.message
    assert sorted(os.listdir(tmp_path)) == before                 # no folder of the destination, no temporary
