"""A rig job rendered, generated and exported camera by camera (``backend/render/rig_jobs.py``, docs/design.md §17):
each camera job is an ordinary single-camera job in ``<output_dir>/<camera>/``, its labels from its own instance
pass; the scene's points are read once for all cameras; a second render renders nothing, and a changed K of one
camera renders that camera alone."""

import json
import os

import numpy as np
import pytest

from backend.render import cleaning
from scpainter_blender.core import files, rig as R
from scpainter_blender.core import job as J
from scpainter_blender.core.output_layout import OutputLayout
from tests_support import run_backend_here as backend, small_job

#: OpenCV camera axes into the ego frame (x forward, y left, z up): looking forward, and looking back
FORWARD = np.array([[0.0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
BACKWARD = np.array([[0.0, 0, -1, 0], [1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]])


def _K(W, H):
    return np.array([[12.0, 0, W / 2], [0, 12.0, H / 2], [0, 0, 1]])


@pytest.fixture(scope="module")
def rigged(tmp_path_factory):
    """small_job's scene (a car 6 m ahead of its camera) as a two-camera rig job: CAM_FRONT rides on the job's
    camera, CAM_BACK (another resolution) looks the other way; rendered once."""
    tmp = tmp_path_factory.mktemp("rig")
    base = small_job(tmp / "drive", fps=10.0)
    rig = R.Rig("custom", [R.RigCamera("CAM_FRONT", (16, 12), _K(16, 12), FORWARD),
                           R.RigCamera("CAM_BACK", (20, 12), _K(20, 12), BACKWARD)])
    R.save(tmp / "two.json", rig)
    code, ev, err = backend("rig", base, "--preset", tmp / "two.json", "--out", tmp / "surround" / "job.json")
    assert code == 0, err
    assert ev[-1]["data_roots"] == [str(tmp / "drive")] and ev[-1]["cameras"] == ["CAM_FRONT", "CAM_BACK"]
    job_path = str(tmp / "surround" / "job.json")
    return tmp, job_path


def _render(job_path, tmp):
    return backend("render", job_path, "--device", "cpu", "--data-root", tmp / "drive")


def test_each_camera_renders_its_own_folder_and_labels(rigged, monkeypatch):
    tmp, job_path = rigged
    loads = []
    real = cleaning.clean_cloud
    monkeypatch.setattr(cleaning, "clean_cloud", lambda *a, **k: loads.append(1) or real(*a, **k))
    code, ev, err = _render(job_path, tmp)
    assert code == 0, err
    assert len(loads) == 1          # the points read and cleaned once for both cameras
    done = ev[-1]
    assert done["cameras"] == ["CAM_FRONT", "CAM_BACK"] and done["frames"] == 4 and done["rendered"] == 4
    progress = [(e["camera"], e["frame"]) for e in ev if e["event"] == "progress" and e["stage"] == "render"]
    assert progress == [("CAM_FRONT", 1), ("CAM_FRONT", 2), ("CAM_BACK", 1), ("CAM_BACK", 2)]
    assert all(e.get("camera") in ("CAM_FRONT", "CAM_BACK") for e in ev if e["event"] == "artifact"
               and e["kind"] != "surround")    # the rig's own pictures (every camera at a frame) name none
    assert [e["frame"] for e in ev if e["event"] == "artifact" and e["kind"] == "surround"] == [1, 2]
    root = OutputLayout(tmp / "surround")
    front, back = root.camera("CAM_FRONT"), root.camera("CAM_BACK")
    assert done["output_dir"] == root.root and done["per_camera"]["CAM_BACK"]["output_dir"] == back.root
    for layout, W in ((front, 16), (back, 20)):
        for f in (1, 2):
            assert os.path.isfile(layout.condition_exr(f))
            lab = files.read_json(layout.frame_labels(f))
            assert lab["frame"] == f and lab["image_size"] == [W, 12]
    # the car 6 m ahead: in CAM_FRONT's instance pass, not in CAM_BACK's (it looks away)
    car = {name: [o for o in files.read_json(layout.frame_labels(1))["objects"] if o["name"] == "car"]
           for name, layout in (("front", front), ("back", back))}
    assert car["front"][0]["visible_pixels"] > 0
    assert not car["back"] or car["back"][0]["visible_pixels"] == 0
    # each camera's labels carry its own camera: CAM_BACK's pose is CAM_FRONT's turned around
    cam_f = np.array(files.read_json(front.frame_labels(1))["camera"]["world_to_camera"])
    cam_b = np.array(files.read_json(back.frame_labels(1))["camera"]["world_to_camera"])
    np.testing.assert_allclose(cam_b[:3, :3] @ cam_f[:3, :3].T, np.diag([-1.0, 1, -1]), atol=1e-9)

    # a second render renders nothing
    code, ev, err = _render(job_path, tmp)
    assert code == 0 and ev[-1]["rendered"] == 0 and ev[-1]["skipped"] == 4, err
    # one camera's K changed: that camera alone renders again
    d = files.read_json(job_path)
    d["rig"]["cameras"][1]["K"][0][0] = 13.0
    J.save(job_path, d)
    code, ev, err = _render(job_path, tmp)
    assert code == 0, err
    per = ev[-1]["per_camera"]
    assert (per["CAM_FRONT"]["rendered"], per["CAM_BACK"]["rendered"]) == (0, 2)


def test_generate_and_export_run_camera_by_camera(rigged):
    tmp, job_path = rigged
    code, ev, err = backend("generate", job_path, "--device", "cpu", "--data-root", tmp / "drive")
    assert code == 0, err
    root = OutputLayout(tmp / "surround")
    done = ev[-1]
    assert done["frames"] == 4 and done["model"] == "baseline"
    assert done["videos"] == {c: root.camera(c).video for c in ("CAM_FRONT", "CAM_BACK")}
    assert all(os.path.isfile(v) for v in done["videos"].values())
    out = tmp / "kitti"
    code, ev, err = backend("export", job_path, "--format", "kitti", "--out", out, "--device", "cpu",
                            "--data-root", tmp / "drive")
    assert code == 0, err
    done = ev[-1]
    assert done["outs"] == {c: str(out / c) for c in ("CAM_FRONT", "CAM_BACK")} and done["frames"] == 4
    assert done["rendered"] == 0 and done["images"] == "generated"
    # each camera's labels its own: the car ahead is CAM_FRONT's object, CAM_BACK (looking away) has none
    per = done["per_camera"]
    assert per["CAM_FRONT"]["objects"] >= 1 and per["CAM_BACK"]["objects"] == 0
    for cam in ("CAM_FRONT", "CAM_BACK"):
        assert files.read_json(out / cam / OutputLayout.EXPORT_RECORD)["scene_frames"] == [1, 2]
    # a dataset export (several formats) takes one camera: refused naming the rig
    code, ev, err = backend("export", job_path, "--format", "kitti,coco", "--out", tmp / "ds", "--device", "cpu",
                            "--data-root", tmp / "drive")
    assert code == 2 and ev[-1]["field"] == "rig" and "one export per camera" in ev[-1]["hint"]


def test_a_rig_export_out_obeys_the_single_export_rule(rigged):
    """``--out`` of a rig job's single-camera-format export: a folder with other content is refused before anything
    is written (not only an occupied ``<out>/<CAMERA>/``); a previous rig export of the format is replaced."""
    tmp, job_path = rigged
    occupied = tmp / "occupied"
    occupied.mkdir()
    (occupied / "notes.txt").write_text("mine")
    export = lambda out, fmt="kitti": backend("export", job_path, "--format", fmt, "--out", out,  # noqa: E731
                                              "--device", "cpu", "--data-root", tmp / "drive")
    code, ev, err = export(occupied)
    assert code == 2 and ev[-1]["field"] == "--out" and "notes.txt" in ev[-1]["message"]
    assert sorted(os.listdir(occupied)) == ["notes.txt"]
    out = tmp / "kitti_again"
    for _ in range(2):   # new, then its own previous export: replaced
        code, ev, err = export(out)
        assert code == 0, err
    record = files.read_json(out / OutputLayout.EXPORT_RECORD)
    assert record["format"] == "kitti" and record["cameras"] == ["CAM_FRONT", "CAM_BACK"]
    assert "CAM_FRONT/export.json" in record["files"]
    code, ev, err = export(out, "coco")   # another format over it: refused, as for one camera
    assert code == 2 and ev[-1]["field"] == "--out" and "kitti" in ev[-1]["message"]


def test_a_rig_export_that_fails_after_its_first_camera_is_replaced_by_the_next(rigged, monkeypatch):
    """Each camera's export is recorded in ``<out>``'s record as it finishes: a run that fails (or is killed) after
    the first camera leaves a rig export the next run may replace, not a folder it refuses."""
    from backend.export import command

    tmp, job_path = rigged
    out = tmp / "kitti_failed"
    real, calls = command.export_job, []

    def failing(*a, **k):   # the second camera's export breaks down
        calls.append(1)
        if len(calls) == 3:   # the rig's own call, then CAM_FRONT's, then CAM_BACK's
            raise OSError("disk went away")
        return real(*a, **k)

    monkeypatch.setattr(command, "export_job", failing)
    code, ev, err = backend("export", job_path, "--format", "kitti", "--out", out, "--device", "cpu",
                            "--data-root", tmp / "drive")
    assert code != 0 and sorted(os.listdir(out)) == ["CAM_FRONT", OutputLayout.EXPORT_RECORD]
    monkeypatch.setattr(command, "export_job", real)
    code, ev, err = backend("export", job_path, "--format", "kitti", "--out", out, "--device", "cpu",
                            "--data-root", tmp / "drive")
    assert code == 0, err
    assert files.read_json(out / OutputLayout.EXPORT_RECORD)["cameras"] == ["CAM_FRONT", "CAM_BACK"]


def test_batch_runs_a_rig_job_camera_by_camera(rigged):
    tmp, job_path = rigged
    code, ev, err = backend("batch", job_path, "--command", "render", "--device", "cpu", "--data-root", tmp / "drive")
    assert code == 0, err
    item = ev[-1]["items"][0]
    assert item["status"] == "ok" and item["frames"] == 4 and item["output_dir"] == str(tmp / "surround")


def test_check_counts_every_camera(rigged):
    tmp, job_path = rigged
    code, ev, err = backend("render", job_path, "--check", "--data-root", tmp / "drive")
    assert code == 0, err
    assert ev[-1]["check"] and ev[-1]["frames"] == 4 and ev[-1]["cameras"] == ["CAM_FRONT", "CAM_BACK"]


def test_a_stop_ends_the_rig_before_the_next_camera(rigged, capsys):
    from backend import events
    from backend.render import rig_jobs

    tmp, job_path = rigged
    job = J.load(job_path)
    stop = []

    def run(cam, camera_job):
        events.progress("render", 1, 1, frame=1)
        stop.append("SIGTERM")   # arrives while the first camera runs
        return {"frames": len(camera_job.frames), "stopped": False}

    results = rig_jobs.run_cameras(job, run, stop)
    assert [name for name, _ in results] == ["CAM_FRONT"]
    out = rig_jobs.combined(job, results, "/out", ("frames",), stop)
    assert out["stopped"] and out["frames"] == 2 and out["cameras"] == ["CAM_FRONT", "CAM_BACK"]
    assert json.loads(capsys.readouterr().out.splitlines()[-1])["camera"] == "CAM_FRONT"
    events.progress("render", 1, 1)   # the tag ends with the camera
    assert "camera" not in json.loads(capsys.readouterr().out)
